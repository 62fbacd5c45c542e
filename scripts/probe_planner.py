"""Probe of the MPPI planner (issue 65): one run per seed, then its controller from 20 fresh starts.

    .venv/bin/python scripts/probe_planner.py --seeds 0 1 2 [--set model=residual] [--plant beam] [--tune] [--out PATH]

Per seed: the plant seconds until the stopping rule fired (every excitation and trial second counted), the
fresh starts balanced (swing-up found, upright std <= 0.1 rad) out of 20, and the wall and CPU seconds of the
run.  The trials start from the first 16 SELECTION_SEEDS; ``--tune`` measures on the other 20 selection seeds
instead of REPORT_SEEDS (for tuning), and writes nothing unless ``--out`` is given.

    .venv/bin/python scripts/probe_planner.py --pair-with-pilco runs/pilco-book --planner-record PATH [--out PATH]

pairs a stored probe of the planner on the PRB rod (``--planner-record``) with the book's PILCO runs of the same
seeds (trained beforehand by ``softpend sweep --methods pilco``; PILCO's plant seconds to its first balancing
policy, infinite unless its final policy balances the fresh report starts, as in the data-efficiency chapter):
per seed the planner's plant seconds to balance over PILCO's, and their median.  ``--plant beam`` (the same as
``--set task.plant=beam``) makes the continuum beam the real rod: excitation, trials and fresh starts on the beam
(one start after the other, on the Exudyn engine).  The JSON is the stored probe summary of ``book/records``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Mapping

import torch

from softpend.control.planner import run_planner
from softpend.evaluation import HOLD_STD_RAD, evaluate
from softpend.io.outputs import atomic_write
from softpend.io.overrides import parse_assignment
from softpend.study.data_efficiency import planner_config, planner_fresh_starts
from softpend.study.presets import REPORT_SEEDS, SELECTION_SEEDS
from softpend.study.records import load_record, record_text
from softpend.task import Task

ROOT = Path(__file__).resolve().parents[1]
TUNING_SEEDS = SELECTION_SEEDS[16:36]
#: A seed balances when at least this share of its fresh starts balance; the target counts seeds within this.
BALANCED_FRACTION, WITHIN_S = 0.9, 30.0


def flat_settings(settings: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``settings`` with nested mappings as dotted names and lists as comma-separated text (record settings)."""
    flat: dict[str, Any] = {}
    for name, value in settings.items():
        if isinstance(value, Mapping):
            flat |= flat_settings(value, f"{prefix}{name}.")
        else:
            flat[f"{prefix}{name}"] = ", ".join(map(str, value)) if isinstance(value, (list, tuple)) else value
    return flat


def _store(out: str, document: dict) -> None:
    with atomic_write(Path(out), "w") as handle:
        handle.write(record_text(document))


def _write(rows: list[dict], args: argparse.Namespace, argv: list[str], config: Any) -> None:
    seconds = [r["plant_s_to_balance"] for r in rows]
    balancing = [r["fresh_balanced"] >= BALANCED_FRACTION * r["fresh_starts"] for r in rows]
    to_balance = [s if ok else math.inf for s, ok in zip(seconds, balancing)]
    figures = {
        "seeds": len(rows),
        "seeds_balancing": sum(ok and math.isfinite(s) for s, ok in zip(seconds, balancing)),
        f"seeds_within_{WITHIN_S:g}s": sum(s <= WITHIN_S for s in to_balance),
        "median_plant_s_to_balance": statistics.median(seconds),
        "worst_plant_s_to_balance": max(seconds),
        "median_real_s_to_balance": statistics.median(to_balance),
        "max_run_cpu_s": max(r["run_cpu_s"] for r in rows),
    }
    print(json.dumps(figures), flush=True)
    out = (
        args.out
        if args.out is not None
        else (None if args.tune else str(ROOT / "book" / "records" / "planner_probe.json"))
    )
    if out is not None:
        settings = flat_settings({k: v for k, v in vars(config).items() if k not in ("task", "seed")})
        settings.update(flat_settings(config.task.to_dict(), "task."))
        settings["fresh_seeds"] = ", ".join(map(str, TUNING_SEEDS if args.tune else REPORT_SEEDS))
        settings["balanced_fraction"] = BALANCED_FRACTION
        settings["hold_std_rad"] = HOLD_STD_RAD
        plant = config.task.plant
        document = {
            "title": f"MPPI planner ({config.model} model) on the {plant} rod, "
            + ("tuning starts" if args.tune else "fresh report starts"),
            "command": "python scripts/probe_planner.py " + " ".join(argv),
            "settings": settings,
            "figures": figures,
            "rows": rows,
        }
        _store(out, document)


