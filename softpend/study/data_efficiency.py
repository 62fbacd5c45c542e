"""Plant seconds to balance: the grey-box route per seed, measured afterwards on the fresh report starts."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional, Sequence

import numpy as np
import torch

from softpend.control.identified import RouteConfig, design_swingup, identify_until_robust, simulated_recorder
from softpend.control.planner import PlannerConfig, fresh_start_evaluation, run_planner
from softpend.evaluation import TEST_EPISODE_S, evaluate
from softpend.plant import RodParams
from softpend.stats import aggregate_interval
from softpend.study.fresh_starts import fresh_start_row, pilco_fresh_start_rows, seed_rows
from softpend.study.greybox import perturbed_guess
from softpend.study.head_to_head import pilco_jobs, pilco_runs
from softpend.study.presets import HPARAMS_DIR, REPORT_SEEDS, SELECTION_SEEDS, load_hparams, load_settings
from softpend.sysid.greybox import GreyBoxConfig, identify
from softpend.task import Task
from softpend.torch_threads import one_torch_thread

#: Methods of the plant-seconds chapter, in plot order: key -> label.
METHODS = {
    "dqn": "model-free DQN",
    "mbpo": "DQN-MBPO",
    "pilco": "PILCO",
    "greybox": "grey-box route",
    "greybox_beam": "grey-box route, beam as the rod",
    "mpc": "MPPI planner, PRB + residual",
    "mpc_blackbox": "MPPI planner, black-box ensemble",
    "mpc_beam": "MPPI planner, PRB + residual, beam as the rod",
}


def greybox_route_rows(
    plant: str = "prb",
    seeds: Iterable[int] = range(10),
    report_seeds: Sequence[int] = REPORT_SEEDS,
    duration_s: float = TEST_EPISODE_S,
) -> list[dict[str, Any]]:
    """One row per seed: the route on ``plant`` from the perturbed guess, then its controller on ``report_seeds``
    (``real_s_to_balance``: its plant seconds, infinite when it does not balance them)."""
    task, config, rows = Task(plant=plant), RouteConfig(), []
    for seed in seeds:
        route = identify_until_robust(
            simulated_recorder(task, config, seed), perturbed_guess(RodParams()), config, seed
        )
        summary = evaluate(route.controller, task, seeds=tuple(report_seeds), duration_s=duration_s)
        row = _route_row(plant, seed, route.plant_s, route.plant_s, summary) | {"robust": route.robust}
        extra = {"max_relative_std": route.steps[-1]["max_relative_std"], "identified": route.identification.estimates}
        rows.append(row | extra)
    return rows


def _route_row(plant: str, seed: int, plant_s: float, to_balance_s: float, summary: Any) -> dict[str, Any]:
    """A run's row: ``balanced_starts``, ``starts`` and ``balances`` of its controller's fresh-start ``summary``, and
    ``real_s_to_balance`` (``to_balance_s``, infinite when it does not balance them)."""
    fresh = fresh_start_row(summary)
    to_balance_s = to_balance_s if fresh["run_balances"] else math.inf
    row = {"plant": plant, "seed": int(seed), "plant_s": plant_s, "balanced_starts": fresh["balanced_starts"]}
    return row | {"starts": fresh["starts"], "balances": fresh["run_balances"], "real_s_to_balance": to_balance_s}


#: The babbling programs the chapter compares at equal length (:data:`softpend.sysid.babble.PROGRAMS`) -> label.
EXCITATIONS = {"noise": "random torque", "multisine": "designed multisine"}


def excitation_rows(
    plant: str = "prb",
    seeds: Iterable[int] = range(10),
    lengths_s: Sequence[float] = (1.0, 2.0, 5.0),
    report_seeds: Sequence[int] = REPORT_SEEDS,
    duration_s: float = TEST_EPISODE_S,
) -> list[dict[str, Any]]:
    """Per program of :data:`EXCITATIONS`, length and seed: the relative error of each field identified from that
    much of it (``error_<field>``, PRB only) and the swing-up + LQR designed on the estimate on ``report_seeds``."""
    task, truth, config = Task(plant=plant), RodParams(), RouteConfig()
    rows = []
    for program, label in EXCITATIONS.items():
        for length_s in lengths_s:
            for seed in seeds:
                data = simulated_recorder(task, config, int(seed), program=program)(float(length_s))
                result = identify(data, GreyBoxConfig(seed=int(seed)), initial_params=perturbed_guess(truth))
                errors = {
                    f"error_{name}": value / getattr(truth, name) - 1.0
                    for name, value in result.estimates.items()
                    if hasattr(truth, name) and plant == "prb"
                }
                summary = evaluate(
                    design_swingup(result.params), task, seeds=tuple(report_seeds), duration_s=duration_s
                )
                row = {"program": program, "excitation": label}
                rows.append(row | _route_row(plant, seed, float(length_s), float(length_s), summary) | errors)
    return rows


def plot_excitation(rows: list[dict[str, Any]]) -> Any:
    """Per field, the median |relative error| against the seconds of excitation per program, and the seeds that balance."""
    import matplotlib.pyplot as plt

    fields = sorted({k[len("error_") :] for r in rows for k in r if k.startswith("error_")})
    lengths = sorted({r["plant_s"] for r in rows})
    fig, axes = plt.subplots(1, len(fields) + 1, figsize=(2.6 * (len(fields) + 1), 2.8), squeeze=False)
    for i, (program, label) in enumerate(EXCITATIONS.items()):
        mine = [r for r in rows if r["program"] == program]
        for ax, name in zip(axes[0], fields):
            median = [np.median([abs(r[f"error_{name}"]) for r in mine if r["plant_s"] == t]) for t in lengths]
            ax.plot(lengths, median, "o-", color=f"C{i}", label=label)
            ax.set(yscale="log", xlabel="excitation [s]")
            ax.set_title(name.replace("_", " "), fontsize=8)
        balancing = [sum(r["balances"] for r in mine if r["plant_s"] == t) for t in lengths]
        axes[0, -1].plot(lengths, balancing, "o-", color=f"C{i}", label=label)
    if fields:
        axes[0, 0].set_ylabel("median |relative error|")
    axes[0, -1].set_title("seeds whose swing-up + LQR balances", fontsize=8)
    axes[0, -1].set_xlabel("excitation [s]")
    axes[0, -1].legend(fontsize=7)
    fig.tight_layout()
    return fig


def greybox_route_figures(rows: list[dict[str, Any]], prefix: str, within_s: float) -> dict[str, float]:
    """Median and worst plant seconds to balance, seeds balanced, and seeds balanced within ``within_s``."""
    s = np.array([row["real_s_to_balance"] for row in rows], float)
    figures = {"real_s_to_balance": np.median(s), "real_s_to_balance_worst": np.max(s)}
    figures |= {"seeds_balanced": np.sum(np.isfinite(s)), f"seeds_within_{within_s:g}s": np.sum(s <= within_s)}
    return {f"{prefix}_{key}": float(value) for key, value in figures.items()}


def plant_seconds_rows(
    learned: list[dict[str, Any]],
    greybox: list[dict[str, Any]],
    beam: Sequence[dict[str, Any]] = (),
    planner: Optional[Mapping[str, Sequence[dict[str, Any]]]] = None,
) -> list[dict[str, Any]]:
    """One row per (method, seed): the learned methods' :func:`~softpend.study.fresh_starts.seed_rows`, the grey-box
    route's rows (PRB, beam) and the planner's (``{"mpc" | "mpc_blackbox" | "mpc_beam": rows}``)."""
    key_of = {label: key for key, label in METHODS.items()}
    groups: list[tuple[str, Sequence[dict[str, Any]], str, str]]
    groups = [(key_of[r["method"]], [r], "plant_s_to_balance", "final_balanced_starts") for r in learned]
    groups += [
        (key, rows, "real_s_to_balance", "balanced_starts")
        for key, rows in (("greybox", greybox), ("greybox_beam", beam), *(planner or {}).items())
    ]
    fields = ("key", "method", "seed", "plant_s_to_balance", "balanced_starts", "starts")
    return [
        dict(zip(fields, (key, METHODS[key], int(r["seed"]), float(r[seconds]), int(r[balanced]), int(r["starts"]))))
        for key, rows, seconds, balanced in groups
        for r in rows
    ]


def method_summary(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per method: seeds, seeds balanced, median plant seconds with its 95 % bootstrap interval, and the worst."""
    out = []
    for key in [k for k in METHODS if any(r["key"] == k for r in rows)]:
        seconds = np.array([r["plant_s_to_balance"] for r in rows if r["key"] == key], float)
        median = low = high = float(np.median(seconds))
        if seconds.size >= 2 and np.all(np.isfinite(seconds)):
            interval = aggregate_interval(seconds, "median", seed=0)
            low, high = interval.low, interval.high
        counts = {"seeds": int(seconds.size), "seeds_balanced": int(np.sum(np.isfinite(seconds)))}
        figures = {"median_plant_s": median, "low_plant_s": float(low), "high_plant_s": float(high)}
        out.append({"key": key, "method": METHODS[key], **counts, **figures, "worst_plant_s": float(np.max(seconds))})
    return out


