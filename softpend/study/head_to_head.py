"""PILCO against DQN and DQN-MBPO in real plant seconds (Figure 10).

All three methods are measured the same way: after each training trial/episode block the current policy is
run by the shared :func:`softpend.evaluation.evaluate_controller` on the true plant from hanging (these test
episodes are not learned from and are not counted), and the curve is plotted against the *training* plant
seconds consumed so far.  PILCO's points come from :class:`~softpend.pilco.loop.TrialRecord` (one per policy
trial), DQN's and DQN-MBPO's from the evaluation rows of :class:`softpend.rl.training_log.TrainingLog`.
DQN's and DQN-MBPO's evaluations stop at their first failing start
(:attr:`softpend.rl.DQNConfig.eval_until_first_failure`): their success rate counts the starts before it, a lower
bound, and is exact when every start succeeded, the only rows the seconds-to-balance table counts.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from softpend.evaluation import SUCCESS_STD_RAD
from softpend.io.reading import read_json_object
from softpend.pilco.loop import PilcoConfig, PilcoResult, run_pilco
from softpend.rl.curves import failures_as
from softpend.study.sweep import run_jobs

__all__ = [
    "curve_rows_pilco",
    "curve_rows_rl",
    "pilco_jobs",
    "pilco_runs",
    "plot_head_to_head",
    "plot_predicted_and_real_cost",
    "run_and_save",
    "seconds_to_balance_table",
]


def pilco_runs(
    config: PilcoConfig,
    seeds: Sequence[int],
    runs_root: Path | str = "runs/pilco-book",
    progress: bool = True,
    workers: Optional[int] = None,
    backend: Optional[str] = None,
) -> list[PilcoResult]:
    """Run (or reuse) PILCO once per seed into ``<runs_root>/pilco-<hash>-seed<k>``
    (:func:`softpend.study.rl_runs.run_folder`: ``<hash>`` names the settings).

    A folder is reused when it holds a finished run with the same config (the seed replaced); the other seeds
    run in parallel, up to ``workers`` at a time (default: one per CPU core, see
    :func:`softpend.study.sweep.default_workers`), each with one torch thread.
    """
    jobs = pilco_jobs(config, seeds, runs_root)
    run_jobs(
        run_and_save,
        [args for _, args in jobs],
        [name for name, _ in jobs],
        workers,
        progress,
        desc="PILCO runs",
        backend=backend,
    )
    from softpend.study.rl_runs import run_folder

    return [
        PilcoResult.load(run_folder(runs_root, "pilco", int(seed), dataclasses.replace(config, seed=int(seed))))
        for seed in seeds
    ]


def pilco_jobs(config: PilcoConfig, seeds: Sequence[int], runs_root: Path | str) -> list[tuple[str, tuple[Any, ...]]]:
    """The PILCO runs (``config`` with each seed) still missing under ``runs_root``, as ``(name, arguments of
    :func:`run_and_save`)``; a folder holding a finished run with the same config is left out.  A folder that
    holds a run of other settings (a hash collision, or one this version cannot read) raises ``ValueError``:
    it is never trained over."""
    from softpend.io.runfolders import check_run_folder
    from softpend.study.rl_runs import run_folder

    if len(seeds) == 0:
        raise ValueError("seeds must not be empty")
    jobs: dict[str, tuple[Any, ...]] = {}  # by folder name: a seed listed twice runs once
    for seed in seeds:
        seeded = dataclasses.replace(config, seed=int(seed))
        folder = run_folder(runs_root, "pilco", int(seed), seeded)
        if folder.name not in jobs and _saved_run(folder, seeded) is None:
            if (folder / "pilco.json").exists():
                saved = read_json_object(folder / "pilco.json", 10**8)
                check_run_folder(
                    folder,
                    saved.get("config") if saved else None,
                    json.loads(json.dumps(seeded.to_dict(), default=float)),
                    None,
                    int(seed),
                    resume=False,
                    can_resume=False,
                )
            jobs[folder.name] = (seeded, folder)
    return list(jobs.items())


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
    """One PILCO run saved to ``folder`` (a job of :func:`softpend.study.sweep.run_jobs`), which must not hold
    a PILCO run yet (``ValueError``: a run folder is never trained over)."""
    if (Path(folder) / "pilco.json").exists():
        raise ValueError(f"run folder {folder} already holds a PILCO run; a run folder is never trained over")
    run_pilco(config, progress=progress).save(folder)


def curve_rows_pilco(results: Sequence[PilcoResult], method: str = "PILCO") -> list[dict[str, Any]]:
    """One row per evaluated PILCO policy: ``method, seed, plant_s, success_rate, max_upright_std_rad``."""
    rows = []
    for result in results:
        for record in result.records:
            if record.kind != "policy" or math.isnan(record.eval_success_rate):
                continue
            rows.append(
                {
                    "method": method,
                    "seed": result.config.seed,
                    "plant_s": record.plant_seconds_total,
                    "success_rate": record.eval_success_rate,
                    "max_upright_std_rad": record.eval_upright_std_rad,
                }
            )
    return rows


def curve_rows_rl(logs_by_method: dict[str, Sequence[Any]]) -> list[dict[str, Any]]:
    """The same rows from the evaluation tables of :class:`softpend.rl.training_log.TrainingLog` objects."""
    rows = []
    for method, logs in logs_by_method.items():
        for log in logs:
            for row in log.evaluations:
                rows.append(
                    {
                        "method": method,
                        "seed": log.seed,
                        "plant_s": float(row["plant_s"]),
                        "success_rate": float(row["success_rate"]),
                        "max_upright_std_rad": float(row["max_upright_std_rad"]),
                    }
                )
    return rows


def _first_balanced_s(rows: Sequence[dict[str, Any]], std_rad: float) -> float:
    for row in sorted(rows, key=lambda r: r["plant_s"]):
        if row["success_rate"] >= 1.0 and row["max_upright_std_rad"] <= std_rad:
            return float(row["plant_s"])
    return math.inf


def seconds_to_balance_table(
    rows: Sequence[dict[str, Any]], std_levels_rad: Sequence[float] = (0.2, 0.1)
) -> list[dict[str, Any]]:
    """Per method: median over seeds of the training plant seconds until an evaluation on which every seed
    succeeds with ``max_upright_std_rad`` at most each level (``inf`` when a seed never does), plus the
    final evaluation's success rate and upright error (medians over seeds)."""
    table = []
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        seeds = sorted({r["seed"] for r in mine})
        entry: dict[str, Any] = {"method": method, "seeds": len(seeds)}
        for level in std_levels_rad:
            per_seed = [_first_balanced_s([r for r in mine if r["seed"] == s], level) for s in seeds]
            entry[f"plant_s_to_std_{level:g}_rad"] = float(np.median(per_seed))
        finals = [max((r for r in mine if r["seed"] == s), key=lambda r: r["plant_s"]) for s in seeds]
        entry["training_plant_s"] = float(np.median([f["plant_s"] for f in finals]))
        entry["final_success_rate"] = float(np.median([f["success_rate"] for f in finals]))
        entry["final_max_upright_std_rad"] = float(np.median([f["max_upright_std_rad"] for f in finals]))
        table.append(entry)
    return table


