"""Does the identification's standard deviation cover its error?  From stored commissioning records (each rod's
identified parameters with their relative standard deviation and, on the twin's side, the truth), the error of
each parameter in standard deviations, ``z = |log(truth / estimate)| / relative_std``: the randomisation of the
commissioning draws each parameter within ``uncertainty_scale`` of them (``RodUncertainty``), so it holds the true
rod only where ``z <= uncertainty_scale``.  The scale that covers every parameter of every TUNING rod is found on
the tuning records only, then its coverage is measured on the HELD-OUT records; a rod whose identification missed
the 5 % target on some parameter is reported and left out of the calibration (no scale of its deviation covers it).

    .venv/bin/python scripts/probe_uncertainty_calibration.py --out book/records/NAME.json \
        --tuning book/records/commission_probe.json ... --held-out book/records/commission_unseen_rods_9201_9205.json \
        --compare-scale 2
"""

import argparse
import math
from pathlib import Path

from softpend.io.outputs import Outputs
from softpend.study.records import load_record, record_text

#: The identification's accuracy target (relative error); a rod beyond it on any parameter failed its identification.
TARGET_ERROR = 0.05


def rod_rows(path: str, role: str) -> list[dict]:
    """One row per rod of a record: each identified parameter's relative error and error in standard deviations."""
    rows = []
    for row in load_record(path)["rows"]:
        identified = row.get("identified")
        if not isinstance(identified, dict):
            continue
        out = {"record": Path(path).stem, "role": role, "rod": row.get("twin_seed")}
        for name, entry in identified.items():
            if "truth" not in entry or not entry.get("relative_std"):
                continue
            log_error = abs(math.log(entry["truth"] / entry["estimate"]))
            out[f"z_{name}"] = round(log_error / entry["relative_std"], 3)
            out[f"error_pct_{name}"] = round(100 * abs(entry["relative_error"]), 3)
        errors = [value for key, value in out.items() if key.startswith("error_pct_")]
        out["identified_within_target"] = max(errors) <= 100 * TARGET_ERROR
        out["max_z"] = max(value for key, value in out.items() if key.startswith("z_"))
        rows.append(out)
    return rows


def coverage(rows: list[dict], scale: float) -> tuple[int, int]:
    """(rods whose every parameter lies within ``scale`` deviations, rods)."""
    return sum(row["max_z"] <= scale for row in rows), len(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="the record to write (JSON)")
    parser.add_argument("--tuning", nargs="+", required=True, help="records the scale is calibrated on")
    parser.add_argument("--held-out", nargs="+", required=True, help="records its coverage is measured on")
    parser.add_argument("--compare-scale", type=float, required=True, help="the scale to compare it with")
    args = parser.parse_args()
    outputs = Outputs()
    outputs.file(Path(args.out))
    tuning = [row for path in args.tuning for row in rod_rows(path, "tuning")]
    held_out = [row for path in args.held_out for row in rod_rows(path, "held-out")]
    calibrated_on = [row for row in tuning if row["identified_within_target"]]
    scale = float(math.ceil(max(row["max_z"] for row in calibrated_on)))
    judged = [row for row in held_out if row["identified_within_target"]]
    figures = {
        "calibrated_scale": scale,
        "compared_scale": args.compare_scale,
        "tuning_rods": len(calibrated_on),
        "tuning_rods_failed_identification": len(tuning) - len(calibrated_on),
        "tuning_max_z": max(row["max_z"] for row in calibrated_on),
        "held_out_rods": len(judged),
        "held_out_rods_failed_identification": len(held_out) - len(judged),
        "held_out_max_z": max(row["max_z"] for row in judged),
        "held_out_covered_at_compared_scale": coverage(judged, args.compare_scale)[0],
        "held_out_covered_at_calibrated_scale": coverage(judged, scale)[0],
    }
    record = {
        "title": "identification uncertainty: errors in standard deviations, the scale that covers them",
        "command": "scripts/probe_uncertainty_calibration.py --out "
        + f"{args.out} --tuning {' '.join(args.tuning)} --held-out {' '.join(args.held_out)} "
        + f"--compare-scale {args.compare_scale:g}",
        "settings": {"target_error": TARGET_ERROR},
        "figures": figures,
        "rows": tuning + held_out,
    }
    outputs.write_text(Path(args.out), record_text(record))
    print(figures)


if __name__ == "__main__":
    main()
