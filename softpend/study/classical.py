"""Figure 7: every classical controller from fresh starts (near upright and hanging, with and without the torque
limit), and the |theta| plot."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np

from softpend.control.learned import learned_model_simulator, lqr_from_learned_model
from softpend.control.lqr import LQRController
from softpend.control.pid import PIDController, PIDGains, plant_simulator, tune_pid
from softpend.control.swingup import EnergySwingUpController
from softpend.evaluation import TEST_EPISODE_S, EvaluationSummary, evaluate_controller
from softpend.study.presets import REPORT_SEEDS
from softpend.sysid import BabbleProtocol, babble
from softpend.sysid.training import fit_dynamics_model
from softpend.task import Task

#: Torque limit of the runs "without the limit" [N m].
UNLIMITED_TORQUE_NM = 1.0
#: The columns of the table of :attr:`ClassicalComparison.rows` (``markdown_table(rows, TABLE_COLUMNS, 4)``).
TABLE_COLUMNS = tuple(
    "controller start torque_limit_nm seeds success_rate success_low success_high swing_up_time_s upright_std_rad "
    "peak_torque_nm energy_used_j".split()
)


@dataclass
class ClassicalComparison:
    """Runs behind Figure 7: ``label -> [summary per tilt]`` near upright, one table row per run, the PID gains by
    where they were tuned, and notes on designs left out."""

    near_upright: dict[str, list[EvaluationSummary]]
    rows: list[dict[str, Any]]
    pid_gains: dict[str, PIDGains]
    notes: list[str] = field(default_factory=list)

    def row(self, controller: str, start: str) -> dict[str, Any]:
        """The table row of one run (``start``: ``"tilt 0.2 rad"`` or ``"hanging"``)."""
        if found := [r for r in self.rows if r["controller"] == controller and r["start"] == start]:
            return found[0]
        raise KeyError(f"no run of {controller!r} from {start!r}")


def train_learned_model(task: Task = Task(), n_trials: int = 60, max_epochs: int = 300, seed: int = 0):
    """Babble ``n_trials`` x 5 s on the task's plant and fit the default learned model."""
    dataset = babble(BabbleProtocol(n_trials=n_trials), params=task.rod, seed=seed, plant=task.plant, progress=False)
    return fit_dynamics_model(dataset, progress=False, max_epochs=max_epochs, seed=seed).model