def plot_plant_seconds(rows: list[dict[str, Any]]) -> Any:
    """Plant seconds to balance per seed (crosses: never balanced), one line per method, with median and interval."""
    import matplotlib.pyplot as plt

    summary = method_summary(rows)
    fig, ax = plt.subplots(figsize=(8, 0.6 + 0.6 * len(summary)))
    finite = [r["plant_s_to_balance"] for r in rows if math.isfinite(r["plant_s_to_balance"])]
    edge = 2.0 * max(finite) if finite else 1.0
    for y, row in enumerate(summary):
        seconds = np.array([r["plant_s_to_balance"] for r in rows if r["key"] == row["key"]], float)
        jitter = np.linspace(-0.15, 0.15, seconds.size) if seconds.size > 1 else np.zeros(1)
        ok = np.isfinite(seconds)
        ax.scatter(seconds[ok], y + jitter[ok], s=18, color=f"C{y}", zorder=3)
        ax.scatter(np.full((~ok).sum(), edge), y + jitter[~ok], marker="x", color=f"C{y}", zorder=3)
        if math.isfinite(row["median_plant_s"]):
            ax.plot([row["low_plant_s"], row["high_plant_s"]], [y, y], color="k", lw=4, alpha=0.3)
            ax.plot([row["median_plant_s"]] * 2, [y - 0.3, y + 0.3], color="k", lw=2)
    ax.set(xscale="log", xlabel="plant seconds until the method has a controller that balances the fresh starts")
    ax.set_yticks(range(len(summary)), [r["method"] for r in summary])
    ax.invert_yaxis()
    ax.grid(axis="x", alpha=0.3)
    return fig


