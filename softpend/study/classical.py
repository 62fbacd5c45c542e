"""Figure 7: every classical controller through the shared evaluation, and the |theta| plot.

:func:`classical_comparison` builds the controllers (LQR from the true model on joint states and on
observations, LQR from the learned model, PID tuned on the learned model, energy swing-up plus LQR), runs
the near-upright ones from the report's kind of start (the straight rod released at rest a little off
upright) with and without the torque limit, the swing-up from hanging, and returns the trajectories and a
table of :meth:`softpend.evaluation.EvaluationSummary.row` rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np

from softpend.evaluation import EvaluationSummary, evaluate_controller
from softpend.task import Task
from softpend.control.learned import learned_model_simulator, lqr_from_learned_model
from softpend.control.lqr import LQRController
from softpend.control.pid import PIDController, PIDGains, plant_simulator, tune_pid
from softpend.control.swingup import EnergySwingUpController

__all__ = ["ClassicalComparison", "classical_comparison", "plot_abs_theta", "table_markdown", "train_learned_model"]

TABLE_COLUMNS = ("controller", "start", "torque_limit_nm", "seeds", "success_rate", "swing_up_time_s",
                 "upright_std_rad", "peak_torque_nm", "energy_used_j")


@dataclass
class ClassicalComparison:
    """Runs behind Figure 7.

    Attributes
    ----------
    near_upright : dict
        ``label -> EvaluationSummary`` of the near-upright runs (one result per tilt).
    swing_up : EvaluationSummary
        Energy swing-up plus LQR from hanging.
    rows : list of dict
        One table row per run (controller, start, torque limit, shared-evaluation medians).
    pid_gains : PIDGains
        The PID gains used, and ``pid_tuned_on`` says on which model they were tuned.
    notes : list of str
        Designs that failed (e.g. a learned model whose linearisation is not stabilisable).
    """

    near_upright: dict[str, EvaluationSummary]
    swing_up: EvaluationSummary
    rows: list[dict[str, Any]]
    pid_gains: PIDGains
    pid_tuned_on: str
    notes: list[str] = field(default_factory=list)


def train_learned_model(task: Optional[Task] = None, n_trials: int = 60, max_epochs: int = 300, seed: int = 0,
                        progress: bool = False):
    """Babble (report protocol, ``n_trials`` x 5 s) on the task's plant and fit the default learned model (3 x 16)."""
    from softpend.sysid import BabbleProtocol, babble
    from softpend.sysid.training import fit_dynamics_model

    task = task if task is not None else Task()
    dataset = babble(BabbleProtocol(n_trials=n_trials), params=task.rod, seed=seed, plant=task.plant, progress=progress)
    return fit_dynamics_model(dataset, progress=progress, max_epochs=max_epochs, seed=seed).model


def _run(controller, task: Task, tilts, duration_s, limit) -> EvaluationSummary:
    results = []
    run_task = task.replace(start="upright", torque_limit_nm=limit)
    for tilt in tilts:
        results += evaluate_controller(controller, run_task, seeds=(0,), duration_s=duration_s,
                                       initial_state=task.tilt_state(tilt)).results
    return EvaluationSummary(name=getattr(controller, "name", "controller"), results=results)


