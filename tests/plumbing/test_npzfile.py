"""plumbing.npzfile: the servo log's .npz writer against numpy's."""

import io
import zipfile

import numpy as np
import pytest

from plumbing import npzfile
from plumbing.npzfile import save_npz


def _arrays():
    rng = np.random.default_rng(3)
    log = np.ascontiguousarray(rng.normal(size=(3, 100_000)))
    return {"t_s": log[0], "position_m": log[1][:500], "clipped": rng.integers(0, 8, 1000).astype(np.uint8),
            "wall_ns": np.arange(1000, dtype=np.int64), "flag": rng.random(10) > 0.5,
            "strided": log[2][::3], "empty": np.zeros(0), "big_endian": np.arange(4, dtype=">f8"),
            "gripkraft_\u00fc": np.ones(3)}


def _zipfile_writes_spec_zip64_headers() -> bool:
    """Whether this Python's zipfile writes a forced zip64 local header as APPNOTE 4.5.3 asks (version 45,
    sizes 0xFFFFFFFF, the sizes in the extra field), as save_npz does; Python 3.11.2's wrote version 20
    and the 32-bit sizes as well (both forms are read by every reader, np.load included)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf, zf.open("a", "w", force_zip64=True) as fh:
        fh.write(b"x")
    return buf.getvalue()[4] == 45


@pytest.mark.parametrize("zip64", [False, True])
def test_save_npz_writes_what_numpy_savez_writes(tmp_path, monkeypatch, zip64):
    """save_npz (no copies, CRCs on a second thread) writes np.savez's members (names, CRC-32s, sizes,
    bytes), and with a zipfile that writes zip64 headers as the spec asks, np.savez's file byte for byte;
    also in the zip64 form zipfile uses beyond 2 GiB (forced here by lowering both writers' limit to 1 kB:
    zip64 sizes and offsets in the central directory, the zip64 end records)."""
    if zip64:
        monkeypatch.setattr(zipfile, "ZIP64_LIMIT", 1000)
        monkeypatch.setattr(npzfile, "_ZIP64_LIMIT", 1000)
    arrays = _arrays()
    save_npz(tmp_path / "ours.npz", arrays)
    np.savez(tmp_path / "numpy.npz", **arrays)
    ours, theirs = (tmp_path / "ours.npz").read_bytes(), (tmp_path / "numpy.npz").read_bytes()
    assert len(ours) > 800_000 and len(ours) == len(theirs)
    assert (b"PK\x06\x06" in ours) is zip64
    if _zipfile_writes_spec_zip64_headers():
        assert ours == theirs
    with zipfile.ZipFile(tmp_path / "ours.npz") as a, zipfile.ZipFile(tmp_path / "numpy.npz") as b:
        assert a.testzip() is None  # every member's CRC-32 checks out
        assert [(i.filename, i.CRC, i.file_size, i.compress_type, i.header_offset) for i in a.infolist()] == \
            [(i.filename, i.CRC, i.file_size, i.compress_type, i.header_offset) for i in b.infolist()]
        for info in a.infolist():
            assert a.read(info) == b.read(info.filename), info.filename


def test_save_npz_matches_numpy_savez(tmp_path):
    """The same arrays back through np.load, dtypes included."""
    arrays = _arrays()
    save_npz(tmp_path / "ours.npz", arrays)
    np.savez(tmp_path / "numpy.npz", **arrays)
    assert (tmp_path / "ours.npz").stat().st_size == (tmp_path / "numpy.npz").stat().st_size
    with np.load(tmp_path / "ours.npz") as a, np.load(tmp_path / "numpy.npz") as b:
        assert a.files == b.files == list(arrays)
        for k in arrays:
            assert a[k].dtype == b[k].dtype == arrays[k].dtype and np.array_equal(a[k], b[k]), k
