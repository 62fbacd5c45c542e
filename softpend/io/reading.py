"""Reading input files with a bound: regular files only, never more bytes than the format can have.

Every file softpend reads goes through :func:`open_regular_file` (or the readers built on it:
:func:`read_bytes_checked`, :func:`read_text_checked`, :func:`read_json_checked`, :func:`read_yaml_checked`,
:func:`read_json_object`), which

* refuses anything that is not a regular file -- a folder, a named pipe (FIFO), a socket, a device such as
  ``/dev/zero`` -- checked with ``os.stat`` *before* opening (opening a FIFO for reading blocks until a writer
  appears, and reading a device never ends), and again with ``os.fstat`` on the descriptor opened with
  ``O_NONBLOCK`` (a file swapped for a FIFO between the two cannot block the open);
* refuses a file larger than ``max_bytes``, the size the format can legitimately have, and reads at most
  ``max_bytes + 1`` bytes (a file that grows while it is read, or a pseudo file that reports size 0, is still
  bounded).

Zip archives (agent files, ``.npz`` arrays) are bounded member by member from their central directory before
any member is decompressed (:func:`check_zip_members`, :func:`read_zip_member`).  Every refusal is one line
that names the file and says why; a missing file is a :class:`FileNotFoundError`, anything else the caller's
``error`` class (``ValueError`` by default).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import stat
import zipfile
from pathlib import Path
from typing import Any, BinaryIO, Iterator, Mapping, Optional, Union

__all__ = [
    "LineDict",
    "LineList",
    "MAX_CONFIG_BYTES",
    "MAX_JSON_BYTES",
    "MAX_YAML_BYTES",
    "check_capture_path",
    "check_regular_file",
    "check_zip_members",
    "file_kind",
    "open_regular_file",
    "read_bytes_checked",
    "read_json_checked",
    "read_json_object",
    "read_text_checked",
    "read_yaml_checked",
    "read_zip_member",
    "yaml_line",
]

#: Largest configuration-like JSON document (a run's config.json, rod parameters, a calibration, markers,
#: a sidecar, PILCO and model metadata) [bytes]: 16 MiB, hundreds of times the size softpend writes.
MAX_CONFIG_BYTES = 16 * 2**20
#: Largest JSON log or record (a training log with one row per episode and evaluation) [bytes]: 256 MiB.
MAX_JSON_BYTES = 256 * 2**20
#: Largest YAML project file (``_toc.yml``, ``book/profiles.yml``, records) [bytes]: 4 MiB.
MAX_YAML_BYTES = 4 * 2**20

PathLike = Union[str, "os.PathLike[str]"]


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words (``"a folder"``, ``"a named pipe (FIFO)"``, ...)."""
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a named pipe (FIFO)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISREG(mode):
        return "a regular file"
    return "not a regular file"


def _described(what: str, path: Path) -> str:
    return f"{what} {path}" if what else str(path)


