"""Command-line entry points of ``softpend train --algo dqn|mbpo`` (see :mod:`softpend.commands.train`)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any, TypeVar

from softpend.io.outputs import json_text
from softpend.io.overrides import apply_overrides
from softpend.rl.config import DQNConfig
from softpend.study.presets import RL_EPISODES, load_hparams

_Config = TypeVar("_Config", bound=DQNConfig)


def config_from_args(base: _Config, args: argparse.Namespace) -> _Config:
    """``base`` with the ``--set`` overrides (``args.overrides``, ``NAME -> parsed value``) applied, then
    ``--n-links`` and ``--torque-limit-nm`` (as ``task.rod.n_links`` and ``task.rod.torque_limit_nm``)."""
    overrides: dict[str, Any] = dict(getattr(args, "overrides", None) or {})
    for name in ("n_links", "torque_limit_nm"):
        if getattr(args, name, None) is not None:
            overrides[f"task.rod.{name}"] = getattr(args, name)
    return apply_overrides(base, overrides)


def _summary(log) -> dict[str, Any]:
    last = log.evaluations[-1] if log.evaluations else {}
    to_balance = log.real_s_to_balance()
    return {
        "algo": log.algo,
        "seed": log.seed,
        "episodes": log.n_episodes,
        "plant_s": log.plant_s,
        "model_steps": log.model_steps,
        "final_eval_starts": last.get("starts_evaluated"),  # fewer than the selection starts: stopped at a failure
        "final_eval_max_upright_std_rad": last.get("max_upright_std_rad"),
        "final_eval_median_swing_up_time_s": last.get("median_swing_up_time_s"),
        "real_s_to_balance": None if math.isinf(to_balance) else to_balance,
        "episodes_to_balance": None if math.isinf(log.episodes_to_balance()) else log.episodes_to_balance(),
    }


def _train(algo: str, args: argparse.Namespace) -> int:
    from softpend.rl.dqn import train_dqn
    from softpend.rl.mbpo import train_mbpo

    base = load_hparams(algo)
    config = config_from_args(base, args)
    episodes = args.episodes if args.episodes is not None else RL_EPISODES[algo]
    train = train_dqn if algo == "dqn" else train_mbpo
    if args.resume and not (Path(args.out) / "config.json").is_file():  # a mistyped --out would start a new run
        raise ValueError(
            f"--resume: {args.out} holds no run to resume (no config.json); leave out --resume to start one"
        )
    _, log = train(
        config, seed=args.seed, episodes=episodes, run_dir=args.out, resume=args.resume, progress=not args.no_progress
    )
    print(json_text(_summary(log), indent=2))
    print(f"saved {args.out}/agent.zip")
    return 0


def train_dqn_from_args(args: argparse.Namespace) -> int:
    """``softpend train --algo dqn``."""
    return _train("dqn", args)


def train_mbpo_from_args(args: argparse.Namespace) -> int:
    """``softpend train --algo mbpo``."""
    return _train("mbpo", args)