def near_upright_starts(task: Task, tilt_rad: float, starts: Sequence[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per seed, the straight rod at rest tilted by ``tilt_rad`` plus a seeded offset within ``task.start_noise_rad``."""
    offsets = [float(np.random.default_rng(int(seed)).uniform(-1.0, 1.0)) * task.start_noise_rad for seed in starts]
    return [task.tilt_state(float(tilt_rad) + offset) for offset in offsets]


def run_from_tilt(
    controller, task: Task, tilt_rad: float, starts: Sequence[int], duration_s: float, limit: float, name: str
) -> EvaluationSummary:
    """``controller`` from :func:`near_upright_starts` with the torque limit ``limit``."""
    run_task = task.replace(start="upright", torque_limit_nm=limit)
    results = []
    for seed, state in zip(starts, near_upright_starts(task, tilt_rad, starts)):
        one = evaluate_controller(controller, run_task, seeds=(int(seed),), duration_s=duration_s, initial_state=state)
        results += one.results
    return EvaluationSummary(name=name, results=results)


def classical_comparison(
    task: Task = Task(),
    learned_model: Any = None,
    tilts_rad: Sequence[float] = (0.2, 0.4),
    duration_s: float = 5.0,
    starts: Sequence[int] = REPORT_SEEDS,
    swingup_duration_s: float = TEST_EPISODE_S,
    pid_tuning_evaluations: int = 60,
    pid_gains: Optional[PIDGains] = None,
) -> ClassicalComparison:
    """Every classical controller from the fresh ``starts`` (off the PRB plant: observation-only designs; without
    ``learned_model``: no learned-model LQR and PID; ``pid_gains`` skips the PID tunings); the LQR on the true model
    and the PIDs also without the torque limit (:data:`UNLIMITED_TORQUE_NM`)."""
    starts = [int(seed) for seed in starts]
    if not starts or len(tilts_rad) == 0:
        raise ValueError("starts and tilts_rad must not be empty")
    params, plant, limit = task.rod, task.plant, task.rod.torque_limit_nm
    joint_state = plant == "prb"
    lqr_state = "joint" if joint_state else "observation"
    notes: list[str] = []
    if not joint_state:
        notes.append(f"plant {plant!r}: joint-state LQR and joint-energy swing-up replaced by observation-only ones")
    near: dict[str, list[EvaluationSummary]] = {}
    rows: list[dict[str, Any]] = []

    def add(label: str, make: Callable[[float], Any], unlimited: bool = False) -> None:
        for name, torque_limit in ((label, limit), (f"{label}, no limit", UNLIMITED_TORQUE_NM))[: 1 + unlimited]:
            controller = make(torque_limit)
            near[name] = [run_from_tilt(controller, task, t, starts, duration_s, torque_limit, name) for t in tilts_rad]
            rows.extend(
                {**s.row(), "start": f"tilt {t:g} rad", "torque_limit_nm": torque_limit}
                for s, t in zip(near[name], tilts_rad)
            )

    add("LQR (true model)", lambda lim: LQRController.from_params(params, state=lqr_state, torque_limit_nm=lim), True)
    if joint_state:
        add("LQR (observations)", lambda lim: LQRController.from_params(params, state="observation"))
    if learned_model is None:
        notes.append("no learned model given: the learned-model LQR and the PID tuned on it are left out")
    else:
        try:
            add("LQR (learned model)", lambda lim: lqr_from_learned_model(learned_model, params))
        except ValueError as exc:
            notes.append(f"LQR on the learned model: design failed ({exc})")
    if pid_gains is not None:
        gains = {"given": pid_gains}
    else:
        simulators = {"true plant": plant_simulator(task)}
        if learned_model is not None:
            simulators["learned model"] = learned_model_simulator(learned_model, params)
        gains = {
            tuned_on: tune_pid(simulator, torque_limit_nm=limit, max_evaluations=pid_tuning_evaluations).gains
            for tuned_on, simulator in simulators.items()
        }
    for tuned_on, tuned in gains.items():
        add(f"PID (tuned on {tuned_on})", lambda lim: PIDController(tuned, torque_limit_nm=lim), True)
    swing = (EnergySwingUpController if joint_state else EnergySwingUpController.for_observations)(params)
    hanging, lqr = task.replace(start="hanging"), LQRController.from_params(params, state=lqr_state)
    for label, controller in (("LQR (true model)", lqr), ("energy swing-up + LQR", swing)):
        summary = evaluate_controller(controller, hanging, name=label, seeds=starts, duration_s=swingup_duration_s)
        rows.append({**summary.row(), "start": "hanging", "torque_limit_nm": limit})
    return ClassicalComparison(near, rows, gains, notes)


def pid_gain_sensitivity(
    task: Task,
    gains: PIDGains,
    scales: Sequence[float] = (0.5, 0.8, 1.0, 1.25, 2.0),
    tilt_rad: float = 0.2,
    starts: Sequence[int] = REPORT_SEEDS,
    duration_s: float = 5.0,
) -> list[dict[str, Any]]:
    """The PID with its gains scaled by each of ``scales`` from the fresh starts of one tilt, one row per scale."""
    if len(scales) == 0 or any(not float(scale) > 0 for scale in scales):
        raise ValueError(f"scales must be positive numbers, got {list(scales)!r}")
    limit, rows = task.torque_limit_nm, []
    for scale in map(float, scales):
        pid = PIDController(PIDGains(*(scale * gains.as_array())), torque_limit_nm=limit)
        summary = run_from_tilt(pid, task, tilt_rad, list(starts), duration_s, limit, f"PID x {scale:g}")
        rows.append({**summary.row(), "gain_scale": scale, "start": f"tilt {tilt_rad:g} rad", "torque_limit_nm": limit})
    return rows


def plot_abs_theta(comparison: ClassicalComparison, tilt_index: int = 0, ax=None):
    """|theta| against time of the near-upright runs from one tilt (log scale): median and 10-90 % band."""
    import matplotlib.pyplot as plt

    ax = ax if ax is not None else plt.gca()
    for index, (label, summaries) in enumerate(comparison.near_upright.items()):
        results = summaries[tilt_index].results
        length = min(len(r.time_s) for r in results)
        time_s = results[0].time_s[:length]
        abs_theta = np.maximum(np.abs(np.stack([r.theta_rad[:length] for r in results])), 1e-6)
        low, median, high = np.percentile(abs_theta, [10, 50, 90], axis=0)
        style, colour = "--" if "no limit" in label else "-", f"C{index % 10}"
        ax.semilogy(time_s, median, style, color=colour, label=f"{label} ({len(results)} starts)")
        ax.fill_between(time_s, low, high, color=colour, alpha=0.15, linewidth=0)
    ax.set(xlabel="time [s]", ylabel=r"$|\theta|$ [rad]", ylim=(1e-6, 3.5))
    ax.legend(fontsize="small")
    return ax
