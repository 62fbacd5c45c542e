"""Output files written without costing the user a file, and JSON that is always valid JSON.

A command checks its output paths with :func:`check_output_file` / :func:`check_output_folder` *before* it
starts the work (so an unwritable path, a parent that is a file, or a file of someone else's that would be
overwritten is reported up front, not after an hour of training), then writes each file through
:func:`atomic_write` (a temporary file in the same folder, renamed over the target only once it is
complete: an interrupted write leaves the old file as it was).  :func:`json_text` is ``json.dumps`` with
non-finite floats written as ``null`` (``json.dumps`` would write ``NaN``/``Infinity``, which is not JSON).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

import numpy as np

__all__ = ["atomic_write", "check_output_file", "check_output_folder", "finite_or_none", "json_text", "read_json_object"]


def read_json_object(path: str | Path, max_bytes: int) -> Optional[dict]:
    """The JSON object in the file at ``path``, or None when it is missing, larger than ``max_bytes``, not
    JSON or not an object (for ownership checks: is this file one of ours?)."""
    path = Path(path)
    try:
        if path.stat().st_size > max_bytes:
            return None
        data = json.loads(path.read_text())
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists."""
    probe = path
    while not os.path.lexists(probe):
        if probe.parent == probe:
            break
        probe = probe.parent
    return probe


def _check_parent(path: Path, what: str) -> None:
    """The folder that will hold ``path`` exists or can be created, and a file can be created in it."""
    ancestor = _nearest_existing(path.parent)
    if not ancestor.is_dir():
        raise ValueError(f"{what} {path}: {ancestor} is not a folder, so {path.parent} cannot be created")
    try:  # the only reliable writability test (permissions, read-only mounts, pseudo file systems, root)
        with tempfile.NamedTemporaryFile(dir=ancestor, prefix=".softpend-probe-"):
            pass
    except OSError as exc:
        raise ValueError(f"{what} {path}: cannot write in {ancestor}: {exc.strerror or exc}") from None


def check_output_file(path: str | Path, *, what: str = "output", owned: Optional[Callable[[Path], bool]] = None) -> Path:
    """Check, before any work, that ``path`` can be written as a new file or replace a file of ours.

    Parameters
    ----------
    path : str or Path
        The file to be written (missing parent folders will be created).
    what : str
        What the file is, for the messages (``"dataset"``, ``"model weights"``).
    owned : callable, optional
        ``owned(path) -> bool``: whether an existing file at ``path`` is one the caller wrote (and may
        replace).  Without it an existing file is never replaced.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        If ``path`` is a folder or not a regular file, its parent cannot be created (an ancestor is a file) or
        written, or it exists and ``owned`` does not claim it.
    """
    path = Path(path)
    if os.path.lexists(path):
        if path.is_dir():
            raise ValueError(f"{what} {path} is a folder")
        if path.is_symlink() or not path.is_file():
            raise ValueError(f"{what} {path} exists and is not a regular file; refusing to replace it")
        if owned is None or not _claims(owned, path):
            raise ValueError(f"{what} {path} exists and is not a file this command wrote; refusing to overwrite it "
                             "(remove it or choose another path)")
    _check_parent(path, what)
    return path


def check_output_folder(path: str | Path, *, what: str = "output folder", owned: Optional[Callable[[Path], bool]] = None) -> Path:
    """Check, before any work, that ``path`` can be created as a folder or is an empty folder or one of ours.

    ``owned(path) -> bool`` says whether an existing non-empty folder is one the caller wrote (and may write
    into); without it only a missing or empty folder passes.  Raises ``ValueError`` otherwise, or when the
    folder cannot be created or written.
    """
    path = Path(path)
    if os.path.lexists(path):
        if not path.is_dir():
            raise ValueError(f"{what} {path} exists and is not a folder")
        if any(path.iterdir()) and (owned is None or not _claims(owned, path)):
            raise ValueError(f"{what} {path} is not empty and is not a folder this command wrote; refusing to "
                             "write into it (choose another path)")
        try:
            with tempfile.NamedTemporaryFile(dir=path, prefix=".softpend-probe-"):
                pass
        except OSError as exc:
            raise ValueError(f"{what} {path}: cannot write in it: {exc.strerror or exc}") from None
        return path
    _check_parent(path / "x", what)
    return path


def _claims(owned: Callable[[Path], bool], path: Path) -> bool:
    try:
        return bool(owned(path))
    except (OSError, ValueError, KeyError, TypeError, RecursionError, MemoryError):
        return False


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "wb") -> Iterator[Any]:
    """Open a temporary file next to ``path`` for writing; on a clean exit it is flushed to disk and renamed
    over ``path`` (missing parent folders are created), on an exception it is removed and ``path`` is left as
    it was.  ``mode`` is ``"wb"`` or ``"w"`` (UTF-8 text)."""
    if mode not in ("wb", "w"):
        raise ValueError(f"mode must be 'wb' or 'w', got {mode!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    try:
        with os.fdopen(fd, mode, encoding="utf-8" if mode == "w" else None) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def finite_or_none(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, +-inf) replaced by ``None``, through dicts, lists and
    tuples; NumPy scalars become Python numbers and NumPy arrays lists."""
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite_or_none(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def json_text(value: Any, **kwargs: Any) -> str:
    """``json.dumps(finite_or_none(value), allow_nan=False, **kwargs)``: valid JSON, non-finite numbers as
    ``null``."""
    return json.dumps(finite_or_none(value), allow_nan=False, **kwargs)
