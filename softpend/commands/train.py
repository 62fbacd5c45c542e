"""``softpend train --algo dqn|mbpo|pilco``: train a controller and save it (with checkpoints) to a run folder."""

from __future__ import annotations

import argparse
import importlib
from typing import Callable

from softpend.commands.options import add_set_option

#: Training entry points, one line per algorithm: ``name -> "module:function(args) -> int"``.
ALGORITHMS: dict[str, str] = {
    "dqn": "softpend.commands.train_rl:train_dqn_from_args",
    "mbpo": "softpend.commands.train_rl:train_mbpo_from_args",
    "pilco": "softpend.commands.train_pilco:train_pilco_from_args",
}


def resolve(algo: str) -> Callable[[argparse.Namespace], int]:
    """The training function registered for ``algo``."""
    if algo not in ALGORITHMS:
        raise ValueError(f"algo must be one of {sorted(ALGORITHMS)}, got {algo!r}")
    module_name, function_name = ALGORITHMS[algo].split(":")
    return getattr(importlib.import_module(module_name), function_name)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("train", help="train a controller (DQN, DQN-MBPO, PILCO)")
    parser.add_argument("--algo", required=True, choices=sorted(ALGORITHMS), help="training algorithm")
    parser.add_argument("--out", default=None, help="run folder (default: runs/<algo>-seed<SEED>)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw of the run")
    parser.add_argument("--episodes", type=int, default=None, help="training episodes (default: the algorithm's)")
    parser.add_argument("--torque-limit-nm", type=float, default=None, help="motor torque limit [N m]")
    parser.add_argument("--n-links", type=int, default=None, help="links of the PRB rod (default: RodParams)")
    parser.add_argument("--resume", action="store_true", help="continue from the latest checkpoint in --out")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    add_set_option(
        parser,
        help="override a field of the algorithm's config (repeatable; VALUE parsed as JSON, else a string; "
        "a dotted NAME reaches a nested field, e.g. task.rod.mass_kg=0.07)",
    )
    parser.set_defaults(func=run)


#: Most training episodes one command may ask for (a million: far beyond any budget of the book).
MAX_EPISODES = 1_000_000


def run(args: argparse.Namespace) -> int:
    from softpend.commands.options import check_numbers

    check_numbers(args, {"--episodes": (0, MAX_EPISODES)})  # before anything starts (0: PILCO's random trials only)
    if args.out is None:
        args.out = f"runs/{args.algo}-seed{args.seed}"
    args.overrides = dict(args.overrides or [])
    return int(resolve(args.algo)(args) or 0)
