"""``softpend evaluate AGENT``: run a trained agent through the shared evaluation on the true plant."""

from __future__ import annotations

import argparse

from softpend.commands.options import Option, add_command

OPTIONS: tuple[Option, ...] = (
    ("agent", None, dict(metavar="AGENT", help="run folder of softpend train, or its agent.zip")),
    ("--seeds", None, dict(type=int, nargs="+", default=[0, 1, 2], help="start-noise seeds (one episode each)")),
    ("--duration-s", None, dict(type=float, default=10.0, help="episode length [s]")),
    ("--which", None, dict(choices=["best", "final"], default="best", help="the best periodic agent or the final")),
    ("--json", None, dict(action="store_true", help="print JSON (per-seed metrics and the summary row)")),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    help = "evaluate a trained agent (run folder or agent.zip) on the true plant"
    add_command(subparsers, "evaluate", help, OPTIONS, run)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import json_text
    from softpend.rl.dqn import evaluate_agent, load_agent

    model, config = load_agent(args.agent, which=args.which)
    summary = evaluate_agent(model, config, seeds=tuple(args.seeds), duration_s=args.duration_s, name=str(args.agent))
    if args.json:
        print(json_text({"summary": summary.row(), "per_seed": [r.metrics() for r in summary.results]}, indent=2))
        return 0
    for m in (r.metrics() for r in summary.results):
        print(
            f"seed {m['seed']:>4}  swing-up {m['swing_up_time_s']:6.2f} s  upright std {m['upright_std_rad']:.3f} rad  "
            f"peak {m['peak_torque_nm']:.3f} N m  energy {m['energy_used_j']:.3f} J  success {m['success']}"
        )
    print(f"success rate {summary.success_rate:.2f}")
    return 0
