"""PILCO against DQN and DQN-MBPO in training plant seconds (Figure 10): PILCO's run cache, curves, table and plots."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from softpend.evaluation import SUCCESS_STD_RAD
from softpend.io.reading import read_json_object
from softpend.io.runfolders import check_run_folder
from softpend.pilco.loop import PilcoConfig, PilcoResult, run_pilco
from softpend.rl.curves import failures_as
from softpend.study.rl_runs import run_folder
from softpend.study.sweep import run_jobs


def pilco_runs(
    config: PilcoConfig,
    seeds: Sequence[int],
    runs_root: Path | str = "runs/pilco-book",
    progress: bool = True,
    workers: Optional[int] = None,
    backend: Optional[str] = None,
) -> list[PilcoResult]:
    """Run (or reuse) PILCO once per seed under ``runs_root``, the missing seeds in parallel; the results."""
    jobs = pilco_jobs(config, seeds, runs_root)
    run_jobs(run_and_save, [a for _, a in jobs], [n for n, _ in jobs], workers, progress, "PILCO runs", backend)
    seeded = (dataclasses.replace(config, seed=int(seed)) for seed in seeds)
    return [PilcoResult.load(run_folder(runs_root, "pilco", c.seed, c)) for c in seeded]


def pilco_jobs(config: PilcoConfig, seeds: Sequence[int], runs_root: Path | str) -> list[tuple[str, tuple[Any, ...]]]:
    """The PILCO runs missing under ``runs_root`` as ``(name, arguments of run_and_save)``; ``ValueError`` for a
    folder holding a run of other settings."""
    if len(seeds) == 0:
        raise ValueError("seeds must not be empty")
    jobs: dict[str, tuple[Any, ...]] = {}  # by folder name: a seed listed twice runs once
    for seed in seeds:
        seeded = dataclasses.replace(config, seed=int(seed))
        folder = run_folder(runs_root, "pilco", int(seed), seeded)
        if folder.name not in jobs and _saved_run(folder, seeded) is None:
            refuse_other_pilco_run(folder, seeded)
            jobs[folder.name] = (seeded, folder)
    return list(jobs.items())


def refuse_other_pilco_run(folder: Path | str, config: PilcoConfig) -> None:
    """``ValueError`` if ``folder`` holds a PILCO run of other settings than ``config``."""
    if (path := Path(folder) / "pilco.json").exists():
        saved = read_json_object(path, 10**8)
        settings = json.loads(json.dumps(config.to_dict(), default=float))
        check_run_folder(folder, saved.get("config") if saved else None, settings, None, config.seed, False, False)


def _saved_run(folder: Path, config: PilcoConfig) -> Optional[PilcoResult]:
    """The finished run saved in ``folder`` if it was made with ``config``, else None."""
    if not (folder / "pilco.json").exists():
        return None
    try:
        previous = PilcoResult.load(folder)
    except (ValueError, KeyError, TypeError):
        return None
    return previous if previous.config == config else None


def run_and_save(config: PilcoConfig, folder: Path, progress: bool = True) -> None:
    """One PILCO run saved to ``folder``, which must not hold one yet."""
    if (Path(folder) / "pilco.json").exists():
        raise ValueError(f"run folder {folder} already holds a PILCO run; a run folder is never trained over")
    run_pilco(config, progress=progress).save(folder)


#: The figures of a curve row, after ``method`` and ``seed``.
_CURVE = ("plant_s", "success_rate", "max_upright_std_rad")


def curve_rows_pilco(results: Sequence[PilcoResult]) -> list[dict[str, Any]]:
    """One curve row per evaluated PILCO policy."""
    return [
        {"method": "PILCO", "seed": result.config.seed}
        | dict(zip(_CURVE, (r.plant_seconds_total, r.eval_success_rate, r.eval_upright_std_rad)))
        for result in results
        for r in result.records
        if r.kind == "policy" and not math.isnan(r.eval_success_rate)
    ]


def curve_rows_rl(logs_by_method: dict[str, Sequence[Any]]) -> list[dict[str, Any]]:
    """The curve rows of the evaluations of training logs, by method."""
    return [
        {"method": method, "seed": log.seed, **{k: float(row[k]) for k in _CURVE}}
        for method, logs in logs_by_method.items()
        for log in logs
        for row in log.evaluations
    ]


def seconds_to_balance_table(
    rows: Sequence[dict[str, Any]], std_levels_rad: Sequence[float] = (0.2, 0.1)
) -> list[dict[str, Any]]:
    """Per method, medians over seeds: plant seconds to the first evaluation succeeding on every start within each
    std level (``inf``: never), and the final evaluation's figures."""
    table = []
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        seeds = sorted({r["seed"] for r in mine})
        entry: dict[str, Any] = {"method": method, "seeds": len(seeds)}
        for level in std_levels_rad:
            ok = [r for r in mine if r["success_rate"] >= 1.0 and r["max_upright_std_rad"] <= level]
            per_seed = [min((float(r["plant_s"]) for r in ok if r["seed"] == s), default=math.inf) for s in seeds]
            entry[f"plant_s_to_std_{level:g}_rad"] = float(np.median(per_seed))
        finals = [max((r for r in mine if r["seed"] == s), key=lambda r: r["plant_s"]) for s in seeds]
        for key, name in zip(_CURVE, ("training_plant_s", "final_success_rate", "final_max_upright_std_rad")):
            entry[name] = float(np.median([f[key] for f in finals]))
        table.append(entry)
    return table


