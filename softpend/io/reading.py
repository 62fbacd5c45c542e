"""Bounded reads of input files: regular files only (checked before and after a non-blocking open), never more
bytes than the format can have, zip members bounded by the central directory; each refusal one line."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import stat
import zipfile
from pathlib import Path
from typing import Any, BinaryIO, Iterator, Optional, Union

#: Largest configuration-like JSON document (a run's config, rod parameters, a calibration, a sidecar) [bytes].
MAX_CONFIG_BYTES = 16 * 2**20
#: Largest JSON log or record [bytes].
MAX_JSON_BYTES = 256 * 2**20
#: Largest YAML project file [bytes].
MAX_YAML_BYTES = 4 * 2**20

PathLike = Union[str, "os.PathLike[str]"]

_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISREG, "a regular file"),
)


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words (``"a folder"``, ``"a named pipe (FIFO)"``, ...)."""
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def _described(what: str, path: PathLike) -> str:
    return f"{what} {Path(path)}" if what else str(Path(path))


def _os_call(call: Any, path: PathLike, what: str, doing: str, error: type[Exception]) -> Any:
    """``call()``, its failure as ``FileNotFoundError`` or ``error`` naming the file."""
    try:
        return call()
    except FileNotFoundError:
        raise FileNotFoundError(f"{_described(what, path)}: no such file") from None
    except (OSError, ValueError) as exc:  # permission, a name too long, a NUL byte in the name
        raise error(f"{_described(what, path)}: cannot be {doing} ({getattr(exc, 'strerror', None) or exc})") from None


def _check_stat(
    info: os.stat_result, path: PathLike, what: str, max_bytes: Optional[int], error: type[Exception]
) -> None:
    if not stat.S_ISREG(info.st_mode):
        raise error(f"{_described(what, path)} is {file_kind(info.st_mode)}, not a regular file")
    if max_bytes is not None and info.st_size > max_bytes:
        raise error(
            f"{_described(what, path)} has {info.st_size} bytes, more than the {max_bytes} a {what or 'file'} can have"
        )


def check_regular_file(
    path: PathLike, what: str, max_bytes: Optional[int] = None, error: type[Exception] = ValueError
) -> os.stat_result:
    """``os.stat(path)`` if ``path`` is a regular file (links followed) of at most ``max_bytes``; else
    ``FileNotFoundError`` (nothing there) or ``error`` naming ``what``, the file and the reason."""
    path = Path(path)
    info = _os_call(lambda: os.stat(path), path, what, "read", error)
    _check_stat(info, path, what, max_bytes, error)
    return info


def open_checked_fd(
    path: PathLike, flags: int, what: str, max_bytes: Optional[int] = None, error: type[Exception] = ValueError
) -> int:
    """``os.open(path, flags)`` made non-blocking for the open, so a FIFO cannot block it, and refused (closed)
    unless the descriptor is a regular file of at most ``max_bytes``."""
    flags |= os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOCTTY", 0)
    fd = _os_call(lambda: os.open(path, flags, 0o644), path, what, "opened", error)
    try:
        _check_stat(os.fstat(fd), path, what, max_bytes, error)
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    except BaseException:
        os.close(fd)
        raise
    return fd


@contextlib.contextmanager
def open_regular_file(
    path: PathLike, what: str, max_bytes: Optional[int] = None, error: type[Exception] = ValueError
) -> Iterator[BinaryIO]:
    """The regular file at ``path`` (checked before and after opening) for binary reads bounded by the caller."""
    check_regular_file(path, what, max_bytes, error)
    with os.fdopen(open_checked_fd(path, os.O_RDONLY, what, max_bytes, error), "rb") as handle:
        yield handle


def read_bytes_checked(path: PathLike, what: str, max_bytes: int, error: type[Exception] = ValueError) -> bytes:
    """The bytes of the regular file at ``path``, refused beyond ``max_bytes`` (also if it grows while read)."""
    with open_regular_file(path, what, max_bytes, error) as handle:
        data = _os_call(lambda: handle.read(max_bytes + 1), path, what, "read", error)
    if len(data) > max_bytes:
        raise error(f"{_described(what, path)} has more than the {max_bytes} bytes a {what or 'file'} can have")
    return data