def check_regular_file(
    path: PathLike, what: str, max_bytes: Optional[int] = None, error: type[Exception] = ValueError
) -> os.stat_result:
    """``os.stat(path)`` if ``path`` is a regular file (symbolic links followed) of at most ``max_bytes``.

    Raises
    ------
    FileNotFoundError
        If nothing is at ``path`` (or a symbolic link there points nowhere).
    error
        If ``path`` is a folder, FIFO, socket or device, or larger than ``max_bytes``; the message names
        ``what``, the file and the reason.
    """
    path = Path(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{_described(what, path)}: no such file") from None
    except (OSError, ValueError) as exc:  # permission, a name too long, a NUL byte in the name
        raise error(f"{_described(what, path)}: cannot be read ({getattr(exc, 'strerror', None) or exc})") from None
    if not stat.S_ISREG(info.st_mode):
        raise error(f"{_described(what, path)} is {file_kind(info.st_mode)}, not a regular file")
    if max_bytes is not None and info.st_size > max_bytes:
        raise error(
            f"{_described(what, path)} has {info.st_size} bytes, more than the {max_bytes} a {what or 'file'} can have"
        )
    return info


@contextlib.contextmanager
def open_regular_file(
    path: PathLike, what: str, max_bytes: Optional[int] = None, error: type[Exception] = ValueError
) -> Iterator[BinaryIO]:
    """The regular file at ``path`` opened for binary reading (a context manager).

    Checked with :func:`check_regular_file` before opening, opened with ``O_NONBLOCK`` (so a FIFO swapped in
    after the check cannot block the open) and checked again on the descriptor.  The caller bounds its reads
    by ``max_bytes`` (:func:`read_bytes_checked` does)."""
    path = Path(path)
    check_regular_file(path, what, max_bytes, error)
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOCTTY", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise FileNotFoundError(f"{_described(what, path)}: no such file") from None
    except OSError as exc:
        raise error(f"{_described(what, path)}: cannot be opened ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise error(f"{_described(what, path)} is {file_kind(info.st_mode)}, not a regular file")
        if max_bytes is not None and info.st_size > max_bytes:
            raise error(
                f"{_described(what, path)} has {info.st_size} bytes, more than the {max_bytes} a "
                f"{what or 'file'} can have"
            )
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
        handle = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with handle:
        yield handle


def read_bytes_checked(path: PathLike, what: str, max_bytes: int, error: type[Exception] = ValueError) -> bytes:
    """The bytes of the regular file at ``path``, at most ``max_bytes`` of them (:func:`open_regular_file`);
    a file that turns out longer while it is read is refused, not truncated."""
    with open_regular_file(path, what, max_bytes, error) as handle:
        try:
            data = handle.read(max_bytes + 1)
        except OSError as exc:
            raise error(f"{_described(what, Path(path))}: cannot be read ({exc.strerror or exc})") from None
    if len(data) > max_bytes:
        raise error(f"{_described(what, Path(path))} has more than the {max_bytes} bytes a {what or 'file'} can have")
    return data


def read_text_checked(path: PathLike, what: str, max_bytes: int, error: type[Exception] = ValueError) -> str:
    """The UTF-8 text of the regular file at ``path`` (:func:`read_bytes_checked`); bytes that are not UTF-8
    are refused with the offset of the first."""
    data = read_bytes_checked(path, what, max_bytes, error)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{_described(what, Path(path))}: not UTF-8 text (byte {exc.start})") from None


def read_json_checked(
    path: PathLike, what: str, max_bytes: int = MAX_CONFIG_BYTES, error: type[Exception] = ValueError
) -> Any:
    """The JSON document in the regular file at ``path``; malformed or too deeply nested JSON is refused
    with the file, the line and the reason."""
    text = read_text_checked(path, what, max_bytes, error)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(
            f"{_described(what, Path(path))}, line {exc.lineno} column {exc.colno}: not valid JSON ({exc.msg})"
        ) from None
    except RecursionError:
        raise error(f"{_described(what, Path(path))}: not valid JSON (nested too deeply)") from None


def read_json_object(path: PathLike, max_bytes: int) -> Optional[dict]:
    """The JSON object in the regular file at ``path``, or ``None`` when it is missing, not a regular file,
    larger than ``max_bytes``, not JSON or not an object (for questions such as "is this file one of ours?"
    that must neither fail nor block)."""
    try:
        data = read_json_checked(path, "", max_bytes)
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


class LineDict(dict):
    """A YAML mapping read by :func:`read_yaml_checked` with ``lines=True``: ``line`` is the 1-based line where
    it starts and ``lines[key]`` the line of each key (for messages about a document of the wrong shape)."""

    line: int = 0
    lines: dict

    def line_of(self, key: Any) -> int:
        """The line of ``key`` (the mapping's own line if it has no such key)."""
        return getattr(self, "lines", {}).get(key, self.line)


class LineList(list):
    """A YAML sequence read with ``lines=True``: ``line`` is where it starts, ``lines[i]`` each item's line."""

    line: int = 0
    lines: list


def _line_loader():
    import yaml

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            mapping = LineDict(super().construct_mapping(node, deep=True))
            mapping.line = node.start_mark.line + 1
            mapping.lines = {}
            for key_node, _ in node.value:
                try:
                    mapping.lines[self.construct_object(key_node, deep=True)] = key_node.start_mark.line + 1
                except TypeError:  # an unhashable key: reported by the base constructor already
                    pass
            return mapping

        def construct_sequence(self, node, deep=False):
            sequence = LineList(super().construct_sequence(node, deep=True))
            sequence.line = node.start_mark.line + 1
            sequence.lines = [item.start_mark.line + 1 for item in node.value]
            return sequence

    Loader.add_constructor("tag:yaml.org,2002:map", Loader.construct_mapping)
    Loader.add_constructor("tag:yaml.org,2002:seq", Loader.construct_sequence)
    return Loader


def yaml_line(node: Any, key: Any = None, default: int = 1) -> int:
    """The line of ``key`` in a mapping (or item ``key`` of a sequence) read with ``lines=True``, or of
    ``node`` itself; ``default`` for values without lines (scalars)."""
    if isinstance(node, LineDict):
        return node.line_of(key) if key is not None else node.line
    if isinstance(node, LineList):
        if isinstance(key, int) and 0 <= key < len(node.lines):
            return node.lines[key]
        return node.line
    return default


def read_yaml_checked(
    path: PathLike, what: str, max_bytes: int = MAX_YAML_BYTES, error: type[Exception] = ValueError, lines: bool = False
) -> Any:
    """The YAML document in the regular file at ``path`` (``yaml.safe_load``: plain data, no Python
    objects); a syntax error is refused with the file, the line and the parser's reason.  With ``lines``,
    mappings and sequences come back as :class:`LineDict` / :class:`LineList`, which know their lines
    (:func:`yaml_line`), for messages about a document of the wrong shape."""
    import yaml

    text = read_text_checked(path, what, max_bytes, error)
    try:
        return yaml.load(text, Loader=_line_loader()) if lines else yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f", line {mark.line + 1} column {mark.column + 1}" if mark is not None else ""
        reason = " ".join(str(exc.problem or exc.context or "invalid syntax").split())
        raise error(f"{_described(what, Path(path))}{where}: not valid YAML ({reason})") from None
    except (yaml.YAMLError, RecursionError) as exc:
        raise error(
            f"{_described(what, Path(path))}: not valid YAML ({' '.join(str(exc).split()) or type(exc).__name__})"
        ) from None


def check_capture_path(name: str, source: str) -> None:
    """A ``--camera`` argument (a device index, a stream URL or a path) that names an existing path must be a
    regular file (a video or an image) or a character device (a camera such as ``/dev/video0``): a FIFO, a
    folder or a socket would block the capture or never deliver a frame, and is refused naming ``name``."""
    try:
        info = os.stat(source)
    except (OSError, ValueError):  # not a path (an index, a URL) or nothing there: the capture reports it
        return
    if not (stat.S_ISREG(info.st_mode) or stat.S_ISCHR(info.st_mode)):
        raise ValueError(f"{name} {source} is {file_kind(info.st_mode)}, not a video file or a camera device")


# ---------------------------------------------------------------------------------------- zip archives
def check_zip_members(
    archive: zipfile.ZipFile,
    path: PathLike,
    what: str,
    max_member_bytes: Union[int, Mapping[str, int]],
    max_total_bytes: Optional[int] = None,
    error: type[Exception] = ValueError,
) -> None:
    """Refuse ``archive`` (opened from ``path``) if a member would unpack to more than its bound, or all
    members together to more than ``max_total_bytes`` -- from the central directory, before any member is
    decompressed (``zipfile`` never unpacks a member beyond the size its directory entry states).

    ``max_member_bytes`` is one bound for every member, or a bound per member name (``"*"``: the bound of a
    name not listed; without it such a member is refused)."""
    total = 0
    for info in archive.infolist():
        if isinstance(max_member_bytes, Mapping):
            bound = max_member_bytes.get(info.filename, max_member_bytes.get("*"))
            if bound is None:
                raise error(f"{_described(what, Path(path))}: unexpected member {info.filename!r}")
        else:
            bound = max_member_bytes
        if info.file_size > bound:
            raise error(
                f"{_described(what, Path(path))}: member {info.filename!r} would unpack to {info.file_size} "
                f"bytes, more than the {bound} it can have"
            )
        total += info.file_size
    if max_total_bytes is not None and total > max_total_bytes:
        raise error(
            f"{_described(what, Path(path))}: its members would unpack to {total} bytes, more than the "
            f"{max_total_bytes} a {what or 'file'} can have"
        )


def read_zip_member(
    archive: zipfile.ZipFile, name: str, path: PathLike, what: str, max_bytes: int, error: type[Exception] = ValueError
) -> bytes:
    """The bytes of member ``name`` of ``archive`` (opened from ``path``), refused beyond ``max_bytes`` by its
    directory entry and read with that bound.  ``KeyError`` if there is no such member."""
    info = archive.getinfo(name)
    if info.file_size > max_bytes:
        raise error(
            f"{_described(what, Path(path))}: member {name!r} would unpack to {info.file_size} bytes, more "
            f"than the {max_bytes} it can have"
        )
    with archive.open(info) as member:
        data = member.read(max_bytes + 1)
    if len(data) > max_bytes:  # pragma: no cover - zipfile stops at the directory's size
        raise error(f"{_described(what, Path(path))}: member {name!r} holds more than {max_bytes} bytes")
    return data
