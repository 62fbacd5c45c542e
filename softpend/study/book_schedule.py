"""When each of the book's notebooks may start: the schedule of :func:`softpend.study.book.run_notebooks`.

The book runner executes notebooks on up to ``lanes`` kernels at once, while the training pool of the runs they
read works in the background at the lowest scheduling priority.  :func:`next_to_start` applies its rules:

* a notebook starts once the notebooks it waits for (:attr:`Needs.after`) have finished and the training runs
  it reads (:attr:`Needs.runs`) are trained;
* a real-time notebook (front matter ``softpend: {realtime: true}``: it paces a rig emulator by the wall
  clock) runs alone: it starts when no other notebook runs and the training pool has ended, and none starts
  while it runs (training workers, even in the idle scheduling class, delay the twin's processes enough for
  its camera or link to miss a deadline now and then);
* otherwise the first ready notebook in execution order starts; a ready real-time notebook first in line
  keeps further notebooks from starting until the running ones end, so it is never passed over for good.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Collection, Container, Mapping, Optional, Sequence

__all__ = ["Needs", "next_to_start"]


@dataclass(frozen=True)
class Needs:
    """What one notebook waits for before it starts."""

    #: Notebooks that must have finished executing (their front matter's ``after``, and more; see the runner).
    after: frozenset[str] = frozenset()
    #: Training runs (folder names such as ``"dqn-seed0"``) that must have finished.
    runs: frozenset[str] = frozenset()
    #: The notebook paces a rig emulator in real time: it runs alone among the notebooks.
    realtime: bool = False


def next_to_start(order: Sequence[str], needs: Mapping[str, Needs], started: Collection[str],
                  finished: Collection[str], trained: Container[str], lanes: int,
                  training: bool = False) -> Optional[str]:
    """The notebook to start now, or None.

    Parameters
    ----------
    order : sequence of str
        Every notebook to execute, in execution order.
    needs : mapping
        Each notebook's :class:`Needs`.
    started, finished : collections of str
        The notebooks started so far, and those among them that have finished.
    trained : container of str
        The training runs that have finished (or need no training).
    lanes : int
        How many notebooks may execute at once (at least 1).
    training : bool
        Whether the training pool is still running (a real-time notebook waits for it to end).
    """
    if lanes < 1:
        raise ValueError(f"lanes must be at least 1, got {lanes}")
    running = [name for name in started if name not in finished]
    if len(running) >= lanes or any(needs[name].realtime for name in running):
        return None
    for name in order:
        if name in started:
            continue
        need = needs[name]
        if not (all(dep in finished for dep in need.after) and all(run in trained for run in need.runs)):
            continue
        if need.realtime and training:
            continue
        if need.realtime and running:
            return None  # it waits for a free processor set, and nothing passes it meanwhile
        return name
    return None