def plot_head_to_head(rows: Sequence[dict[str, Any]], target_std_rad: float = 0.1):
    """Success rate and worst-start upright error against training plant seconds, a line per method and seed."""
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_e) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, method in enumerate(dict.fromkeys(r["method"] for r in rows)):
        colour = colours[i % len(colours)]
        mine = [r for r in rows if r["method"] == method]
        for j, seed in enumerate(sorted({r["seed"] for r in mine})):
            seq = sorted((r for r in mine if r["seed"] == seed), key=lambda r: r["plant_s"])
            t, rate = [max(r["plant_s"], 1e-3) for r in seq], [r["success_rate"] for r in seq]
            style = dict(color=colour, alpha=0.7, ms=3, label=method if j == 0 else None)
            ax_s.plot(t, rate, "o-", **style)
            ax_e.plot(t, failures_as([r["max_upright_std_rad"] for r in seq], rate, SUCCESS_STD_RAD), "o-", **style)
    for ax in (ax_s, ax_e):
        ax.set(xscale="log", xlabel="training plant time [s]")
        ax.grid(True, which="both", alpha=0.3)
    ax_s.set(ylabel="evaluation success rate\n(DQN, DQN-MBPO: the starts before the first failure)", ylim=(-0.05, 1.05))
    ax_e.set_yscale("log")
    ax_e.set_ylabel(f"worst-start upright error (std of theta) [rad]\n({SUCCESS_STD_RAD:g} when a start failed)")
    ax_e.axhline(target_std_rad, color="k", ls="--", lw=1, label=f"target {target_std_rad:g} rad")
    ax_s.legend(loc="upper left")
    ax_e.legend(loc="lower left")
    return fig


def plot_predicted_and_real_cost(results: Sequence[PilcoResult]):
    """PILCO's predicted (dashed) and real (solid) summed cost of each policy trial, per seed."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, ax = plt.subplots(figsize=(6, 3.5), constrained_layout=True)
    for result in results:
        records = [r for r in result.records if r.kind == "policy"]
        trials = [r.index for r in records]
        (line,) = ax.plot(trials, [r.predicted_cost for r in records], "x--", alpha=0.8)
        real = [r.real_cost for r in records]
        ax.plot(trials, real, "o-", color=line.get_color(), alpha=0.8, label=f"seed {result.config.seed}")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("trial")
    ax.set(ylabel="summed cost over the trial", title="predicted (dashed) and real (solid) cost per trial")
    ax.legend()
    return fig