def read_text_checked(path: PathLike, what: str, max_bytes: int) -> str:
    """The UTF-8 text of the regular file at ``path`` (:func:`read_bytes_checked`)."""
    data = read_bytes_checked(path, what, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{_described(what, path)}: not UTF-8 text (byte {exc.start})") from None


def read_json_checked(path: PathLike, what: str, max_bytes: int = MAX_CONFIG_BYTES) -> Any:
    """The JSON document in the regular file at ``path``; invalid JSON is refused with the file and line."""
    text = read_text_checked(path, what, max_bytes)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(
            f"{_described(what, path)}, line {exc.lineno} column {exc.colno}: not valid JSON ({exc.msg})"
        ) from None
    except RecursionError:
        raise ValueError(f"{_described(what, path)}: not valid JSON (nested too deeply)") from None


def read_json_object(path: PathLike, max_bytes: int) -> Optional[dict]:
    """The JSON object in the regular file at ``path``, or ``None`` when there is none (never fails or blocks)."""
    try:
        data = read_json_checked(path, "", max_bytes)
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


class _LineDict(dict):
    line: int = 0
    lines: dict


class _LineList(list):
    line: int = 0
    lines: dict


def _line_loader():
    import yaml

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            mapping = _LineDict(super().construct_mapping(node, deep=True))  # refuses unhashable keys
            mapping.line = node.start_mark.line + 1
            mapping.lines = {self.construct_object(key, deep=True): key.start_mark.line + 1 for key, _ in node.value}
            return mapping

        def construct_sequence(self, node, deep=False):
            sequence = _LineList(super().construct_sequence(node, deep=True))
            sequence.line = node.start_mark.line + 1
            sequence.lines = {i: item.start_mark.line + 1 for i, item in enumerate(node.value)}
            return sequence

    Loader.add_constructor("tag:yaml.org,2002:map", Loader.construct_mapping)
    Loader.add_constructor("tag:yaml.org,2002:seq", Loader.construct_sequence)
    return Loader


def yaml_line(node: Any, key: Any = None, default: int = 1) -> int:
    """The line of ``key`` (or of ``node`` itself) in ``node`` read with ``lines=True``; ``default`` for scalars."""
    if not isinstance(node, (_LineDict, _LineList)):
        return default
    return node.line if key is None else node.lines.get(key, node.line)


def read_yaml_checked(path: PathLike, what: str, max_bytes: int = MAX_YAML_BYTES, lines: bool = False) -> Any:
    """The YAML document in the regular file at ``path`` (safe loading: plain data only); a syntax error is
    refused with the file and line.  With ``lines``, :func:`yaml_line` finds the lines of its parts."""
    import yaml

    text = read_text_checked(path, what, max_bytes)
    try:
        return yaml.load(text, Loader=_line_loader()) if lines else yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f", line {mark.line + 1} column {mark.column + 1}" if mark is not None else ""
        reason = " ".join(str(exc.problem or exc.context or "invalid syntax").split())
        raise ValueError(f"{_described(what, path)}{where}: not valid YAML ({reason})") from None
    except (yaml.YAMLError, RecursionError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"{_described(what, path)}: not valid YAML ({reason})") from None


def check_capture_path(name: str, source: str) -> None:
    """Refuse (naming ``name``) a ``--camera`` argument that names an existing path other than a regular file or
    a character device: a FIFO, folder or socket would block the capture."""
    try:
        info = os.stat(source)
    except (OSError, ValueError):  # not a path (an index, a URL) or nothing there: the capture reports it
        return
    if not (stat.S_ISREG(info.st_mode) or stat.S_ISCHR(info.st_mode)):
        raise ValueError(f"{name} {source} is {file_kind(info.st_mode)}, not a video file or a camera device")


def check_zip_members(
    archive: zipfile.ZipFile,
    path: PathLike,
    what: str,
    max_member_bytes: int,
    max_total_bytes: Optional[int] = None,
    error: type[Exception] = ValueError,
) -> None:
    """Refuse ``archive`` (opened from ``path``) if a member would unpack to more than ``max_member_bytes``, or
    all together to more than ``max_total_bytes``, from its central directory before anything is unpacked."""
    for info in archive.infolist():
        _check_member_size(info, path, what, max_member_bytes, error)
    if max_total_bytes is not None and (total := sum(i.file_size for i in archive.infolist())) > max_total_bytes:
        raise error(
            f"{_described(what, path)}: its members would unpack to {total} bytes, more than the "
            f"{max_total_bytes} a {what or 'file'} can have"
        )


def _check_member_size(
    info: zipfile.ZipInfo, path: PathLike, what: str, max_bytes: int, error: type[Exception]
) -> None:
    if info.file_size > max_bytes:
        raise error(
            f"{_described(what, path)}: member {info.filename!r} would unpack to {info.file_size} bytes, more "
            f"than the {max_bytes} it can have"
        )


def read_zip_member(
    archive: zipfile.ZipFile, name: str, path: PathLike, what: str, max_bytes: int, error: type[Exception] = ValueError
) -> bytes:
    """The bytes (at most ``max_bytes``) of member ``name`` of ``archive`` from ``path`` (``KeyError``: none)."""
    info = archive.getinfo(name)
    _check_member_size(info, path, what, max_bytes, error)
    with archive.open(info) as member:  # zipfile reads no more than the directory's size
        return member.read(max_bytes)
