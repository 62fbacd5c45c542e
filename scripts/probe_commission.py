"""Commission the unknown rods of seeds 9001..9005 on the twin (softpend rig commission's stages) and store a
summary per rod and controller class; a rod's folder under --work resumes where an earlier run stopped.

    .venv/bin/python scripts/probe_commission.py [--work runs/commission_probe]
        [--out book/records/commission_probe.json] [--rods 5] [--seeds 9001 ...] [--verify-starts 10]
        [--controllers swingup dqn mbpo pilco] [--default-runs pilco=runs/pilco-book/pilco-2da326ca-seed0 ...]
"""

import argparse
import json
import statistics
import time

from softpend.io.outputs import Outputs
from softpend.study.commission import CLASSES, CommissionConfig, commission
from softpend.study.records import record_text
from softpend.study.twin_side import TwinTruth

SEEDS = (9001, 9002, 9003, 9004, 9005)


def rod_row(seed: int, report: dict, wall_s: float) -> dict:
    """A rod's row: its scalars (per class: plant seconds, training simulator and wall seconds, successes per
    condition of the commissioned and the default-rod version; relative errors) rendered, the report's parts kept
    as mappings."""
    row = {
        "twin_seed": seed,
        "excite_plant_s": report["plant_s"]["excite"],
        "design_all_balanced": report["design"]["all_balanced"],
        **{f"{name}_error": v["relative_error"] for name, v in report["identified"].items()},
    }
    for name, entry in report["classes"].items():
        training = entry["training"] or {}
        row[f"{name}_plant_s"] = entry["plant_s"]
        row[f"{name}_simulator_s"] = entry["simulator_s"]
        row[f"{name}_train_wall_s"] = training.get("wall_s")
        row[f"{name}_train_balanced"] = training.get("balanced")
        row[f"{name}_train_attempts"] = training.get("attempts")
        for prefix, key in (("", "verification"), ("default_rod_", "default_rod_verification")):
            for summary in entry[key] or []:
                row[f"{prefix}{name}_{summary['condition']}_successes"] = summary["successes"]
                row[f"{prefix}{name}_{summary['condition']}_starts"] = summary["starts"]
    row["wall_s"] = wall_s
    row["identified"] = report["identified"]
    row["rod_uncertainty"] = report["rod_uncertainty"]
    return row


def rod_figures(rows: list[dict]) -> dict:
    """Rods, median plant seconds per class, successes and starts summed, the worst rod's successes per class and
    condition."""
    figures: dict = {"rods": len(rows), "rods_design_balanced": sum(r["design_all_balanced"] for r in rows)}
    for key in sorted({k for r in rows for k in r if k.endswith(("_plant_s", "_simulator_s"))}):
        figures[f"median_{key}"] = statistics.median(r[key] for r in rows if r.get(key) is not None)
    for key in sorted({k for r in rows for k in r if k.endswith(("_successes", "_starts"))}):
        values = [r[key] for r in rows if key in r]
        figures[key] = sum(values)
        if key.endswith("_successes"):
            figures[f"min_{key}"] = min(values)
    return figures


def main() -> None:  # the twin's side runs in spawned children, which import this file
    parser = argparse.ArgumentParser()
    parser.add_argument("--work", default="runs/commission_probe")
    parser.add_argument("--out", default="book/records/commission_probe.json")
    parser.add_argument("--rods", type=int, default=len(SEEDS))
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS), help="the unknown rods' twin seeds")
    parser.add_argument("--verify-starts", type=int, default=10)
    parser.add_argument("--controllers", nargs="+", default=list(CLASSES), choices=CLASSES)
    parser.add_argument("--default-runs", nargs="*", default=[], metavar="LEARNER=FOLDER")
    parser.add_argument("--uncertainty-scale", type=float, default=None, help="CommissionConfig.uncertainty_scale")
    args = parser.parse_args()
    default_runs = dict(item.split("=", 1) for item in args.default_runs)
    config = CommissionConfig(
        verify_starts=args.verify_starts,
        controllers=tuple(args.controllers),
        default_rod_runs=default_runs,
        **({} if args.uncertainty_scale is None else {"uncertainty_scale": args.uncertainty_scale}),
    )
    outputs = Outputs()
    outputs.file(args.out, "--out")
    rods = []
    for seed in args.seeds[: args.rods]:
        started = time.perf_counter()
        report = commission(f"{args.work}/rod_{seed}", TwinTruth(seed=seed), config)
        rods.append(rod_row(seed, report, time.perf_counter() - started))
        settings = {
            k: v if isinstance(v, (str, int, float, bool)) else json.dumps(v) for k, v in config.__dict__.items()
        }
        summary = {
            "title": "softpend rig commission (excite, identify, design, train, verify) on unknown twin rods, per rod",
            "command": "scripts/probe_commission.py "
            + " ".join(
                f"--{k.replace('_', '-')} {' '.join(map(str, v)) if isinstance(v, list) else v}"
                for k, v in vars(args).items()
            ),
            "settings": settings,
            "figures": rod_figures(rods),
            "rows": rods,
        }
        outputs.write_text(args.out, record_text(summary))
        print(json.dumps({"twin_seed": seed, "row": {k: v for k, v in rods[-1].items() if k.endswith("successes")}}))


if __name__ == "__main__":
    main()
