"""Job functions of tests/test_sweep.py, in a module of their own: a sweep worker imports the module of the function
it runs, and this one imports nothing heavy (the test module imports torch and the RL stack)."""

import os
from pathlib import Path


def write_pid(folder: Path, value: int, progress: bool = True) -> None:
    if value < 0:
        raise ValueError(f"negative value {value}")
    (folder / f"job{value}.txt").write_text(f"{value} {os.getpid()} {progress}")


def die_once(folder: Path, value: int, progress: bool = True) -> None:
    """Kill its own worker process the first time (as an out-of-memory kill would), succeed the second."""
    marker = folder / f"died{value}"
    if not marker.exists():
        marker.write_text("x")
        os._exit(9)
    write_pid(folder, value, progress)


def always_die(folder: Path, value: int, progress: bool = True) -> None:
    os._exit(9)
