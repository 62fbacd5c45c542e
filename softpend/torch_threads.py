"""Torch's CPU thread count for a block of work."""

from __future__ import annotations

import contextlib
from typing import Any, Iterator

__all__ = ["one_torch_thread"]


@contextlib.contextmanager
def one_torch_thread() -> Iterator[Any]:
    """Context: torch on one thread, the caller's count restored afterwards; yields the ``torch`` module."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield torch
    finally:
        torch.set_num_threads(before)
