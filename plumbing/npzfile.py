"""NumPy archives (``.npz``): the servo log's fast writer and a reader whose errors name the file.

Apart from :mod:`plumbing.fileio` because both need numpy, which every command's ``--help`` (they all import
fileio) would otherwise load (93 ms CPU).
"""

from __future__ import annotations

import io
import struct
import threading
import zipfile
import zlib
from pathlib import Path

import numpy as np

#: what zipfile (and so np.savez) writes in every member: zip64 local headers (ZIP64_VERSION), a Unix
#: creator, ``-rw-------`` members, and the zip64 limits of its end records
_ZIP64_VERSION, _UNIX, _MEMBER_MODE = 45, 3, 0o600 << 16
_ZIP64_LIMIT, _ZIP_COUNT_LIMIT = (1 << 31) - 1, (1 << 16) - 1


def save_npz(path, arrays: dict) -> None:
    """``np.savez(path, **arrays)`` (uncompressed ``.npz``, one ``.npy`` member per array; byte for byte
    with a zipfile that writes zip64 local headers as the spec asks, Python 3.11.7 here, not 3.11.2),
    with less waiting: contiguous arrays are written from their own memory (``np.savez`` copies every
    array in chunks first), and each member's CRC-32 is computed on a second thread while the previous
    member is written (a 30 s servo log is 34 MB: ~7 ms of CRC and ~7 ms of writing here, one after the
    other in ``zipfile``). Read back by ``np.load`` like any ``.npz``; ``tests/devices/test_fileio.py``
    checks the members and bytes against ``np.savez`` and the archive with ``zipfile``.

    The format is zipfile's (PKWARE APPNOTE 6.3): stored members whose local headers carry the zip64
    sizes (``force_zip64``, as numpy asks), central directory entries and end records in zip64 form
    only beyond zipfile's limits.
    """
    members = []  # (name bytes, utf-8 flag, .npy header, data)
    for name, arr in arrays.items():
        arr = np.asanyarray(arr)
        head = io.BytesIO()
        if arr.flags.c_contiguous and arr.dtype.kind in "biuf" and arr.size:
            np.lib.format.write_array_header_1_0(head, np.lib.format.header_data_from_array_1_0(arr))
            data = memoryview(arr).cast("B")
        else:  # object, structured, empty or strided: numpy's own writer, in memory
            np.lib.format.write_array(head, arr, allow_pickle=False)
            data = memoryview(b"")
        fname = name + ".npy"
        try:
            members.append((fname.encode("ascii"), 0, head.getvalue(), data))
        except UnicodeEncodeError:
            members.append((fname.encode("utf-8"), 0x800, head.getvalue(), data))
    crcs = [None] * len(members)
    done = [threading.Event() for _ in members]

    def crc_all():  # zlib releases the GIL over large buffers: this runs beside the writes
        try:
            for k, (_, _, head, data) in enumerate(members):
                crcs[k] = zlib.crc32(data, zlib.crc32(head))
                done[k].set()
        finally:  # never leave the writer waiting (a member without its CRC is an error there)
            for event in done:
                event.set()

    worker = threading.Thread(target=crc_all, name="npz-crc", daemon=True)
    worker.start()
    # zipfile's default member time, which np.savez's members carry: 1980-01-01 00:00 (MS-DOS form)
    dosdate, dostime = 1 << 5 | 1, 0
    central = []
    try:
        with open(path, "wb") as fh:
            for k, (fname, flags, head, data) in enumerate(members):
                size = len(head) + data.nbytes
                done[k].wait()
                if crcs[k] is None:
                    raise RuntimeError(f"{path}: no CRC-32 for member {fname.decode()}")
                offset = fh.tell()
                extra = struct.pack("<HHQQ", 1, 16, size, size)
                fh.write(struct.pack("<4s2B4HL2L2H", b"PK\x03\x04", _ZIP64_VERSION, 0, flags, zipfile.ZIP_STORED,
                                     dostime, dosdate, crcs[k], 0xFFFFFFFF, 0xFFFFFFFF, len(fname), len(extra)))
                fh.write(fname)
                fh.write(extra)
                fh.write(head)
                fh.write(data)
                central.append((fname, flags, crcs[k], size, offset))
            start = fh.tell()
            for fname, flags, crc, size, offset in central:
                big = [size, size] if size > _ZIP64_LIMIT else []
                if offset > _ZIP64_LIMIT:
                    big.append(offset)
                extra = struct.pack(f"<HH{len(big)}Q", 1, 8 * len(big), *big) if big else b""
                small = 0xFFFFFFFF if size > _ZIP64_LIMIT else size
                fh.write(struct.pack("<4s4B4HL2L5H2L", b"PK\x01\x02", _ZIP64_VERSION, _UNIX, _ZIP64_VERSION, 0, flags,
                                     zipfile.ZIP_STORED, dostime, dosdate, crc, small, small, len(fname), len(extra),
                                     0, 0, 0, _MEMBER_MODE, offset if offset <= _ZIP64_LIMIT else 0xFFFFFFFF))
                fh.write(fname)
                fh.write(extra)
            end = fh.tell()
            count, cd_size = len(central), end - start
            if count > _ZIP_COUNT_LIMIT or start > _ZIP64_LIMIT or cd_size > _ZIP64_LIMIT:
                fh.write(struct.pack("<4sQ2H2L4Q", b"PK\x06\x06", 44, _ZIP64_VERSION, _ZIP64_VERSION, 0, 0, count,
                                     count, cd_size, start))
                fh.write(struct.pack("<4sLQL", b"PK\x06\x07", 0, end, 1))
                count, cd_size, start = min(count, 0xFFFF), min(cd_size, 0xFFFFFFFF), min(start, 0xFFFFFFFF)
            fh.write(struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, count, count, cd_size, start, 0))
    finally:
        worker.join()


def load_npz(path, what: str = ".npz file"):
    """Open an ``.npz`` archive safely (no pickles); errors name the file and say what is wrong.

    Distinguishes a missing file, an empty one, a pickle (refused: loading it could run code), a
    single-array ``.npy`` file, another kind of file, and a truncated or corrupt zip archive.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file should be, for the messages ("HFAM library", "trace").

    Returns
    -------
    numpy.lib.npyio.NpzFile
        Use it as a context manager.

    Raises
    ------
    FileNotFoundError, ValueError
        One line: ``"<path>: <what> ... (reason)"``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    with open(path, "rb") as fh:
        head = fh.read(8)
    if not head:
        raise ValueError(f"{path}: {what} is empty (0 bytes)")
    if head[:1] == b"\x80" or head[:1] in (b"(", b"]", b"}"):
        raise ValueError(f"{path}: {what} is a Python pickle, not an .npz archive (refused: loading pickles can "
                         "run code)")
    if head.startswith(b"\x93NUMPY"):
        raise ValueError(f"{path}: {what} is a single-array .npy file, not an .npz archive")
    if not head.startswith(b"PK"):
        # what kind of file, never its bytes: the path may name any file the user can read (a catalog's
        # library = "../../etc/passwd" must not echo the file's first bytes)
        kind = "a text file" if all(32 <= b < 127 or b in (9, 10, 13) for b in head) else "another binary format"
        raise ValueError(f"{path}: {what} is not an .npz (zip) archive ({kind}, without the zip signature)")
    try:
        return np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise ValueError(f"{path}: {what} is a truncated or corrupt zip archive ({exc})") from None
