"""Commission the unknown rods of seeds 9001..9005 on the twin (softpend rig commission's stages) and store a
summary per rod; a rod's folder under --work resumes where an earlier run stopped.

    .venv/bin/python scripts/probe_commission.py [--work runs/commission_probe]
        [--out book/records/commission_probe.json] [--rods 5] [--seeds 9001 ...] [--verify-starts 10]
"""

import argparse
import json
import statistics
import time

from softpend.io.outputs import Outputs
from softpend.study.commission import CommissionConfig, commission
from softpend.study.records import record_text
from softpend.study.twin_side import TwinTruth

SEEDS = (9001, 9002, 9003, 9004, 9005)


def rod_row(seed: int, report: dict, wall_s: float) -> dict:
    """A rod's row: its scalars (plant seconds, design check, relative errors, verified successes) rendered, the
    report's parts kept as mappings."""
    verification = {v["condition"]: v for v in report["verification"]}
    return {
        "twin_seed": seed,
        "plant_s": report["plant_s"]["commissioning"],
        "design_all_balanced": report["design"]["all_balanced"],
        **{f"{name}_error": v["relative_error"] for name, v in report["identified"].items()},
        **{f"{c}_successes": v["successes"] for c, v in verification.items()},
        **{f"{c}_starts": v["starts"] for c, v in verification.items()},
        "wall_s": wall_s,
        "plant_s_by_stage": report["plant_s"],
        "identified": report["identified"],
        "design_check": report["design"],
        "verification": verification,
    }


def rod_figures(rows: list[dict]) -> dict:
    """Rods, rods whose design check balanced, median plant seconds, verified successes and starts summed."""
    figures = {"rods": len(rows), "rods_design_balanced": sum(r["design_all_balanced"] for r in rows)}
    figures["median_plant_s"] = statistics.median(r["plant_s"] for r in rows)
    for key in [k for k in rows[0] if k.endswith(("_successes", "_starts"))]:
        figures[key] = sum(r[key] for r in rows)
    return figures


def main() -> None:  # the twin's side runs in spawned children, which import this file
    parser = argparse.ArgumentParser()
    parser.add_argument("--work", default="runs/commission_probe")
    parser.add_argument("--out", default="book/records/commission_probe.json")
    parser.add_argument("--rods", type=int, default=len(SEEDS))
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS), help="the unknown rods' twin seeds")
    parser.add_argument("--verify-starts", type=int, default=10)
    args = parser.parse_args()
    config = CommissionConfig(verify_starts=args.verify_starts)
    outputs = Outputs()
    outputs.file(args.out, "--out")
    rods = []
    for seed in args.seeds[: args.rods]:
        started = time.perf_counter()
        report = commission(f"{args.work}/rod_{seed}", TwinTruth(seed=seed), config)
        rods.append(rod_row(seed, report, time.perf_counter() - started))
        summary = {
            "title": "softpend rig commission (excite, identify, design, verify) on unknown twin rods, per rod",
            "command": "scripts/probe_commission.py "
            + " ".join(
                f"--{k.replace('_', '-')} {' '.join(map(str, v)) if isinstance(v, list) else v}"
                for k, v in vars(args).items()
            ),
            "settings": config.__dict__,
            "figures": rod_figures(rods),
            "rows": rods,
        }
        outputs.write_text(args.out, record_text(summary))
        print(json.dumps({"twin_seed": seed, "verification": report["verification"]}, default=str), flush=True)


if __name__ == "__main__":
    main()