def plot_head_to_head(rows: Sequence[dict[str, Any]], target_std_rad: float = 0.1):
    """Success rate and upright error against training plant seconds, one colour per method, a line per seed.

    The upright error is the worst start's, drawn at the success level :data:`softpend.evaluation.SUCCESS_STD_RAD`
    for an evaluation in which a start failed.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_e) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, method in enumerate(dict.fromkeys(r["method"] for r in rows)):
        colour = colours[i % len(colours)]
        mine = [r for r in rows if r["method"] == method]
        for j, seed in enumerate(sorted({r["seed"] for r in mine})):
            seq = sorted((r for r in mine if r["seed"] == seed), key=lambda r: r["plant_s"])
            t = [max(r["plant_s"], 1e-3) for r in seq]
            label = method if j == 0 else None
            ax_s.plot(t, [r["success_rate"] for r in seq], "o-", color=colour, alpha=0.7, ms=3, label=label)
            worst = failures_as(
                [r["max_upright_std_rad"] for r in seq], [r["success_rate"] for r in seq], SUCCESS_STD_RAD
            )
            ax_e.plot(t, worst, "o-", color=colour, alpha=0.7, ms=3, label=label)
    for ax in (ax_s, ax_e):
        ax.set_xscale("log")
        ax.set_xlabel("training plant time [s]")
        ax.grid(True, which="both", alpha=0.3)
    ax_s.set_ylabel("evaluation success rate\n(DQN, DQN-MBPO: the starts before the first failure)")
    ax_s.set_ylim(-0.05, 1.05)
    ax_e.set_yscale("log")
    ax_e.set_ylabel(f"worst-start upright error (std of theta) [rad]\n({SUCCESS_STD_RAD:g} when a start failed)")
    ax_e.axhline(target_std_rad, color="k", ls="--", lw=1, label=f"target {target_std_rad:g} rad")
    ax_s.legend(loc="upper left")
    ax_e.legend(loc="lower left")
    return fig


def plot_predicted_and_real_cost(results: Sequence[PilcoResult]):
    """PILCO's predicted (dashed, crosses) and real (solid, dots) summed cost of each policy trial, per seed.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, ax = plt.subplots(figsize=(6, 3.5), constrained_layout=True)
    for result in results:
        records = [r for r in result.records if r.kind == "policy"]
        trials = [r.index for r in records]
        (line,) = ax.plot(trials, [r.predicted_cost for r in records], "x--", alpha=0.8)
        ax.plot(
            trials,
            [r.real_cost for r in records],
            "o-",
            color=line.get_color(),
            alpha=0.8,
            label=f"seed {result.config.seed}",
        )
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("trial")
    ax.set_ylabel("summed cost over the trial")
    ax.set_title("predicted (dashed) and real (solid) cost per trial")
    ax.legend()
    return fig