def planner_config(
    task: Task,
    overrides: Optional[Mapping[str, Any] | Sequence[tuple[str, Any]]] = None,
    hparams: Optional[str | Path] = None,
) -> Any:
    """The ``PlannerConfig`` on ``task``: ``hparams`` (default ``book/hparams/planner.yml``), then ``overrides``;
    trials from the first 16 selection starts."""
    path = hparams if hparams is not None else HPARAMS_DIR / "planner.yml"
    return load_settings(PlannerConfig, path, task, overrides).replace(selection_seeds=SELECTION_SEEDS[:16])


def planner_rows(
    model: str = "residual",
    seeds: Iterable[int] = range(10),
    report_seeds: Sequence[int] = REPORT_SEEDS,
    plant: str = "prb",
    overrides: Optional[Mapping[str, Any]] = None,
    duration_s: float = TEST_EPISODE_S,
) -> list[dict[str, Any]]:
    """One row per seed of the planner (``model``: ``"residual"`` or ``"ensemble"``) on ``plant``, then its controller on
    ``report_seeds`` (``real_s_to_balance``: infinite unless 90 % of them balance)."""
    config = planner_config(Task(plant=plant), overrides).replace(model=model)
    rows = []
    for seed in seeds:
        result = run_planner(config.replace(seed=int(seed)))
        summary = planner_fresh_starts(result, report_seeds, duration_s)
        rows.append(_route_row(plant, seed, result.plant_seconds, result.plant_seconds_to_balance, summary))
    return rows


def planner_fresh_starts(result: Any, seeds: Sequence[int], duration_s: float = TEST_EPISODE_S) -> Any:
    """The final controller of a planner run from the fresh starts ``seeds`` on the run's rod (PRB: batched);
    ``ValueError`` for seeds shared with the run's selection starts."""
    task = result.config.task
    if task.plant == "prb":
        return fresh_start_evaluation(result, tuple(seeds), duration_s)
    if shared := sorted(set(int(s) for s in seeds) & set(result.config.selection_seeds)):
        raise ValueError(f"seeds must be fresh starts, disjoint from selection_seeds; shared: {shared}")
    with torch.no_grad(), one_torch_thread():
        return evaluate(
            result.controller, task, engine="exudyn", name="planner", seeds=tuple(seeds), duration_s=duration_s
        )


def pilco_rows_if_trained(seeds: Iterable[int], runs_root: Path | str) -> Optional[list[dict[str, Any]]]:
    """The book's PILCO runs of ``seeds`` as :func:`~softpend.study.fresh_starts.seed_rows` rows on the report starts,
    or None if any is not trained (nothing is trained here)."""
    seeds, config = [int(s) for s in seeds], load_hparams("pilco", Task())
    if not Path(runs_root).is_dir() or pilco_jobs(config, seeds, runs_root):
        return None
    results = pilco_runs(config, seeds, runs_root, progress=False)
    return seed_rows({}, pilco_fresh_start_rows(results), results)


def paired_ratio_rows(numerator: Mapping[int, float], denominator: Mapping[int, float]) -> list[dict[str, Any]]:
    """Per seed held by both: ``numerator`` over ``denominator`` plant seconds to balance (0 when only the numerator's
    method balances, ``inf`` when it does not)."""
    rows = []
    for seed in sorted(set(numerator) & set(denominator)):
        top, bottom = float(numerator[seed]), float(denominator[seed])
        ratio = math.inf if not math.isfinite(top) else (top / bottom if math.isfinite(bottom) else 0.0)
        rows.append({"seed": int(seed), "numerator_s": top, "denominator_s": bottom, "ratio": ratio})
    return rows


def paired_ratio(numerator: Mapping[int, float], denominator: Mapping[int, float]) -> float:
    """Median over seeds of :func:`paired_ratio_rows` (NaN when no seed is held by both)."""
    ratios = [row["ratio"] for row in paired_ratio_rows(numerator, denominator)]
    return float(np.median(ratios)) if ratios else math.nan
