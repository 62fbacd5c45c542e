"""``softpend sweep``: train every method over many seeds on a parallel engine and summarise the runs; ``--book``
trains the runs the book's notebooks read; ``--fresh`` measures the agents on the fresh report starts."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from softpend.commands.options import Option, add_command, set_option
from softpend.commands.train import MAX_EPISODES

METHODS = ("dqn", "mbpo", "pilco")
#: Most seeds one sweep may train.
MAX_SEEDS = 10_000


def seed_list(text: str) -> list[int]:
    """``"0-9"``, ``"0,3,5"`` or a mix (``"0-2,7"``) as a sorted list of distinct seeds >= 0."""
    seeds: set[int] = set()
    for part in text.split(","):
        match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        low, high = (int(match[1]), int(match[2] or match[1])) if match else (0, -1)
        if high < low:
            raise argparse.ArgumentTypeError(f"seeds must look like 0-9 or 0,3,5, got {text!r}")
        if high - low + 1 > MAX_SEEDS - len(seeds):  # refused by its size before a single seed is listed
            raise argparse.ArgumentTypeError(
                f"seeds {text!r} name {high - low + 1 + len(seeds)} or more seeds, more "
                f"than the {MAX_SEEDS} one sweep may train"
            )
        seeds.update(range(low, high + 1))
    return sorted(seeds)


def method_list(text: str) -> list[str]:
    """Comma-separated method names among :data:`METHODS`."""
    if not (methods := [m.strip() for m in text.split(",") if m.strip()]) or not set(methods) <= set(METHODS):
        raise argparse.ArgumentTypeError(f"methods must be among {list(METHODS)}, got {text!r}")
    return list(dict.fromkeys(methods))


#: The options besides ``--book``, ``--backend`` and the ``--<method>-set`` (:func:`register`).
OPTIONS: tuple[Option, ...] = (
    ("--profile", None, dict(default="full", help="with --book: the profile of book/profiles.yml (default full)")),
    ("--root", None, dict(type=Path, default=Path("."), help="with --book: the project root (default .)")),
    ("--methods", None, dict(type=method_list, default=list(METHODS), help="comma-separated, default all")),
    ("--seeds", None, dict(type=seed_list, default=list(range(10)), help="e.g. 0-9 (default) or 0,3,5")),
    ("--workers", (1, 1024), dict(type=int, help="parallel runs (default $SOFTPEND_WORKERS or the CPU count)")),
    ("--runs-root", None, dict(type=Path, default=Path("runs/sweep"), help="run folders (default runs/sweep)")),
    ("--episodes-dqn", (1, MAX_EPISODES), dict(type=int, help="DQN episodes per seed (default: the book's)")),
    ("--episodes-mbpo", (1, MAX_EPISODES), dict(type=int, help="DQN-MBPO episodes per seed (default: the book's)")),
    ("--pilco-trials", (0, 10_000), dict(type=int, help="PILCO policy trials per seed (default: the book's)")),
    ("--fresh", None, dict(action="store_true", help="also measure every run on the fresh report starts")),
)
#: ``method -> (config class, method name, example of --<method>-set)``.
SET_EXAMPLES = {
    "dqn": ("DQNConfig", "DQN", "learner.gradient_steps=4"),
    "mbpo": ("MBPOConfig", "DQN-MBPO", "reset_every_episodes=20"),
    "pilco": ("PilcoConfig", "PILCO", "policy.balance_within_rad=null"),
}


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.study.sweep import BACKENDS

    book = "train the runs the book's notebooks read (for --profile), then stop; the other training options are unused"
    options: list[Option] = [
        ("--book", None, dict(action="store_true", help=book)),
        ("--backend", None, dict(choices=BACKENDS, default=None, help="parallel engine ($SOFTPEND_BACKEND or loky)")),
        *OPTIONS,
    ]
    for method, (cls, name, example) in SET_EXAMPLES.items():
        text = f"set a {cls} field for every {name} run, VALUE as JSON (repeatable; e.g. {example})"
        options.append(set_option(text, flag=f"--{method}-set", dest=f"{method}_overrides"))
    add_command(subparsers, "sweep", "train methods over many seeds on a parallel engine", options, run)


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from softpend.io.outputs import json_text
    from softpend.io.overrides import apply_overrides
    from softpend.study.head_to_head import pilco_runs
    from softpend.study.presets import PILCO, RL_EPISODES
    from softpend.study.rl_runs import figure_configs, summary_table, train_seeds
    from softpend.study.run_pool import train_book, train_in_one_pool
    from softpend.study.sweep import check_backend, default_backend

    check_backend(args.backend or default_backend())  # before any run, whatever the number of runs to train
    if args.book:
        record = train_book(args.root, args.profile, workers=args.workers, backend=args.backend)
        print(
            f"[sweep] profile {args.profile!r}: trained {len(record['trained'])} of the book's runs in "
            f"{record['seconds']:.0f} s ({record['workers']} workers)",
            file=sys.stderr,
        )
        return 0
    root: Path = args.runs_root
    if root.exists() and not root.is_dir():
        raise ValueError(f"--runs-root {root} exists and is not a folder")
    configs = {algo: apply_overrides(c, getattr(args, f"{algo}_overrides")) for algo, c in figure_configs().items()}
    episodes = {algo: getattr(args, f"episodes_{algo}") or RL_EPISODES[algo] for algo in configs}
    rl_algos = [m for m in args.methods if m != "pilco"]
    config = PILCO if args.pilco_trials is None else dataclasses.replace(PILCO, n_policy_trials=args.pilco_trials)
    config = apply_overrides(config, args.pilco_overrides)
    pool = dict(workers=args.workers, backend=args.backend)
    # every method's runs in one pool; the per-method calls below find them finished
    rl_specs = [(algo, configs[algo], args.seeds, episodes[algo]) for algo in rl_algos]
    train_in_one_pool(rl_specs, root, config if "pilco" in args.methods else None, args.seeds, **pool)
    rl_logs = {algo: train_seeds(algo, configs[algo], args.seeds, episodes[algo], root, **pool) for algo in rl_algos}
    methods = {
        algo: {"episodes": episodes[algo], "runs": summary_table({algo: logs})} for algo, logs in rl_logs.items()
    }
    out: dict = {"seeds": args.seeds, "runs_root": str(root), "methods": methods}
    pilco_results = pilco_runs(config, args.seeds, root, **pool) if "pilco" in args.methods else []
    if pilco_results:
        keys = ("seed", "plant_s_to_balance", "plant_s", "cpu_s")
        runs = [(r.config.seed, r.real_seconds_to_balance, r.plant_seconds_total, r.train_cpu_s) for r in pilco_results]
        out["methods"]["pilco"] = {"runs": [dict(zip(keys, run)) for run in runs]}
    if args.fresh:
        from softpend.study import fresh_starts as fs

        rows = fs.pilco_fresh_start_rows(pilco_results) if pilco_results else []
        if rl_logs:
            rows += fs.rl_fresh_start_rows(root, args.seeds, algos=list(rl_logs), configs=configs)
        per_seed = fs.seed_rows(rl_logs, rows, pilco_results)
        out.update(fresh_starts=rows, fresh_start_summary=fs.aggregate_fresh_start_rows(rows), per_seed=per_seed)
        out["headline"] = fs.headline_figures(per_seed)
    print(json_text(out, indent=2))
    return 0
