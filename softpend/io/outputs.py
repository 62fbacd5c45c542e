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

__all__ = [
    "MANIFEST",
    "Outputs",
    "atomic_write",
    "check_output_file",
    "check_output_folder",
    "finite_or_none",
    "json_text",
    "output_name",
    "read_json_object",
    "written_by_softpend",
]


def read_json_object(path: str | Path, max_bytes: int) -> Optional[dict]:
    """The JSON object in the file at ``path``, or None when it is missing, not a regular file, larger than
    ``max_bytes``, not JSON or not an object (for ownership checks: is this file one of ours?); never blocks
    (:func:`softpend.io.reading.read_json_object`)."""
    from softpend.io.reading import read_json_object as read

    return read(path, max_bytes)


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


def check_output_file(
    path: str | Path, *, what: str = "output", owned: Optional[Callable[[Path], bool]] = None
) -> Path:
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
        written, or it exists and ``owned`` does not claim it; or if ``path`` is empty.
    """
    _not_empty(path, what)
    path = Path(path)
    if os.path.lexists(path):
        if path.is_dir():
            raise ValueError(f"{what} {path} is a folder")
        if path.is_symlink() or not path.is_file():
            raise ValueError(f"{what} {path} exists and is not a regular file; refusing to replace it")
        if owned is None or not _claims(owned, path):
            raise ValueError(
                f"{what} {path} exists and is not a file this command wrote; refusing to overwrite it "
                "(remove it or choose another path)"
            )
    _check_parent(path, what)
    return path


def check_output_folder(
    path: str | Path, *, what: str = "output folder", owned: Optional[Callable[[Path], bool]] = None
) -> Path:
    """Check, before any work, that ``path`` can be created as a folder or is an empty folder or one of ours.

    ``owned(path) -> bool`` says whether an existing non-empty folder is one the caller wrote (and may write
    into); without it only a missing or empty folder passes.  Raises ``ValueError`` otherwise, or when the
    folder cannot be created or written, or ``path`` is empty.
    """
    _not_empty(path, what)
    path = Path(path)
    if os.path.lexists(path):
        if not path.is_dir():
            raise ValueError(f"{what} {path} exists and is not a folder")
        if any(path.iterdir()) and (owned is None or not _claims(owned, path)):
            raise ValueError(
                f"{what} {path} is not empty and is not a folder this command wrote; refusing to "
                "write into it (choose another path)"
            )
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


# ---------------------------------------------------------------------------------------------------- one writer
#: The manifest a command keeps in each output folder it writes: the name and SHA-256 of every file it wrote
#: there.  A file is the command's own (and may be replaced) only while its bytes are the ones recorded.
MANIFEST = ".softpend-outputs.json"
_MANIFEST_KIND = "softpend-outputs"
_MANIFEST_MAX_BYTES = 10**7


def output_name(text: str | Path, suffix: str, what: str = "output") -> Path:
    """``text`` as a file path ending in ``suffix`` (appended when missing).

    Raises ``ValueError`` for an empty name, a name that ends in a path separator or names a folder (``.``,
    ``..``), and a name that is the suffix alone (``".npz"`` would write the hidden file ``.npz``, ``""`` the
    hidden ``.npz``): the file would not be where the user looks.
    """
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


def _sha256(path: Path) -> str:
    import hashlib

    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _read_manifest(folder: Path) -> Optional[dict]:
    """The manifest of ``folder`` (``{}`` when there is none), or None when ``MANIFEST`` there is not ours."""
    path = folder / MANIFEST
    if not os.path.lexists(path):
        return {}
    data = read_json_object(path, _MANIFEST_MAX_BYTES)
    if data is None or data.get("kind") != _MANIFEST_KIND or not isinstance(data.get("files"), dict):
        return None
    return data["files"]


def written_by_softpend(path: str | Path) -> bool:
    """Whether ``path`` is a file a softpend command wrote and nobody changed since: the manifest of its folder
    records it with the SHA-256 of its current bytes."""
    path = Path(path)
    files = _read_manifest(path.parent)
    entry = (files or {}).get(path.name)
    if not isinstance(entry, dict) or not isinstance(entry.get("sha256"), str):
        return False
    try:
        return path.is_file() and not path.is_symlink() and _sha256(path) == entry["sha256"]
    except OSError:
        return False


def _not_empty(path: str | Path, what: str) -> None:
    """``ValueError`` for an empty path (``Path("")`` is the current folder: never what an empty ``--out`` meant)."""
    if not os.fspath(path).strip():
        raise ValueError(f"{what}: the path is empty")


def _unfinished_log(path: Path) -> bool:
    """Whether ``path`` is a crash-safe sample log the manifest records as being written (:meth:`Outputs.live`)
    by a command that did not finish (it never reached :meth:`Outputs.done`)."""
    entry = (_read_manifest(path.parent) or {}).get(path.name)
    if not isinstance(entry, dict) or entry.get("sha256", "") is not None:
        return False
    if path.is_symlink() or not path.is_file():  # a FIFO would block the read
        return False
    try:
        with open(path, "rb") as handle:
            return handle.read(18) == b"# softpend-log v1 "
    except OSError:
        return False


class Outputs:
    """The files one command writes: all planned and checked before any work, each then written atomically.

    A command names every file it will write with :meth:`file` (a file of its own, e.g. ``--out FILE``) or
    :meth:`folder` (files in an output folder) before it starts the work; each check raises ``ValueError``
    naming the file when the path cannot be written or an existing file there is not one the command wrote.
    "Written by the command" is known from the manifest (:data:`MANIFEST`) the writer keeps in each folder it
    writes into: a file is the command's only while its bytes are the ones recorded (a user's file, or one the
    user edited or put in its place, is never replaced); ``owned`` predicates also claim files by their content
    (a dataset, a model of an earlier version).  :meth:`write_text`, :meth:`write_bytes`, :meth:`write_json` and
    :meth:`open` write through :func:`atomic_write` (a temporary file in the same folder, renamed over the
    target when complete) and record the file in the manifest; :meth:`live` prepares a file that is written in
    place while the command runs (a crash-safe :class:`~softpend.io.samplelog.SampleLog`) and :meth:`done`
    records it once closed.
    """

    def __init__(self) -> None:
        self._planned: dict[Path, tuple[str, Optional[Callable[[Path], bool]]]] = {}

    # -------------------------------------------------------------- planning
    def file(self, path: str | Path, what: str = "output", owned: Optional[Callable[[Path], bool]] = None) -> Path:
        """Plan and check the file ``path`` (see the class docstring); returns it as a ``Path``."""
        _not_empty(path, what)
        path = Path(path)
        self._check(path, what, owned)
        self._planned[path] = (what, owned)
        return path

    def folder(
        self,
        path: str | Path,
        names: tuple[str, ...] | list[str],
        what: str = "output folder",
        owned: Optional[Callable[[Path], bool]] = None,
    ) -> Path:
        """Plan and check the folder ``path`` (created when missing) and the files ``names`` in it; the folder
        may hold other files (they are left alone), not one of ``names`` that the command did not write."""
        _not_empty(path, what)
        path = Path(path)
        if os.path.lexists(path) and not path.is_dir():
            raise ValueError(f"{what} {path} exists and is not a folder")
        if path.is_dir() and _read_manifest(path) is None:
            raise ValueError(
                f"{what} {path}: {path / MANIFEST} is not a softpend manifest; refusing to write "
                "into this folder (choose another path)"
            )
        for name in names:
            self.file(path / name, f"{what} {path}: file", owned)
        return path

    def _check(self, path: Path, what: str, owned: Optional[Callable[[Path], bool]]) -> None:
        if path.name == MANIFEST:
            raise ValueError(f"{what} {path}: {MANIFEST} is the name of softpend's manifest; choose another name")
        if os.path.lexists(path) and path.is_dir() and not path.is_symlink():
            raise ValueError(f"{what} {path} is a folder")
        if path.parent.is_dir() and _read_manifest(path.parent) is None:
            raise ValueError(
                f"{what} {path}: {path.parent / MANIFEST} is not a softpend manifest; refusing to "
                "write into this folder (choose another path)"
            )
        check_output_file(
            path,
            what=what,
            owned=lambda p: written_by_softpend(p) or _unfinished_log(p) or (owned is not None and owned(p)),
        )

    def _planned_entry(self, path: Path) -> tuple[str, Optional[Callable[[Path], bool]]]:
        path = Path(path)
        if path not in self._planned:
            raise ValueError(f"{path} was not planned before the work (Outputs.file or Outputs.folder)")
        return self._planned[path]

    # -------------------------------------------------------------- writing
    @contextlib.contextmanager
    def open(self, path: str | Path, mode: str = "wb") -> Iterator[Any]:
        """:func:`atomic_write` of the planned ``path`` (checked again: a file that appeared there during the
        work is not replaced), recorded in the folder's manifest."""
        path = Path(path)
        what, owned = self._planned_entry(path)
        self._check(path, what, owned)
        with atomic_write(path, mode) as handle:
            yield handle
        _record(path, _sha256(path))

    def write_bytes(self, path: str | Path, data: bytes) -> Path:
        with self.open(path, "wb") as handle:
            handle.write(data)
        return Path(path)

    def write_text(self, path: str | Path, text: str) -> Path:
        with self.open(path, "w") as handle:
            handle.write(text)
        return Path(path)

    def write_json(self, path: str | Path, value: Any, indent: Optional[int] = 2) -> Path:
        """``value`` as valid JSON (:func:`json_text`: non-finite numbers as ``null``) and a newline."""
        return self.write_text(path, json_text(value, indent=indent) + "\n")

    def live(self, path: str | Path) -> Path:
        """Prepare the planned ``path`` for a file written in place while the command runs (a crash-safe log):
        an earlier file of the command's there is removed (checked again first), the folder is created, and
        the manifest records the name as being written.  Call :meth:`done` when the file is closed."""
        path = Path(path)
        what, owned = self._planned_entry(path)
        self._check(path, what, owned)
        if os.path.lexists(path):
            path.unlink()
        path.parent.mkdir(parents=True, exist_ok=True)
        _record(path, None)
        return path

    def done(self, path: str | Path) -> None:
        """Record the planned file ``path``, now complete, in the manifest: one prepared with :meth:`live`, or one
        that a format's own atomic writer wrote (a dataset, a model, an agent)."""
        path = Path(path)
        if path.is_file():
            _record(path, _sha256(path))


def _record(path: Path, sha256: Optional[str]) -> None:
    """Record ``path`` (its SHA-256, or None: being written) in the manifest of its folder, atomically."""
    files = _read_manifest(path.parent)
    if files is None:
        raise ValueError(f"{path.parent / MANIFEST} is not a softpend manifest; refusing to replace it")
    files = dict(files)
    files[path.name] = {"sha256": sha256}
    with atomic_write(path.parent / MANIFEST, "w") as handle:
        handle.write(json.dumps({"kind": _MANIFEST_KIND, "files": files}, indent=1, sort_keys=True) + "\n")
