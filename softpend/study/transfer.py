"""Sim-to-"real" transfer: controllers designed on the PRB plant, evaluated on the PRB plant and the beam, nominal and
with stiffness, mass or damping perturbed."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from tqdm.auto import tqdm

from softpend.evaluation import TEST_EPISODE_S, evaluate_controller
from softpend.plant import RodParams
from softpend.task import Task

#: Shortest episode :func:`transfer_table` runs [s] (a swing-up needs a 1 s hold to count).
MIN_DURATION_S = 2.0


def perturbations(params: RodParams, fraction: float = 0.2) -> dict[str, RodParams]:
    """The nominal parameters and six one-at-a-time perturbations by ``+-fraction`` (stiffness, mass, damping)."""
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"fraction must be in [0, 1), got {fraction!r}")
    out = {"nominal": params}
    for sign, label in ((+1, "+"), (-1, "-")):
        s, pct = 1.0 + sign * fraction, f"{label}{100 * fraction:g}%"
        out[f"stiffness {pct}"] = params.replace(stiffness_scale=params.stiffness_scale * s)
        out[f"mass {pct}"] = params.replace(mass_kg=params.mass_kg * s, tip_mass_kg=params.tip_mass_kg * s)
        damping = {n: getattr(params, n) * s for n in ("joint_damping_nms_per_rad", "hub_friction_nms_per_rad")}
        out[f"damping {pct}"] = params.replace(**damping)
    return out


@dataclass
class TransferCase:
    """A controller factory and the start, episode length and start noise it is evaluated with."""

    name: str
    make_controller: Callable[[], Any]
    start: str = "hanging"
    duration_s: float = TEST_EPISODE_S
    start_noise_rad: float = 0.05


def default_transfer_cases(params: RodParams = RodParams()) -> list[TransferCase]:
    """The observation-only LQR from near upright and energy swing-up + LQR from hanging."""
    from softpend.control.lqr import LQRController
    from softpend.control.swingup import EnergySwingUpController

    lqr = lambda: LQRController.from_params(params, state="observation")  # noqa: E731
    swing = lambda: EnergySwingUpController(params, lqr_state="observation", energy_source="observation")  # noqa: E731
    return [
        TransferCase("LQR (observations), balance", lqr, start="upright", duration_s=3.0, start_noise_rad=0.2),
        TransferCase("energy swing-up + LQR (observations)", swing, start="hanging", duration_s=10.0),
    ]


def rl_transfer_cases(
    runs_root: str | Path,
    algos: Sequence[str] = ("dqn", "mbpo"),
    seeds: Sequence[int] = (0, 1, 2),
    which: str = "best",
    params: RodParams = RodParams(),
    duration_s: float = TEST_EPISODE_S,
) -> list[TransferCase]:
    """The agents ``which`` of the RL runs under ``runs_root`` as swing-up cases (trained with the links and torque
    limit of ``params``)."""
    from softpend.rl.dqn import load_agent
    from softpend.rl.training_env import policy_controller
    from softpend.study.rl_runs import METHOD_NAMES, run_folder

    if unknown := [algo for algo in algos if algo not in METHOD_NAMES]:
        raise ValueError(f"algos must be among {sorted(METHOD_NAMES)}, got {unknown[0]!r}")
    cases = []
    for algo, seed in ((algo, seed) for algo in algos for seed in seeds):
        model, config = load_agent(run_folder(runs_root, algo, int(seed)), which)
        rod = config.task.rod
        if (trained := (rod.n_links, rod.torque_limit_nm)) != (used := (params.n_links, params.torque_limit_nm)):
            raise ValueError(f"{algo} seed {seed}: (n_links, torque_limit_nm) {trained} in training, {used} here")
        controller = functools.partial(policy_controller, model, config)
        cases.append(TransferCase(f"{METHOD_NAMES[algo]} (seed {seed})", controller, duration_s=duration_s))
    return cases


def transfer_matrix(
    rows: Sequence[dict[str, Any]], plant: str, metric: str = "success_rate"
) -> tuple[list[str], list[str], np.ndarray]:
    """One metric of :func:`transfer_table` rows on one plant as ``(controllers, perturbations, matrix)``."""
    if not (sel := [r for r in rows if r["plant"] == plant]):
        raise ValueError(f"no rows for plant {plant!r}")
    controllers = list(dict.fromkeys(r["controller"] for r in sel))
    labels = list(dict.fromkeys(r["perturbation"] for r in sel))
    values = np.full((len(controllers), len(labels)), np.nan)
    for r in sel:
        values[controllers.index(r["controller"]), labels.index(r["perturbation"])] = float(r[metric])
    return controllers, labels, values


def transfer_table(
    cases: Sequence[TransferCase],
    params: RodParams = RodParams(),
    plants: Sequence[str] = ("prb", "beam"),
    fraction: float = 0.2,
    seeds: Sequence[int] = (0, 1, 2),
    duration_scale: float = 1.0,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Every case on every plant and perturbation: an :meth:`EvaluationSummary.row` with ``plant``, ``perturbation``
    and ``diverged``; ``duration_scale`` shortens every episode, down to :data:`MIN_DURATION_S`."""
    if duration_scale <= 0:
        raise ValueError(f"duration_scale must be positive, got {duration_scale!r}")
    variants = perturbations(params, fraction)
    jobs = [(case, plant, label) for case in cases for plant in plants for label in variants]
    controllers = {case.name: case.make_controller() for case in cases}
    rows = []
    for case, plant, label in tqdm(jobs, desc="transfer", disable=not progress):
        task = Task(plant=plant, rod=variants[label], start=case.start, start_noise_rad=case.start_noise_rad)
        duration_s = max(case.duration_s * duration_scale, MIN_DURATION_S)
        summary = evaluate_controller(controllers[case.name], task, name=case.name, seeds=seeds, duration_s=duration_s)
        diverged = sum(r.diverged is not None for r in summary.results)
        rows.append(summary.row() | {"plant": plant, "perturbation": label, "diverged": diverged})
    return rows
