"""Commission the unknown rods of seeds 9001..9005 on the twin (softpend rig commission's stages) and store a
summary per rod; a rod's folder under --work resumes where an earlier run stopped.

    .venv/bin/python scripts/probe_commission.py [--work runs/commission_probe]
        [--out book/records/commission_probe.json] [--rods 5] [--verify-starts 10]
"""

import argparse
import json
import time

from softpend.io.outputs import Outputs
from softpend.study.commission import CommissionConfig, commission
from softpend.study.twin_side import TwinTruth

SEEDS = (9001, 9002, 9003, 9004, 9005)


def main() -> None:  # the twin's side runs in spawned children, which import this file
    parser = argparse.ArgumentParser()
    parser.add_argument("--work", default="runs/commission_probe")
    parser.add_argument("--out", default="book/records/commission_probe.json")
    parser.add_argument("--rods", type=int, default=len(SEEDS))
    parser.add_argument("--verify-starts", type=int, default=10)
    args = parser.parse_args()
    config = CommissionConfig(verify_starts=args.verify_starts)
    outputs = Outputs()
    outputs.file(args.out, "--out")
    rods = []
    for seed in SEEDS[: args.rods]:
        started = time.perf_counter()
        report = commission(f"{args.work}/rod_{seed}", TwinTruth(seed=seed), config)
        rods.append(
            {
                "twin_seed": seed,
                "plant_s": report["plant_s"],
                "identified": report["identified"],
                "design_check": report["design"],
                "verification": report["verification"],
                "wall_s": time.perf_counter() - started,
            }
        )
        summary = {
            "command": "scripts/probe_commission.py "
            + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()),
            "settings": config.__dict__,
            "rods": rods,
        }
        outputs.write_json(args.out, summary)
        print(json.dumps({"twin_seed": seed, "verification": report["verification"]}, default=str), flush=True)


if __name__ == "__main__":
    main()
