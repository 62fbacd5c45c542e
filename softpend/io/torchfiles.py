"""A state dict with its JSON metadata written atomically, and read back bounded with ``weights_only=True``."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from typing import Any, Iterator

import torch

from softpend.io.outputs import atomic_write
from softpend.io.reading import read_bytes_checked


def save_state(weights_path: str | Path, state: dict[str, Any], meta_path: str | Path, meta_text: str) -> None:
    """Write ``state`` (``torch.save``) to ``weights_path`` and ``meta_text`` to ``meta_path``, each atomically."""
    with atomic_write(weights_path) as handle:
        torch.save(state, handle)
    with atomic_write(meta_path, "w") as handle:
        handle.write(meta_text)


def load_state(path: str | Path, what: str, max_bytes: int) -> dict[str, Any]:
    """The state dict in the regular file at ``path`` of at most ``max_bytes``, unpickling plain tensors only."""
    return torch.load(io.BytesIO(read_bytes_checked(path, what, max_bytes)), weights_only=True, map_location="cpu")


@contextlib.contextmanager
def refused(prefix: str, error: type[Exception] = ValueError) -> Iterator[None]:
    """Any exception inside (a corrupt or foreign file can fail inside torch's reader in any way) becomes one line
    ``error``: ``prefix (Type: message)``."""
    try:
        yield
    except Exception as exc:
        message = " ".join(str(exc).split())[:300]
        raise error(f"{prefix} ({type(exc).__name__}: {message})") from None
