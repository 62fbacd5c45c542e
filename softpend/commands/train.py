"""``softpend train --algo dqn|mbpo|pilco``: train a controller into a run folder; prints a JSON summary."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from softpend.commands.options import Option, add_command, set_option

#: Most training episodes one command may ask for.
MAX_EPISODES = 1_000_000

OPTIONS: tuple[Option, ...] = (
    ("--algo", None, dict(required=True, choices=("dqn", "mbpo", "pilco"), help="training algorithm")),
    ("--out", None, dict(help="run folder (default: runs/<algo>-seed<SEED>)")),
    ("--seed", None, dict(type=int, default=0, help="seed of every random draw of the run")),
    ("--episodes", (0, MAX_EPISODES), dict(type=int, help="training episodes (default: the algorithm's)")),
    ("--torque-limit-nm", None, dict(type=float, help="motor torque limit [N m]")),
    ("--n-links", None, dict(type=int, help="links of the PRB rod (default: RodParams)")),
    ("--resume", None, dict(action="store_true", help="continue from the latest checkpoint in --out")),
    ("--no-progress", None, dict(action="store_true", help="hide the progress bar")),
    set_option(
        "override a field of the algorithm's config (repeatable; VALUE parsed as JSON, else a string; a dotted NAME "
        "reaches a nested field, e.g. task.rod.mass_kg=0.07)"
    ),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    add_command(subparsers, "train", "train a controller (DQN, DQN-MBPO, PILCO)", OPTIONS, run)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import json_text
    from softpend.study.presets import load_hparams

    out = args.out if args.out is not None else f"runs/{args.algo}-seed{args.seed}"
    flags = {f"task.rod.{n}": getattr(args, n) for n in ("n_links", "torque_limit_nm") if getattr(args, n) is not None}
    if args.algo == "pilco":  # the --set overrides win over the flags
        if args.resume:
            raise ValueError("--resume is not supported for pilco (runs are short; start a new run)")
        episodes = {} if args.episodes is None else {"n_policy_trials": args.episodes}
        config = load_hparams("pilco", overrides={"seed": args.seed, **episodes, **flags, **dict(args.overrides)})
        summary = _train_pilco(config, out, progress=not args.no_progress)
    else:  # the flags win over the --set overrides
        summary = _train_rl(args, load_hparams(args.algo, overrides={**dict(args.overrides), **flags}), out)
    print(json_text(summary, indent=2))
    if args.algo != "pilco":
        print(f"saved {out}/agent.zip")
    return 0


def _train_pilco(config, out: str, progress: bool) -> dict[str, Any]:
    import torch

    from softpend.io.outputs import check_output_folder
    from softpend.pilco.loop import run_pilco
    from softpend.study.head_to_head import refuse_other_pilco_run

    torch.set_num_threads(1)
    # before the work: a new or empty folder; one that holds a PILCO run (of any settings) is never trained over
    check_output_folder(out, what="run folder", owned=lambda folder: (folder / "pilco.json").is_file())
    refuse_other_pilco_run(out, config)
    result = run_pilco(config, progress=progress)
    r, balance = result, result.real_seconds_to_balance
    figures = {"out": str(r.save(Path(out))), "trials": len(r.records), "plant_seconds_total": r.plant_seconds_total}
    figures |= {"real_seconds_to_balance": balance if math.isfinite(balance) else None, "train_wall_s": r.train_wall_s}
    return figures | {"final_eval_upright_std_rad": r.records[-1].eval_upright_std_rad}


def _train_rl(args: argparse.Namespace, config, out: str) -> dict[str, Any]:
    from softpend.rl.dqn import train_dqn
    from softpend.rl.mbpo import train_mbpo
    from softpend.study.presets import RL_EPISODES

    if args.resume and not (Path(out) / "config.json").is_file():  # a mistyped --out would start a new run
        raise ValueError(f"--resume: {out} holds no run to resume (no config.json); leave out --resume to start one")
    episodes = args.episodes if args.episodes is not None else RL_EPISODES[args.algo]
    train = train_dqn if args.algo == "dqn" else train_mbpo
    run = dict(seed=args.seed, episodes=episodes, run_dir=out, resume=args.resume, progress=not args.no_progress)
    _, log = train(config, **run)
    last = log.evaluations[-1] if log.evaluations else {}
    finite = lambda x: None if math.isinf(x) else x  # noqa: E731
    return {
        **dict(algo=log.algo, seed=log.seed, episodes=log.n_episodes, plant_s=log.plant_s, model_steps=log.model_steps),
        "final_eval_starts": last.get("starts_evaluated"),  # fewer than the selection starts: stopped at a failure
        **{f"final_eval_{key}": last.get(key) for key in ("max_upright_std_rad", "median_swing_up_time_s")},
        "real_s_to_balance": finite(log.real_s_to_balance()),
        "episodes_to_balance": finite(log.episodes_to_balance()),
    }
