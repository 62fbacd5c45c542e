"""Figure 3: model rollouts against the data and rollout errors against the horizon."""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from softpend.sysid.metrics import RolloutErrors

_LABELS = {
    "phi_rad": r"base angle $\phi$ [rad]",
    "theta_rad": r"tip angle $\theta$ [rad]",
    "ex_m": r"tip $e_x$ [m]",
    "ey_m": r"tip $e_y$ [m]",
}


def plot_rollout(curves: dict[str, np.ndarray], title: str = ""):
    """Four panels of :func:`softpend.sysid.rollout_trial` ``curves``: data (solid) and model rollout (dashed); axes."""
    import matplotlib.pyplot as plt

    axes = np.ravel(plt.subplots(2, 2, figsize=(9, 5.5), sharex=True, constrained_layout=True)[1])
    for ax, (name, label) in zip(axes, _LABELS.items()):
        ax.plot(curves["time_s"], curves[name], color="k", lw=1.5, label="simulator")
        ax.plot(curves["time_s"], curves[f"{name}_model"], color="tab:orange", lw=1.5, ls="--", label="model rollout")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes[-2:]:
        ax.set_xlabel("time in trial [s]")
    axes[0].legend(loc="best", fontsize=8)
    if title:
        axes[0].figure.suptitle(title)
    return axes


def plot_rollout_errors(errors: dict[str, RolloutErrors], length_m: Optional[float] = None):
    """Tip and base-angle RMSE against the horizon per model (label -> ``RolloutErrors``), the "hold" yardstick."""
    import matplotlib.pyplot as plt

    axes = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)[1]
    first = next(iter(errors.values()))
    # a diverged rollout leaves the physical range; clip there (tip errors above 2 L, angles above pi)
    tip_top = 2 * length_m if length_m is not None else 1.0
    panels = (("tip_rmse_m", tip_top, "tip-position RMSE [m]"), ("phi_rmse_rad", np.pi, "base-angle RMSE [rad]"))
    for ax, (name, top, ylabel) in zip(axes, panels):
        for label, err in errors.items():
            ax.semilogy(err.horizon_s[1:], getattr(err, name)[1:], lw=1.8, label=label)
        hold = getattr(first, f"hold_{name}")[1:]
        ax.semilogy(first.horizon_s[1:], hold, color="grey", ls=":", label="hold (no model)")
        if length_m is not None and name == "tip_rmse_m":
            ax.axhline(0.05 * length_m, color="tab:red", lw=0.8, ls="--", label="5% of rod length")
        ax.set_ylim(top=top)
        ax.set(xlabel="open-loop horizon [s]", ylabel=ylabel)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    return axes


def plot_rollout_overlay(axes: Sequence, curves: dict[str, np.ndarray], label: str, color: str = "tab:blue"):
    """Add a second model's rollout (dotted) to the panels of :func:`plot_rollout`."""
    for ax, name in zip(axes, _LABELS):
        ax.plot(curves["time_s"], curves[f"{name}_model"], color=color, lw=1.5, ls=":", label=label)
    axes[0].legend(loc="best", fontsize=8)
    return axes


def plot_lyapunov_errors(
    curves: dict[str, np.ndarray], horizon_s: np.ndarray, lyapunov_rate_per_s: float, length_m: float
):
    """RMS tip error of each model against the horizon in Lyapunov times, with the 5 % of ``L`` line."""
    import matplotlib.pyplot as plt

    ax = plt.subplots(figsize=(7, 3.8), constrained_layout=True)[1]
    x = np.asarray(horizon_s) * lyapunov_rate_per_s
    for label, curve in curves.items():
        ax.semilogy(x[1:], np.asarray(curve)[1:], lw=1.8, label=label)
    ax.axhline(0.05 * length_m, color="tab:red", lw=0.8, ls="--", label="5% of rod length")
    ax.set_ylim(top=2 * length_m)
    ax.set(xlabel=r"open-loop horizon [Lyapunov times $1/\lambda$]", ylabel="tip-position RMSE [m]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return ax
