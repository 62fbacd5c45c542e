"""``softpend bench --only commission``: ``softpend rig commission`` on the twins of five unknown rods (seeds no code
was tuned on): the worst fresh-start success on the nominal and the harsh twin, the excitation seconds, the largest
identification error (infinite when a parameter was held at the guess) and the plant seconds each controller class
(swing-up + LQR, DQN, DQN-MBPO, PILCO) used."""

from __future__ import annotations

import statistics
import tempfile

#: The unknown rods of the commissioning figures (9001-9005 and 9101-9105 were looked at while it was fixed).
UNKNOWN_ROD_SEEDS = (9201, 9202, 9203, 9204, 9205)
#: The figures' names of the commissioned classes that differ from their names in the report.
BENCH_NAMES = {"swingup": "swingup_lqr"}


def commission_figures(reports: list[dict]) -> dict[str, float]:
    """The group's figures from the commissioning reports of :func:`softpend.study.commission.commission`: the
    worst class on the worst rod per condition, and per class the median plant seconds."""
    from softpend.study.commission import identification_errors

    successes: dict[str, list[float]] = {}
    plant_s: dict[str, list[float]] = {}
    errors = []
    for report in reports:
        for name, entry in report["classes"].items():
            for row in entry["verification"]:
                successes.setdefault(row["condition"], []).append(10.0 * row["successes"] / row["starts"])
            plant_s.setdefault(BENCH_NAMES.get(name, name), []).append(entry["plant_s"])
        errors += identification_errors(report)
    return {
        "commission_success_min": min(successes["nominal"]),
        "commission_harsh_success_min": min(successes["harsh"]),
        "commission_identify_s": max(r["plant_s"]["excite"] for r in reports),
        "commission_max_param_error_pct": 100.0 * max(errors),
        **{f"commission_plant_s_{name}": statistics.median(values) for name, values in plant_s.items()},
    }


def bench_commission() -> dict[str, float]:
    """The ``commission`` benchmark group (see the module docstring)."""
    from softpend.study.commission import commissioned_rods

    with tempfile.TemporaryDirectory(prefix="softpend-bench-commission-") as work:
        return commission_figures(commissioned_rods(work, UNKNOWN_ROD_SEEDS))