def classical_comparison(
    task: Optional[Task] = None,
    learned_model: Any = None,
    tilts_rad: Sequence[float] = (0.2, 0.4),
    duration_s: float = 5.0,
    unlimited_torque_nm: float = 1.0,
    swingup_seeds: Sequence[int] = (0, 1, 2),
    swingup_duration_s: float = 10.0,
    pid_tuning_evaluations: int = 60,
    pid_gains: Optional[PIDGains] = None,
    progress: bool = False,
) -> ClassicalComparison:
    """Evaluate every classical controller (see the module docstring).

    Parameters
    ----------
    task : Task, optional
        The plant and rod (its ``torque_limit_nm`` is "the torque limit"); on plants other than the PRB
        chain the controllers that read the chain's joint state (joint-state LQR, joint-energy swing-up) are
        replaced by their observation-only versions, and ``notes`` says so.
    learned_model : DynamicsModel, optional
        Learned model for the learned-model LQR and the PID tuning; without it the PID is tuned on the
        true plant and the learned-model LQR is left out (both said in ``notes``).
    tilts_rad : sequence of float
        Initial tilts of the near-upright runs [rad].
    duration_s : float
        Length of the near-upright runs [s].
    unlimited_torque_nm : float
        Torque limit of the "without torque limit" runs [N m] (about 9x the torque that holds the rod
        horizontal, so it never binds in these runs).
    swingup_seeds, swingup_duration_s
        Start seeds and length of the swing-up runs from hanging.
    pid_tuning_evaluations : int
        Cost evaluations of the PID tuning.
    pid_gains : PIDGains, optional
        Skip the tuning and use these gains.
    """
    task = task if task is not None else Task()
    params, plant = task.rod, task.plant
    limit = params.torque_limit_nm
    notes: list[str] = []
    near: dict[str, EvaluationSummary] = {}
    rows: list[dict[str, Any]] = []

    def add(label: str, controller, torque_limit: float) -> None:
        summary = _run(controller, task, tilts_rad, duration_s, torque_limit)
        summary.name = label
        near[label] = summary
        for tilt, result in zip(tilts_rad, summary.results):
            row = EvaluationSummary(label, [result]).row()
            row.update(start=f"tilt {tilt:g} rad", torque_limit_nm=torque_limit)
            rows.append(row)

    joint_state = plant == "prb"
    if not joint_state:
        notes.append(f"plant {plant!r}: joint-state LQR and joint-energy swing-up replaced by observation-only versions")
    lqr_state = "joint" if joint_state else "observation"
    add("LQR (true model)", LQRController.from_params(params, state=lqr_state), limit)
    add("LQR (true model), no limit",
        LQRController.from_params(params, state=lqr_state, torque_limit_nm=unlimited_torque_nm), unlimited_torque_nm)
    if joint_state:
        add("LQR (observations)", LQRController.from_params(params, state="observation"), limit)
    if learned_model is not None:
        try:
            add("LQR (learned model)", lqr_from_learned_model(learned_model, params), limit)
        except ValueError as exc:
            notes.append(f"LQR on the learned model: design failed ({exc})")
    if pid_gains is None:
        simulator = (learned_model_simulator(learned_model, params) if learned_model is not None
                     else plant_simulator(task))
        tuned_on = "learned model" if learned_model is not None else "true plant"
        if learned_model is None:
            notes.append("no learned model given: PID tuned on the true plant")
        pid_gains = tune_pid(simulator, torque_limit_nm=limit, max_evaluations=pid_tuning_evaluations,
                             progress=progress).gains
    else:
        tuned_on = "given"
    add("PID", PIDController(pid_gains, torque_limit_nm=limit), limit)
    add("PID, no limit", PIDController(pid_gains, torque_limit_nm=unlimited_torque_nm), unlimited_torque_nm)
    swing_controller = EnergySwingUpController(params) if joint_state else EnergySwingUpController.for_observations(params)
    swing = evaluate_controller(swing_controller, task.replace(start="hanging"), name="energy swing-up + LQR",
                                seeds=swingup_seeds, duration_s=swingup_duration_s)
    row = swing.row()
    row.update(start="hanging", torque_limit_nm=limit)
    rows.append(row)
    return ClassicalComparison(near, swing, rows, pid_gains, tuned_on, notes)


def plot_abs_theta(comparison: ClassicalComparison, tilt_index: int = 0, ax=None):
    """|theta| against time for the near-upright runs from one tilt (log scale), as the report's Figure 7."""
    import matplotlib.pyplot as plt

    ax = ax if ax is not None else plt.gca()
    for label, summary in comparison.near_upright.items():
        result = summary.results[tilt_index]
        style = "--" if "no limit" in label else "-"
        ax.semilogy(result.time_s, np.maximum(np.abs(result.theta_rad), 1e-6), style, label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(r"$|\theta|$ [rad]")
    ax.set_ylim(1e-6, 3.5)
    ax.legend(fontsize="small")
    return ax


def table_markdown(rows: Sequence[dict[str, Any]], columns: Sequence[str] = TABLE_COLUMNS) -> str:
    """A Markdown table of comparison rows (numbers to 4 significant digits)."""
    def cell(value: Any) -> str:
        return f"{value:.4g}" if isinstance(value, float) else str(value)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(row.get(c, "")) for c in columns) + " |" for row in rows]
    return "\n".join(lines)
