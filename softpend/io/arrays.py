"""``.npz`` archives of plain arrays read without ``numpy.load``: a bounded regular file, ``.npy`` members only,
no object dtypes (pickles), and each header's data checked against its member's size before it is read."""

from __future__ import annotations

import math
import zipfile
import zlib
from pathlib import Path

import numpy as np

from softpend.checks import MAX_WORK_BYTES
from softpend.io.reading import check_zip_members, open_regular_file

#: What reading a corrupt, truncated or hostile archive can raise.
_READ_ERRORS: tuple[type[Exception], ...] = (OSError, ValueError, EOFError, KeyError, MemoryError, TypeError)
_READ_ERRORS += (NotImplementedError, SyntaxError, zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error)


def _read_npy_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> np.ndarray:
    """The array in the ``.npy`` member ``info`` of ``archive``; ``ValueError`` saying why it is not a plain array."""
    fmt = np.lib.format
    with archive.open(info) as member:
        try:
            version = fmt.read_magic(member)
        except ValueError:
            raise ValueError("not a .npy array") from None
        readers = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}
        if version not in readers:
            raise ValueError(f".npy format version {version[0]}.{version[1]} is not supported")
        shape, fortran, dtype = readers[version](member, max_header_size=10_000)
        if dtype.hasobject:
            raise ValueError(f"dtype {dtype} holds Python objects (a pickle), not plain numbers")
        if dtype.itemsize == 0:
            raise ValueError(f"dtype {dtype} has items of zero size")
        count = math.prod(shape)
        n_bytes = count * dtype.itemsize
        held = info.file_size - member.tell()  # the bytes after the header, from the zip directory
        if n_bytes > held:
            raise ValueError(
                f"its header declares shape {shape} of {dtype} ({n_bytes} bytes), more than the "
                f"{held} bytes of data it holds"
            )
        data = member.read(n_bytes)
    if len(data) != n_bytes:
        raise ValueError(f"truncated: {len(data)} of {n_bytes} bytes of data")
    array = np.frombuffer(bytearray(data), dtype=dtype, count=count)
    return array.reshape(shape[::-1]).transpose() if fortran else array.reshape(shape)


def read_npz(
    path: str | Path, what: str, error: type[Exception] = ValueError, max_bytes: int = MAX_WORK_BYTES
) -> dict[str, np.ndarray]:
    """Every member of the ``.npz`` archive at ``path`` (at most ``max_bytes``, also unpacked) as an array;
    ``error`` names the file, ``what`` it should be and the reason (``FileNotFoundError`` if it is missing)."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    with open_regular_file(path, what, max_bytes, error) as handle:
        try:
            archive = zipfile.ZipFile(handle)
        except _READ_ERRORS as exc:
            raise error(f"{path}: not a readable {what} ({type(exc).__name__}: {' '.join(str(exc).split())})") from None
        with archive:
            check_zip_members(archive, path, what, max_bytes, max_bytes, error)
            for info in archive.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                if name in arrays or not info.filename.endswith(".npy"):
                    reason = "appears twice" if name in arrays else "is not a .npy array"
                    raise error(f"{path}: not a readable {what} (member {info.filename!r} {reason})")
                try:
                    arrays[name] = _read_npy_member(archive, info)
                except _READ_ERRORS as exc:
                    message = " ".join(str(exc).split())
                    if type(exc) is not ValueError:
                        message = f"{type(exc).__name__}: {message}"
                    raise error(f"{path}: not a readable {what} (member {info.filename!r}: {message})") from None
    return arrays
