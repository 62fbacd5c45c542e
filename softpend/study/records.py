"""The record of settings tried for each method (``book/records/what_we_tried.yml``) as the appendix's tables
and plot, beside the same figures read from the current run folders.  An outcome is a number (the measure at
which the run first balanced), a string (did not balance) or ``"-"`` (a seed not run)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np

#: The record, relative to the project root.
RECORDS_PATH = Path("book/records/what_we_tried.yml")

#: Required fields of a method and of a run.
METHOD_FIELDS = ("title", "measure", "unit", "legend", "budget", "runs", "diagnostics")
RUN_FIELDS = ("setting", "seeds", "outcome", "notes")

NOT_RUN = "-"


def load_records(path: Path | str = RECORDS_PATH) -> dict[str, dict[str, Any]]:
    """The methods of the record, by key, checked (``ValueError`` for a missing field, seeds that are not integers,
    outcomes or details not keyed by the run's seeds, or ``"all"`` for a run without seeds)."""
    from softpend.io.reading import read_yaml_checked

    data = read_yaml_checked(path, "records file")
    if not isinstance(data, dict) or not isinstance(data.get("methods"), dict) or not data["methods"]:
        raise ValueError(f"{path}: methods must be a non-empty mapping")
    for key, method in data["methods"].items():
        missing = [f for f in METHOD_FIELDS if f not in (method or {})]
        if missing:
            raise ValueError(f"{path}: method {key!r} lacks {missing}")
        for table in ("runs", "diagnostics"):
            if not isinstance(method[table], list):
                raise ValueError(f"{path}: {key}.{table} must be a list")
            for index, run in enumerate(method[table]):
                _check_run(run, f"{path}: {key}.{table}[{index}]")
    return data["methods"]


def _check_run(run: Any, where: str) -> None:
    if not isinstance(run, dict):
        raise ValueError(f"{where} must be a mapping")
    missing = [f for f in RUN_FIELDS if f not in run]
    if missing:
        raise ValueError(f"{where} lacks {missing}")
    seeds = run["seeds"]
    if not isinstance(seeds, list) or any(isinstance(s, bool) or not isinstance(s, int) for s in seeds):
        raise ValueError(f"{where}: seeds must be a list of integers, got {seeds!r}")
    keys = set(seeds) if seeds else {"all"}
    if not isinstance(run["outcome"], dict) or set(run["outcome"]) != keys:
        raise ValueError(
            f"{where}: outcome must have one entry per seed ({sorted(keys, key=str)}), got {run['outcome']!r}"
        )
    details = run.get("details", {})
    if not isinstance(details, dict) or not set(details) <= keys:
        raise ValueError(f"{where}: details must be keyed by the run's seeds, got {details!r}")


def _value(outcome: Any) -> Optional[float]:
    """The measure of one outcome: the number, ``inf`` (did not balance), ``None`` (not run)."""
    if isinstance(outcome, bool):
        raise ValueError(f"an outcome must be a number or a string, got {outcome!r}")
    if isinstance(outcome, (int, float)):
        return float(outcome)
    return None if str(outcome).strip() == NOT_RUN else math.inf


def _summary(outcomes: Sequence[Any]) -> tuple[str, float]:
    """``("k of n", median)`` over the seeds that were run."""
    values = [v for v in (_value(o) for o in outcomes) if v is not None]
    balanced = sum(math.isfinite(v) for v in values)
    return f"{balanced} of {len(values)}", float(np.median(values)) if values else math.nan


def _cell(value: Any) -> Any:
    return value.replace("|", "\\|") if isinstance(value, str) else value


def _format(value: float) -> str:
    return "never" if math.isinf(value) else ("" if math.isnan(value) else f"{value:g}")


def run_rows(
    method: Mapping[str, Any], table: str = "runs", current: Sequence[Mapping[str, Any]] = ()
) -> tuple[list[dict[str, Any]], list[str]]:
    """Rows and columns of one table of a method: a row per run (``current`` rows last), a column per seed, then
    for ``runs`` the seeds that balanced, the median, the unit; and the notes."""
    runs = list(method[table]) + list(current)
    seeds = sorted({s for run in runs for s in run["seeds"]})
    seed_columns = [f"seed {s}" for s in seeds] + (["all seeds"] if any(not run["seeds"] for run in runs) else [])
    summarise = table == "runs" and bool(method["unit"])
    rows = []
    for number, run in enumerate(runs, start=1):
        row: dict[str, Any] = {
            "row": number,
            "setting": run["setting"] + (" **(defaults)**" if run.get("defaults") else ""),
        }
        row.update({column: "" for column in seed_columns})
        for key, outcome in run["outcome"].items():
            row["all seeds" if key == "all" else f"seed {key}"] = outcome
        if summarise:
            row["balanced"], row["median"] = "", ""
            if run["seeds"]:  # a run that names no seeds says nothing about how many balanced
                row["balanced"], median = _summary(list(run["outcome"].values()))
                row["median"] = _format(median)
            row["unit"] = run.get("unit", method["unit"])
        row["notes"] = run["notes"]
        rows.append({k: _cell(v) for k, v in row.items()})
    columns = ["row", "setting", *seed_columns] + (["balanced", "median", "unit"] if summarise else []) + ["notes"]
    return rows, columns


def detail_rows(method: Mapping[str, Any], table: str = "runs") -> list[dict[str, Any]]:
    """One row per run and seed with details: ``{row, seed, details}`` (``row`` as in :func:`run_rows`)."""
    return [
        {"row": number, "seed": seed, "details": _cell(text)}
        for number, run in enumerate(method[table], start=1)
        for seed, text in run.get("details", {}).items()
    ]


def summary_rows(
    records: Mapping[str, Mapping[str, Any]], current: Mapping[str, Sequence[Mapping[str, Any]]] = {}
) -> list[dict[str, Any]]:
    """Per method, the recorded runs of the defaults and the current runs: seeds that balanced and the median."""
    rows = []
    for key, method in records.items():
        if not method["unit"]:
            continue
        groups = [
            ("recorded runs of the defaults", [r for r in method["runs"] if r.get("defaults")]),
            ("the book's current runs", list(current.get(key, ()))),
        ]
        for what, runs in groups:
            outcomes = [o for run in runs if run["seeds"] for o in run["outcome"].values()]
            if not outcomes:
                continue
            seeds = sorted(s for run in runs for s in run["seeds"])
            balanced, median = _summary(outcomes)
            rows.append(
                {
                    "key": key,
                    "current": what != groups[0][0],
                    "method": method["title"],
                    "runs": what,
                    "seeds": ", ".join(map(str, seeds)),
                    "balanced": balanced,
                    "median": _format(median),
                    "unit": method["unit"],
                }
            )
    return rows


def current_rl_runs(runs_root: Path | str, algo: str, seeds: Sequence[int], plant: str = "prb") -> list[dict[str, Any]]:
    """The book's current runs of one RL method as a record run: plant seconds at the first balanced evaluation."""
    from softpend.rl.config import load_config
    from softpend.rl.training_log import TrainingLog
    from softpend.study.rl_runs import plant_runs_root, run_folder

    outcome, details = {}, {}
    for seed in seeds:
        folder = run_folder(plant_runs_root(runs_root, plant), algo, int(seed))
        try:
            load_config(folder / "config.json")
            log = TrainingLog.load(folder / "log.json")
        except (FileNotFoundError, ValueError, KeyError):
            continue
        value = log.real_s_to_balance()
        outcome[int(seed)] = float(value) if math.isfinite(value) else f"never within {log.plant_s:g} plant s"
        details[int(seed)] = f"{log.n_episodes} episodes"
    return _current_run(outcome, details, f"{runs_root} (plant {plant})")


def current_pilco_runs(runs_root: Path | str, seeds: Sequence[int], plant: str = "prb") -> list[dict[str, Any]]:
    """The book's current PILCO runs as a record run: plant seconds up to the first policy that balances."""
    from softpend.pilco.loop import PilcoResult
    from softpend.study.rl_runs import plant_runs_root, run_folder

    outcome, details = {}, {}
    for seed in seeds:
        folder = run_folder(plant_runs_root(runs_root, plant), "pilco", int(seed))
        try:
            result = PilcoResult.load(folder)
        except (FileNotFoundError, ValueError, KeyError, TypeError):
            continue
        value = result.real_seconds_to_balance
        outcome[int(seed)] = float(value) if math.isfinite(value) else f"not within {result.plant_seconds_total:g} s"
        policy_trials = sum(r.kind == "policy" for r in result.records)
        worst = result.records[-1].eval_upright_std_rad if result.records else math.nan
        details[int(seed)] = (
            f"{policy_trials} policy trials, worst test std {worst:.2g} rad, {result.train_cpu_s:.0f} CPU s"
        )
    return _current_run(outcome, details, f"{runs_root} (plant {plant})")


def _current_run(outcome: dict, details: dict, where: str) -> list[dict[str, Any]]:
    if not outcome:
        return []
    return [
        {
            "setting": f"the current defaults: the book's runs in {where}",
            "seeds": sorted(outcome),
            "outcome": outcome,
            "details": details,
            "notes": "computed from the run folders",
        }
    ]


def plot_records(records: Mapping[str, Mapping[str, Any]], current: Mapping[str, Sequence[Mapping[str, Any]]] = {}):
    """One panel per method with a unit: each run's outcome per seed (crosses at the right edge: did not balance)."""
    import matplotlib.pyplot as plt

    keys = [k for k, m in records.items() if m["unit"]]
    heights = [len(records[k]["runs"]) + len(current.get(k, ())) for k in keys]
    fig, axes = plt.subplots(
        len(keys), 1, figsize=(8, 1.2 + 0.28 * sum(heights)), squeeze=False, gridspec_kw={"height_ratios": heights}
    )
    for ax, key in zip(axes[:, 0], keys):
        method = records[key]
        runs = list(method["runs"]) + list(current.get(key, ()))
        finite = [
            v
            for run in runs
            for v in map(_value, run["outcome"].values())
            if v is not None and math.isfinite(v) and run.get("unit", method["unit"]) == method["unit"]
        ]
        edge = 1.15 * max(finite) if finite else 1.0
        for number, run in enumerate(runs, start=1):
            if not run["seeds"]:  # no per-seed outcome to draw
                continue
            same_unit = run.get("unit", method["unit"]) == method["unit"]
            color = "C1" if run.get("defaults") else ("C2" if run in current.get(key, ()) else "C0")
            for outcome in run["outcome"].values():
                value = _value(outcome)
                if value is None or not same_unit:
                    continue
                if math.isfinite(value):
                    ax.plot(value, number, "o", color=color, alpha=0.8)
                else:
                    ax.plot(edge, number, "x", color=color, alpha=0.8)
        ax.axvline(edge, color="0.8", lw=0.8)
        ax.set_yticks(range(1, len(runs) + 1))
        ax.set_ylim(len(runs) + 0.5, 0.5)
        ax.set_xlim(0, 1.05 * edge)
        ax.set_ylabel("row")
        ax.set_title(method["title"], fontsize=10, loc="left")
        ax.set_xlabel(f"{method['unit']} (crosses at the grey line: did not balance)")
    fig.tight_layout()
    return fig