def _pair_with_pilco(args: argparse.Namespace, argv: list[str]) -> int:
    from softpend.study.data_efficiency import paired_ratio, paired_ratio_rows, pilco_rows_if_trained

    record = load_record(args.planner_record)
    planner = {
        int(r["seed"]): r["plant_s_to_balance"]
        if r["fresh_balanced"] >= BALANCED_FRACTION * r["fresh_starts"]
        else math.inf
        for r in record["rows"]
    }
    pilco_rows = pilco_rows_if_trained(sorted(planner), args.pair_with_pilco)
    if pilco_rows is None:
        raise SystemExit(f"the book's PILCO runs of seeds {sorted(planner)} are not all in {args.pair_with_pilco}")
    pilco = {int(r["seed"]): r for r in pilco_rows}
    rows = [
        {
            "seed": row["seed"],
            "planner_s_to_balance": row["numerator_s"],
            "pilco_s_to_balance": row["denominator_s"],
            "ratio": row["ratio"],
            "pilco_plant_s": pilco[row["seed"]]["plant_s"],
            "pilco_trials": pilco[row["seed"]]["episodes"],
            "pilco_fresh_balanced": pilco[row["seed"]]["final_balanced_starts"],
            "pilco_fresh_starts": pilco[row["seed"]]["starts"],
        }
        for row in paired_ratio_rows(planner, {s: r["plant_s_to_balance"] for s, r in pilco.items()})
    ]
    figures = {
        "seeds": len(rows),
        "mpc_over_pilco_real_s_ratio": paired_ratio(planner, {s: r["plant_s_to_balance"] for s, r in pilco.items()}),
        "median_planner_s_to_balance": statistics.median(r["planner_s_to_balance"] for r in rows),
        "median_pilco_s_to_balance": statistics.median(r["pilco_s_to_balance"] for r in rows),
        "seeds_planner_fewer_s": sum(r["ratio"] < 1 for r in rows),
    }
    print(json.dumps(figures), flush=True)
    document = {
        "title": "MPPI planner (PRB-residual model) against PILCO: plant seconds to balance, paired by seed",
        "command": "python scripts/probe_planner.py " + " ".join(argv),
        "settings": {
            "planner_record": args.planner_record,
            "pilco_runs_root": args.pair_with_pilco,
            "fresh_seeds": ", ".join(map(str, REPORT_SEEDS)),
            "balanced_fraction": BALANCED_FRACTION,
        },
        "figures": figures,
        "rows": rows,
    }
    out = args.out if args.out is not None else str(ROOT / "book" / "records" / "planner_vs_pilco.json")
    _store(out, document)
    return 0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--plant", default=None, help="the real rod: prb or beam (default: the task's)")
    parser.add_argument("--hparams", default=str(ROOT / "book" / "hparams" / "planner.yml"))
    parser.add_argument("--tune", action="store_true", help="measure on selection starts, not REPORT_SEEDS")
    parser.add_argument("--out", default=None)
    parser.add_argument("--pair-with-pilco", default=None, metavar="RUNS_ROOT", help="pair with PILCO's book runs")
    parser.add_argument("--planner-record", default=str(ROOT / "book" / "records" / "planner_probe_residual.json"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.pair_with_pilco is not None:
        return _pair_with_pilco(args, argv)
    overrides = [parse_assignment(item) for item in args.set]
    if args.plant is not None:
        overrides.append(("task.plant", args.plant))
    config = planner_config(Task(), overrides, args.hparams)
    # the batched engine simulates the PRB chain only: other rods run one start after the other
    engine = "batched" if config.task.plant == "prb" else "exudyn"
    rows = []
    for seed in args.seeds:
        wall, cpu = time.perf_counter(), time.process_time()
        result = run_planner(config.replace(seed=seed), progress=True)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        started = time.perf_counter()
        if args.tune:
            policy = result.controller.batch_policy() if engine == "batched" else result.controller
            with torch.no_grad():
                summary = evaluate(policy, config.task, engine=engine, seeds=TUNING_SEEDS)
        else:
            summary = planner_fresh_starts(result, REPORT_SEEDS)
        held = [math.isfinite(r.swing_up_time_s) and r.upright_std_rad <= HOLD_STD_RAD for r in summary.results]
        row = {
            "seed": seed,
            "plant_s_to_balance": result.plant_seconds_to_balance,
            "plant_s_total": result.plant_seconds,
            "trials": sum(r.kind == "trial" for r in result.records),
            "fresh_balanced": int(sum(held)),
            "fresh_starts": len(held),
            "fresh_worst_std_rad": max(r.upright_std_rad for r in summary.results),
            "fresh_median_swing_up_s": statistics.median(r.swing_up_time_s for r in summary.results),
            "run_wall_s": wall,
            "run_cpu_s": cpu,
            "eval_wall_s": time.perf_counter() - started,
            "identified_rod": result.rod.to_dict(),
        }
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "identified_rod"}), flush=True)
        _write(rows, args, argv, config)  # after every seed, so that a cut-short probe keeps its seeds
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
