"""What a training run records: one row per training episode and per evaluation, in plant time."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from softpend.evaluation import SUCCESS_STD_RAD
from softpend.io.outputs import atomic_write
from softpend.io.reading import MAX_JSON_BYTES, read_json_checked


@dataclass
class TrainingLog:
    """Episode and evaluation records of one run (JSON round-trip with :meth:`save` / :meth:`load`)."""

    algo: str
    seed: int
    episodes: list[dict[str, float]] = field(default_factory=list)
    evaluations: list[dict[str, Any]] = field(default_factory=list)
    #: Why training ended before its episode budget (early stopping), or ``None``.
    stop_reason: Optional[str] = None

    @property
    def n_episodes(self) -> int:
        return len(self.episodes)

    @property
    def plant_s(self) -> float:
        """Real plant seconds consumed by training so far."""
        return float(self.episodes[-1]["plant_s"]) if self.episodes else 0.0

    @property
    def model_steps(self) -> int:
        """Model (simulated-by-the-learned-model) agent steps generated so far."""
        return int(self.episodes[-1]["model_steps"]) if self.episodes else 0

    def column(self, name: str, table: str = "episodes") -> np.ndarray:
        """One field of every episode (or evaluation) row as an array."""
        rows = self.episodes if table == "episodes" else self.evaluations
        return np.array([row[name] for row in rows], dtype=float)

    def real_s_to_balance(self, std_rad: float = SUCCESS_STD_RAD, key: str = "plant_s") -> float:
        """Training plant seconds (``key="episode"``: episodes) at the first evaluation in which every seed swung up
        and held ``upright_std_rad <= std_rad`` (``inf`` if none)."""
        rows = (r for r in self.evaluations if r["all_swung_up"] and r["max_upright_std_rad"] <= std_rad)
        return float(next(rows, {key: math.inf})[key])

    def episodes_to_balance(self, std_rad: float = SUCCESS_STD_RAD) -> float:
        return self.real_s_to_balance(std_rad, "episode")

    def save(self, path: Path) -> None:
        data = {"algo": self.algo, "seed": self.seed, "episodes": self.episodes, "evaluations": self.evaluations}
        if self.stop_reason is not None:
            data["stop_reason"] = self.stop_reason
        text = json.dumps(data, indent=1, default=_json_default)
        with atomic_write(path, "w") as handle:
            handle.write(text)

    @classmethod
    def load(cls, path: Path) -> "TrainingLog":
        try:
            data = read_json_checked(path, "training log", MAX_JSON_BYTES)  # a regular file, read with a bound
            rows = list(data["episodes"]), list(data["evaluations"])
            log = cls(str(data["algo"]), int(data["seed"]), *rows, stop_reason=data.get("stop_reason"))
            if log.stop_reason is not None and not isinstance(log.stop_reason, str):
                raise ValueError("stop_reason is not a string")
            for row in log.episodes + log.evaluations:
                if not isinstance(row, dict) or not isinstance(row.get("episode"), int):
                    raise ValueError("a row is not an object with an integer episode")
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError, KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: not a training log ({type(exc).__name__}: {exc})") from None
        return log


def _json_default(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    raise TypeError(f"cannot serialise {type(value).__name__}")
