"""``softpend evaluate AGENT``: run a trained agent through the shared evaluation on the true plant."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "evaluate", help="evaluate a trained agent (run folder or agent.zip) on the true plant"
    )
    parser.add_argument("agent", metavar="AGENT", help="run folder of softpend train, or its agent.zip")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="start-noise seeds (one episode each)")
    parser.add_argument("--duration-s", type=float, default=10.0, help="episode length [s]")
    parser.add_argument(
        "--which",
        choices=["best", "final"],
        default="best",
        help="the agent of the best periodic evaluation (default) or the final one",
    )
    parser.add_argument("--json", action="store_true", help="print JSON (per-seed metrics and the summary row)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import json_text
    from softpend.rl.dqn import evaluate_agent, load_agent

    model, config = load_agent(args.agent, which=args.which)
    summary = evaluate_agent(model, config, seeds=tuple(args.seeds), duration_s=args.duration_s, name=str(args.agent))
    if args.json:
        print(json_text({"summary": summary.row(), "per_seed": [r.metrics() for r in summary.results]}, indent=2))
    else:
        for r in summary.results:
            m = r.metrics()
            print(
                f"seed {m['seed']:>4}  swing-up {m['swing_up_time_s']:6.2f} s  upright std {m['upright_std_rad']:.3f} rad  "
                f"peak {m['peak_torque_nm']:.3f} N m  energy {m['energy_used_j']:.3f} J  success {m['success']}"
            )
        print(f"success rate {summary.success_rate:.2f}")
    return 0
