"""Reading ``.npz`` archives of plain arrays: never unpickling, bounded, every failure a named error.

:func:`read_npz` reads the archive itself rather than through ``numpy.load``: the file must be a regular
file of at most ``max_bytes`` (:func:`softpend.io.reading.open_regular_file`), every member must be a
``.npy`` array (``numpy.load`` hands any other member back as raw bytes), its dtype must hold no Python
objects (those are pickles), and the data its header declares must fit in the bytes its zip directory entry
states -- checked before any memory is allocated for it, so a crafted header cannot ask for terabytes.
"""

from __future__ import annotations

import math
import zipfile
import zlib
from pathlib import Path

import numpy as np

from softpend.checks import MAX_WORK_BYTES
from softpend.io.reading import check_zip_members, open_regular_file

__all__ = ["read_npz", "read_npy_member"]

#: What reading a corrupt, truncated or hostile archive can raise.
_READ_ERRORS = (
    OSError,
    ValueError,
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    EOFError,
    KeyError,
    MemoryError,
    NotImplementedError,
    zlib.error,
    SyntaxError,
    TypeError,
)


def read_npy_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> np.ndarray:
    """The array in the ``.npy`` member ``info`` of ``archive``; ``ValueError`` saying why it is not a plain
    array (not ``.npy``, an object dtype, a header that declares more data than the member holds)."""
    fmt = np.lib.format
    with archive.open(info) as member:
        try:
            version = fmt.read_magic(member)
        except ValueError:
            raise ValueError("not a .npy array") from None
        if version == (1, 0):
            shape, fortran, dtype = fmt.read_array_header_1_0(member, max_header_size=10_000)
        elif version == (2, 0):
            shape, fortran, dtype = fmt.read_array_header_2_0(member, max_header_size=10_000)
        else:
            raise ValueError(f".npy format version {version[0]}.{version[1]} is not supported")
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
    """Every member of the ``.npz`` archive at ``path`` as an array (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The archive: a regular file (not a folder, FIFO or device).
    what : str
        What the file is, for the messages (``"dataset file"``).
    error : type
        The exception class of a refusal.
    max_bytes : int
        Bound on the file's size and on the bytes its members unpack to (default: the 4 GiB that one piece of
        work may plan for, :data:`softpend.checks.MAX_WORK_BYTES`).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    error
        If the archive cannot be read as plain arrays; the message names the file, ``what`` it should be and
        the reason (the member, where one is at fault).
    """
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
                    arrays[name] = read_npy_member(archive, info)
                except _READ_ERRORS as exc:
                    message = " ".join(str(exc).split())
                    if type(exc) is not ValueError:
                        message = f"{type(exc).__name__}: {message}"
                    raise error(f"{path}: not a readable {what} (member {info.filename!r}: {message})") from None
    return arrays
