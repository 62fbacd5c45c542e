"""Output files: checked before the work, written atomically, never replacing a file softpend did not write;
:func:`json_text` is JSON with non-finite numbers as ``null``."""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

import numpy as np

from softpend.io.reading import read_json_object


def _check_parent(path: Path, what: str, shown: Optional[Path] = None) -> None:
    """Refuse ``path`` (shown as ``shown``) unless its folder exists or can be created, and is writable."""
    ancestor, shown = path.parent, shown or path
    while not os.path.lexists(ancestor) and ancestor.parent != ancestor:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ValueError(f"{what} {shown}: {ancestor} is not a folder, so {path.parent} cannot be created")
    try:  # the only reliable writability test (permissions, read-only mounts, pseudo file systems, root)
        with tempfile.NamedTemporaryFile(dir=ancestor, prefix=".softpend-probe-"):
            pass
    except OSError as exc:
        raise ValueError(f"{what} {shown}: cannot write in {ancestor}: {exc.strerror or exc}") from None


def _not_empty(path: str | Path, what: str, folder: bool = False) -> Path:
    """``path`` as a ``Path``; ``ValueError`` when empty (``Path("")`` is the current folder) or, for a ``folder``,
    when something else is there."""
    if not os.fspath(path).strip():
        raise ValueError(f"{what}: the path is empty")
    if folder and os.path.lexists(path) and not os.path.isdir(path):
        raise ValueError(f"{what} {path} exists and is not a folder")
    return Path(path)


def _claims(owned: Optional[Callable[[Path], bool]], path: Path) -> bool:
    try:
        return owned is not None and bool(owned(path))
    except (OSError, ValueError, KeyError, TypeError, RecursionError, MemoryError):
        return False


def check_output_folder(
    path: str | Path, *, what: str = "output folder", owned: Optional[Callable[[Path], bool]] = None
) -> Path:
    """Check, before any work, that ``path`` can be created as a folder, or is empty, or is one that
    ``owned(path)`` claims; ``ValueError`` otherwise."""
    path = _not_empty(path, what, folder=True)
    if os.path.lexists(path) and any(path.iterdir()) and not _claims(owned, path):
        raise ValueError(
            f"{what} {path} is not empty and is not a folder this command wrote; refusing to "
            "write into it (choose another path)"
        )
    _check_parent(path / "x", what, path)
    return path


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "wb") -> Iterator[Any]:
    """A temporary file next to ``path`` (``mode`` ``"wb"`` or ``"w"``, UTF-8) that is synced and renamed over
    ``path`` on a clean exit and removed on an exception; missing parent folders are created."""
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
    """``value`` as plain JSON data (NumPy values as Python ones), every non-finite float as ``None``."""
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
    """``json.dumps`` of :func:`finite_or_none` ``(value)``: valid JSON, non-finite numbers as ``null``."""
    return json.dumps(finite_or_none(value), allow_nan=False, **kwargs)


def output_name(text: str | Path, suffix: str, what: str = "output") -> Path:
    """``text`` as a file path ending in ``suffix`` (appended when missing); ``ValueError`` for an empty name,
    a folder (``/``, ``.``, ``..``) or the suffix alone."""
    raw = os.fspath(text)
    if not raw.strip():
        raise ValueError(f"{what} name is empty")
    if raw.endswith(("/", os.sep)) or Path(raw).name in ("", ".", ".."):
        raise ValueError(f"{what} {raw!r} names a folder, not a file")
    name = Path(raw).name
    stem = name[: -len(suffix)] if suffix and name.endswith(suffix) else name
    if stem in ("", "."):
        raise ValueError(f"{what} {raw!r} has no name before its suffix {suffix!r}")
    return Path(raw if raw.endswith(suffix) else raw + suffix)


#: The manifest a command keeps in each output folder: the SHA-256 of every file it wrote there (None: a log
#: being written).  A file is the command's own (and may be replaced) only while its bytes are the recorded ones.
MANIFEST = ".softpend-outputs.json"
_MANIFEST_KIND = "softpend-outputs"


def _sha256(path: Path) -> str:
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def _read_manifest(folder: Path) -> Optional[dict]:
    """The manifest of ``folder`` (``{}`` when there is none), or None when ``MANIFEST`` there is not ours."""
    path = folder / MANIFEST
    if not os.path.lexists(path):
        return {}
    data = read_json_object(path, 10**7)
    if data is None or data.get("kind") != _MANIFEST_KIND or not isinstance(data.get("files"), dict):
        return None
    return data["files"]


