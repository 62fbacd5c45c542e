"""Multi-seed training runs for the book's figures and the benchmarks, cached in run folders.

:func:`train_seeds` trains one method over several seeds into ``<root>/<algo>-seed<k>``; a folder that
already holds a finished run with the same config and at least as many episodes is reused, and a shorter
one is resumed from its checkpoint, so that Figures 4-6 and ``softpend bench --only rl`` share runs.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .config import DQNConfig, MBPOConfig, load_config
from .training_log import BALANCE_STD_RAD, TrainingLog

__all__ = ["median_real_s_to_balance", "train_seeds", "summary_table"]


def train_seeds(
    algo: str,
    config: DQNConfig,
    seeds: Sequence[int],
    episodes: int,
    root: Path | str = "runs/rl",
    progress: bool = True,
) -> list[TrainingLog]:
    """Train (or reuse) one run per seed; returns their logs in seed order."""
    from .dqn import train_dqn
    from .mbpo import train_mbpo

    if algo not in ("dqn", "mbpo"):
        raise ValueError(f"algo must be 'dqn' or 'mbpo', got {algo!r}")
    if len(seeds) == 0:
        raise ValueError("seeds must not be empty")
    if algo == "mbpo" and not isinstance(config, MBPOConfig):
        raise ValueError("algo 'mbpo' needs an MBPOConfig")
    logs = []
    for seed in seeds:
        run_dir = Path(root) / f"{algo}-seed{seed}"
        log_path = run_dir / "log.json"
        if log_path.exists() and (run_dir / "config.json").exists() and load_config(run_dir / "config.json") == config:
            log = TrainingLog.load(log_path)
            if log.n_episodes == episodes:
                logs.append(log)
                continue
            resume = log.n_episodes < episodes
        else:
            resume = False
        train = train_dqn if algo == "dqn" else train_mbpo
        _, log = train(config, seed=int(seed), episodes=int(episodes), run_dir=run_dir, resume=resume, progress=progress)
        logs.append(log)
    return logs


def summary_table(logs_by_method: dict[str, Sequence[TrainingLog]], std_rad: float = BALANCE_STD_RAD) -> list[dict[str, Any]]:
    """One row per method and seed: episodes and plant seconds to balance, to the asymptote, final std."""
    from .curves import episodes_to_asymptote, plant_s_at_episode

    rows = []
    for method, logs in logs_by_method.items():
        for log in logs:
            asym = episodes_to_asymptote(log.column("return"))
            last = log.evaluations[-1] if log.evaluations else {}
            rows.append({
                "method": method,
                "seed": log.seed,
                "episodes": log.n_episodes,
                "plant_s": log.plant_s,
                "episodes_to_asymptote": asym,
                "plant_s_to_asymptote": plant_s_at_episode(log, asym),
                "episodes_to_balance": log.episodes_to_balance(std_rad),
                "plant_s_to_balance": log.real_s_to_balance(std_rad),
                "final_max_upright_std_rad": last.get("max_upright_std_rad", math.nan),
                "final_swing_up_time_s": last.get("median_swing_up_time_s", math.nan),
                "model_steps": log.model_steps,
            })
    return rows


def median_real_s_to_balance(logs: Sequence[TrainingLog], std_rad: float = BALANCE_STD_RAD) -> float:
    """Median over seeds of the plant seconds until the evaluation balances (``inf`` counts as never)."""
    return float(np.median([log.real_s_to_balance(std_rad) for log in logs]))
