"""Crash-safe sample logs: an append-only CSV (header ``# softpend-log v1 <json metadata>``, then the column
names) written one complete line per ``write(2)``, so a killed writer leaves every appended sample readable."""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from softpend.checks import MAX_WORK_BYTES
from softpend.io.reading import check_regular_file, open_checked_fd, read_bytes_checked

_MAGIC = "# softpend-log v1 "


def _format(value: Any) -> str:
    return str(int(value)) if isinstance(value, (bool, np.bool_, int, np.integer)) else repr(float(value))


class SampleLog:
    """Append-only CSV log of ``columns`` at ``path`` (appended to if it holds a log of the same columns); the
    data is forced to disk at most every ``fsync_every_s`` (0: every sample, None: only on close)."""

    def __init__(
        self,
        path: str | os.PathLike,
        columns: Sequence[str],
        metadata: Optional[dict] = None,
        fsync_every_s: Optional[float] = 1.0,
    ) -> None:
        columns = [str(c) for c in columns]
        if not columns or any((not c) or ("," in c) or ("\n" in c) for c in columns):
            raise ValueError(f"columns must be non-empty names without commas or newlines, got {columns!r}")
        self.path, self.columns, self.fsync_every_s, self.rows_written = Path(path), columns, fsync_every_s, 0
        # a FIFO or device would block or swallow the log
        exists = os.path.exists(self.path) and check_regular_file(self.path, "sample log").st_size > 0
        if exists and (existing := read_sample_log(self.path).columns) != columns:
            raise ValueError(f"path {self.path} holds a log with columns {existing}, not {columns}")
        self._fd: Optional[int] = open_checked_fd(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, "sample log")
        self._last_sync = time.monotonic()
        if not exists:
            header = _MAGIC + json.dumps(metadata or {}, sort_keys=True) + "\n" + ",".join(columns) + "\n"
            os.write(self._fd, header.encode())
            os.fsync(self._fd)

    def append(self, row: Sequence[Any]) -> None:
        """Write one sample (values in column order)."""
        if self._fd is None:
            raise ValueError("append to a closed SampleLog")
        values = list(row)
        if len(values) != len(self.columns):
            raise ValueError(f"row has {len(values)} values, the log has {len(self.columns)} columns")
        os.write(self._fd, (",".join(_format(v) for v in values) + "\n").encode())  # one syscall per line
        self.rows_written += 1
        if self.fsync_every_s is not None:
            now = time.monotonic()
            if now - self._last_sync >= self.fsync_every_s:
                os.fsync(self._fd)
                self._last_sync = now

    def close(self) -> None:
        if self._fd is not None:
            try:
                os.fsync(self._fd)
            finally:
                os.close(self._fd)
                self._fd = None

    def __enter__(self) -> "SampleLog":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class LogContents:
    """A log read back: ``data[column]`` arrays, the metadata, and the number of torn last lines dropped."""

    columns: list[str]
    data: dict[str, np.ndarray]
    metadata: dict = field(default_factory=dict)
    torn_lines: int = 0

    def __len__(self) -> int:
        return len(next(iter(self.data.values()))) if self.data else 0

    def __getitem__(self, column: str) -> np.ndarray:
        return self.data[column]


def read_sample_log(path: str | os.PathLike, max_bytes: int = MAX_WORK_BYTES) -> LogContents:
    """Read a :class:`SampleLog` file of at most ``max_bytes``; a torn last line is counted, not parsed."""
    path = Path(path)
    text = read_bytes_checked(path, "sample log", max_bytes).decode(errors="replace")
    lines = text.split("\n")
    if not lines or not lines[0].startswith(_MAGIC):
        raise ValueError(f"path {path} is not a softpend sample log (missing {_MAGIC.strip()!r} header)")
    metadata = json.loads(lines[0][len(_MAGIC) :])
    if len(lines) < 2 or not lines[1]:
        raise ValueError(f"path {path} has no column line")
    columns, body = lines[1].split(","), lines[2:]
    torn = int(bool(body) and body[-1] != "")  # the file does not end with a newline
    rows = [line for line in body[:-1] if line]
    values = np.array([[float(v) for v in line.split(",")] for line in rows], dtype=float).reshape(-1, len(columns))
    return LogContents(columns, {c: values[:, i] for i, c in enumerate(columns)}, metadata, torn)