def _ours(path: Path) -> bool:
    """Whether the manifest records ``path`` with its SHA-256, or as a sample log still being written."""
    entry = (_read_manifest(path.parent) or {}).get(path.name)
    if not isinstance(entry, dict) or path.is_symlink() or not path.is_file():  # a FIFO would block the read
        return False
    if isinstance(entry.get("sha256"), str):  # an OSError reading it: not ours (_claims)
        return _sha256(path) == entry["sha256"]
    if "sha256" in entry and entry["sha256"] is None:
        with open(path, "rb") as handle:
            return handle.read(18) == b"# softpend-log v1 "
    return False


def _record(path: Path, sha256: Optional[str]) -> None:
    """Record ``path`` (its SHA-256, or None: being written) in the manifest of its folder, atomically."""
    if (files := _read_manifest(path.parent)) is None:
        raise ValueError(f"{path.parent / MANIFEST} is not a softpend manifest; refusing to replace it")
    data = {"kind": _MANIFEST_KIND, "files": {**files, path.name: {"sha256": sha256}}}
    with atomic_write(path.parent / MANIFEST, "w") as handle:
        handle.write(json.dumps(data, indent=1, sort_keys=True) + "\n")


class Outputs:
    """The files one command writes: planned and checked before the work (:meth:`file`, :meth:`folder`), then
    written atomically or as a live log (:meth:`live`, :meth:`done`) and recorded in the folder's :data:`MANIFEST`."""

    def __init__(self) -> None:
        self._planned: dict[Path, str] = {}

    def file(self, path: str | Path, what: str = "output") -> Path:
        """Plan and check the file ``path``; returns it as a ``Path``."""
        path = _not_empty(path, what)
        self._check(path, what)
        self._planned[path] = what
        return path

    def folder(self, path: str | Path, names: tuple[str, ...] | list[str], what: str = "output folder") -> Path:
        """Plan and check the folder ``path`` and the files ``names`` in it (other files there are left alone)."""
        path = _not_empty(path, what, folder=True)
        self._check_manifest(path, what, path)
        for name in names:
            self.file(path / name, f"{what} {path}: file")
        return path

    @staticmethod
    def _check_manifest(folder: Path, what: str, path: Path) -> None:
        if folder.is_dir() and _read_manifest(folder) is None:
            raise ValueError(
                f"{what} {path}: {folder / MANIFEST} is not a softpend manifest; refusing to write into this folder "
                "(choose another path)"
            )

    def _check(self, path: Path, what: str) -> None:
        """``path`` can be written as a new file or replace one of ours (missing folders will be created)."""
        if path.name == MANIFEST:
            raise ValueError(f"{what} {path}: {MANIFEST} is the name of softpend's manifest; choose another name")
        exists = os.path.lexists(path)
        if exists and path.is_dir():
            raise ValueError(f"{what} {path} is a folder")
        if exists and (path.is_symlink() or not path.is_file()):
            raise ValueError(f"{what} {path} exists and is not a regular file; refusing to replace it")
        self._check_manifest(path.parent, what, path)
        if exists and not _claims(_ours, path):
            raise ValueError(
                f"{what} {path} exists and is not a file this command wrote; refusing to overwrite it "
                "(remove it or choose another path)"
            )
        _check_parent(path, what)

    def _checked_again(self, path: str | Path) -> Path:
        """The planned ``path``, checked again (a file that appeared there during the work is not replaced)."""
        path = Path(path)
        if path not in self._planned:
            raise ValueError(f"{path} was not planned before the work (Outputs.file or Outputs.folder)")
        self._check(path, self._planned[path])
        return path

    @contextlib.contextmanager
    def open(self, path: str | Path, mode: str = "wb") -> Iterator[Any]:
        """:func:`atomic_write` of the planned ``path``, recorded in the folder's manifest."""
        path = self._checked_again(path)
        with atomic_write(path, mode) as handle:
            yield handle
        _record(path, _sha256(path))

    def write_text(self, path: str | Path, text: str) -> Path:
        with self.open(path, "w") as handle:
            handle.write(text)
        return Path(path)

    def write_json(self, path: str | Path, value: Any) -> Path:
        """``value`` as indented :func:`json_text` and a newline."""
        return self.write_text(path, json_text(value, indent=2) + "\n")

    def live(self, path: str | Path) -> Path:
        """Prepare the planned ``path`` for a file written in place while the command runs: an earlier file of
        ours there is removed, the folder created, and the manifest records the name as being written."""
        path = self._checked_again(path)
        if os.path.lexists(path):
            path.unlink()
        path.parent.mkdir(parents=True, exist_ok=True)
        _record(path, None)
        return path

    def done(self, path: str | Path) -> None:
        """Record the complete file ``path`` (from :meth:`live` or a format's own atomic writer) in the manifest."""
        path = Path(path)
        if path.is_file():
            _record(path, _sha256(path))
