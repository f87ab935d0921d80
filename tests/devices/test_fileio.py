"""devices.fileio: the servo log's .npz writer against numpy's."""

import numpy as np

from devices.fileio import save_npz


def test_save_npz_matches_numpy_savez(tmp_path):
    """save_npz (no copies of contiguous arrays) writes what np.savez writes: same members, same
    headers and bytes (the files are the same size), the same arrays back through np.load."""
    rng = np.random.default_rng(3)
    log = np.ascontiguousarray(rng.normal(size=(3, 1000)))
    arrays = {"t_s": log[0], "position_m": log[1][:500], "clipped": rng.integers(0, 8, 1000).astype(np.uint8),
              "wall_ns": np.arange(1000, dtype=np.int64), "flag": rng.random(10) > 0.5,
              "strided": log[2][::3], "empty": np.zeros(0), "big_endian": np.arange(4, dtype=">f8")}
    save_npz(tmp_path / "ours.npz", arrays)
    np.savez(tmp_path / "numpy.npz", **arrays)
    assert (tmp_path / "ours.npz").stat().st_size == (tmp_path / "numpy.npz").stat().st_size
    with np.load(tmp_path / "ours.npz") as a, np.load(tmp_path / "numpy.npz") as b:
        assert a.files == b.files == list(arrays)
        for k in arrays:
            assert a[k].dtype == b[k].dtype == arrays[k].dtype and np.array_equal(a[k], b[k]), k
