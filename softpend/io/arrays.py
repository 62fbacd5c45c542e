"""Reading ``.npz`` archives of plain arrays: never unpickling, every failure a named error."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

__all__ = ["read_npz"]

#: What ``numpy.load`` raises on a corrupt, truncated or hostile archive.
_READ_ERRORS = (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError, MemoryError, NotImplementedError, zlib.error)


def read_npz(path: str | Path, what: str, error: type[Exception] = ValueError) -> dict[str, np.ndarray]:
    """Every member of the ``.npz`` archive at ``path`` as an array (``allow_pickle=False``: object arrays
    are refused).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist (the message calls it ``what``).
    error
        If the archive cannot be read as plain arrays; the message names the file, ``what`` it should be and
        the reason.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no {what} at {path}")
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except _READ_ERRORS as exc:
        raise error(f"{path}: not a readable {what} ({type(exc).__name__}: {exc})") from None
