"""Do two trainings of the book's runs repeat each other episode for episode?  OLD holds run folders named
``<method>-seed<k>`` (before run folders were named by their settings' hash), NEW ``<method>-<hash>-seed<k>``;
for DQN and DQN-MBPO every field of every episode and evaluation record is compared (the measured wall and CPU
seconds excepted), and the tensors of the final and best agents (and of DQN-MBPO's dynamics model); for PILCO every
field of every trial record (but the measured seconds), the GP hyperparameters and the policy tensors.

    .venv/bin/python scripts/probe_compare_runs.py --old OLD_ROOT --new NEW_ROOT --out book/records/NAME.json \
        [--seeds 0 1 ...] [--note "what OLD and NEW were trained from"]
"""

import argparse
import io
import json
import math
import zipfile
from pathlib import Path

import torch

from softpend.io.outputs import Outputs
from softpend.study.records import record_text

#: Record fields that are measured times, not results.
MEASURED = ("wall_s", "cpu_s")


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return a == b


def _differing(old: list[dict], new: list[dict]) -> int:
    """Fields that differ over the records of two lists (measured times left out); a length mismatch counts."""
    fields = [k for row in old for k in row if not k.startswith(MEASURED)]
    count = abs(len(old) - len(new))
    return count + sum(not _same(a.get(k), b.get(k)) for a, b in zip(old, new) for k in fields if k in a)


def _tensors_equal(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        torch.equal(a[k], b[k]) if torch.is_tensor(a[k]) else _same(a[k], b[k]) for k in a
    )


def _agent(path: Path) -> dict:
    with zipfile.ZipFile(path) as archive:
        return torch.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)


def _new_folder(root: Path, method: str, seed: int) -> Path:
    found = sorted(root.glob(f"{method}-*-seed{seed}"))
    if len(found) != 1:
        raise SystemExit(f"{root}: expected one {method}-<hash>-seed{seed} folder, found {len(found)}")
    return found[0]


def rl_row(old_root: Path, new_root: Path, method: str, seed: int) -> dict:
    old, new = old_root / f"{method}-seed{seed}", _new_folder(new_root, method, seed)
    log_old = json.loads((old / "log.json").read_text())
    log_new = json.loads((new / "log.json").read_text())
    equal = _tensors_equal(_agent(old / "agent.zip"), _agent(new / "agent.zip"))
    equal = equal and _tensors_equal(_agent(old / "best_agent.zip"), _agent(new / "best_agent.zip"))
    if method == "mbpo":
        dynamics = [torch.load(folder / "dynamics.pt", weights_only=True) for folder in (old, new)]
        equal = equal and _tensors_equal(*dynamics)
    return {
        "method": method,
        "seed": seed,
        "episodes_old": len(log_old["episodes"]),
        "episodes_new": len(log_new["episodes"]),
        "differing_fields": _differing(log_old["episodes"], log_new["episodes"])
        + _differing(log_old["evaluations"], log_new["evaluations"]),
        "weights_equal": equal,
    }


def pilco_row(old_root: Path, new_root: Path, seed: int) -> dict:
    old, new = old_root / f"pilco-seed{seed}", _new_folder(new_root, "pilco", seed)
    run_old = json.loads((old / "pilco.json").read_text())
    run_new = json.loads((new / "pilco.json").read_text())
    policies = [torch.load(folder / "policy.pt", weights_only=True) for folder in (old, new)]
    return {
        "method": "pilco",
        "seed": seed,
        "episodes_old": len(run_old["records"]),
        "episodes_new": len(run_new["records"]),
        "differing_fields": _differing(run_old["records"], run_new["records"])
        + (run_old["gp_hyperparameters"] != run_new["gp_hyperparameters"]),
        "weights_equal": _flat_equal(policies[0], policies[1]),
    }


def _flat_equal(a, b) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_flat_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_flat_equal(x, y) for x, y in zip(a, b))
    return torch.equal(a, b) if torch.is_tensor(a) else _same(a, b)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--old", type=Path, required=True, help="the project root of the first training")
    parser.add_argument("--new", type=Path, required=True, help="the project root of the second training")
    parser.add_argument("--out", type=Path, required=True, help="the record to write (JSON)")
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    parser.add_argument("--note", default="", help="what OLD and NEW were trained from")
    args = parser.parse_args()
    outputs = Outputs()
    outputs.file(args.out)
    rl_old, rl_new = args.old / "runs" / "rl-book", args.new / "runs" / "rl-book"
    pilco_old, pilco_new = args.old / "runs" / "pilco-book", args.new / "runs" / "pilco-book"
    rows = [rl_row(rl_old, rl_new, method, seed) for method in ("dqn", "mbpo") for seed in args.seeds]
    rows += [pilco_row(pilco_old, pilco_new, seed) for seed in args.seeds]
    identical = [r for r in rows if r["differing_fields"] == 0 and r["weights_equal"]]
    record = {
        "title": "the book's runs trained twice: episode for episode (" + args.note + ")",
        "command": f"scripts/probe_compare_runs.py --old {args.old} --new {args.new} --out {args.out} "
        + f"--seeds {' '.join(map(str, args.seeds))}",
        "settings": {"seeds": " ".join(map(str, args.seeds))},
        "figures": {"runs": len(rows), "runs_identical": len(identical)},
        "rows": rows,
    }
    outputs.write_text(args.out, record_text(record))
    print(record["figures"])


if __name__ == "__main__":
    main()
