"""Does a host-side check predict a commissioned controller's success on the twin?  For each ROD:LEARNER, the
learner's commissioned run (``--work``/rod_ROD, from scripts/probe_commission.py) is run from ten hanging starts of
its own (seeds 50000-50009, used by no other stage) on a twin of the IDENTIFIED rod (what the host knows) and on the
twin of the TRUE rod, in both sensor conditions; the record holds the successes of each.

    .venv/bin/python scripts/probe_host_check.py --work runs/commission_probe --out book/records/NAME.json \
        9201:dqn 9203:pilco ...
"""

import argparse
import json
import tempfile
from pathlib import Path

from softpend.io.outputs import Outputs
from softpend.study.records import record_text
from softpend.study.rig_runs import learned_controller, twin_start
from softpend.study.twin_side import CONDITIONS, TwinTruth, _resolve
from softpend.task import Task

SEEDS = tuple(range(50000, 50010))


def successes(controller, learner: str, task: Task, estimator_task: Task, condition: str) -> int:
    work = Path(tempfile.mkdtemp(prefix="softpend-host-check-"))
    rows = [
        twin_start(
            controller,
            learner,
            task,
            CONDITIONS[condition],
            seed,
            10.0,
            work / f"start_{seed}",
            estimator_task=estimator_task,
        )
        for seed in SEEDS
    ]
    return sum(bool(row["success"]) for row in rows)


def main() -> None:  # the twin's side may spawn children, which import this file
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("cases", nargs="+", metavar="ROD:LEARNER")
    args = parser.parse_args()
    outputs = Outputs()
    outputs.file(args.out, "--out")  # refused before any work when it cannot be written
    rows = []
    for case in args.cases:
        rod_seed, learner = int(case.split(":")[0]), case.split(":")[1]
        root = Path(args.work) / f"rod_{rod_seed}"
        run = json.loads((root / "train" / "train.json").read_text())["runs"][learner]
        controller, model_task, _ = learned_controller(str(root / run["folder"]), "best")
        identified = Task(rod=model_task.rod)
        true = Task(rod=_resolve(TwinTruth(seed=rod_seed), root / "twin", Outputs()).effective_rod())
        row = {"twin_seed": rod_seed, "learner": learner, "starts": len(SEEDS)}
        for side, task in (("identified", identified), ("true", true)):
            for condition in ("nominal", "harsh"):
                row[f"{side}_rod_{condition}_successes"] = successes(controller, learner, task, identified, condition)
                print(row, flush=True)
        rows.append(row)
    record = {
        "title": "host-side check: commissioned controllers on a twin of the identified rod and of the true rod",
        "command": "scripts/probe_host_check.py --work {} --out {} {}".format(
            args.work, args.out, " ".join(args.cases)
        ),
        "settings": {"seeds": f"{SEEDS[0]}-{SEEDS[-1]}", "duration_s": 10.0, "agent": "best"},
        "figures": {key: sum(r[key] for r in rows) for key in rows[0] if key.endswith("_successes")},
        "rows": rows,
    }
    outputs.write_text(args.out, record_text(record))


if __name__ == "__main__":
    main()
