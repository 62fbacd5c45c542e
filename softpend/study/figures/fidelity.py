"""Model-fidelity figures (thin wrappers over matplotlib): model rollouts against the data and rollout errors against
the horizon (Figure 3), and the beam-reference chapter's."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Optional, Sequence

import matplotlib.ticker
import numpy as np

from softpend.fidelity.validation import FreeVibration

if TYPE_CHECKING:  # annotations only: importing these modules brings in their progress bars and torch
    from softpend.fidelity.prb_vs_beam import ConvergenceRow
    from softpend.sysid.metrics import RolloutErrors


def plot_free_vibration(ax_time, ax_spectrum, run: FreeVibration) -> None:
    """Tip signal of a free-vibration run and its spectrum, with the fitted and theoretical frequencies."""
    ax_time.plot(run.time_s, run.tip_x_m * 1e3, lw=0.8)
    ax_time.set_xlabel("time [s]")
    ax_time.set(ylabel="tip $e_x$ [mm]", title=f"{run.plant}, resolution {run.resolution}: free vibration")
    x = (run.tip_x_m - run.tip_x_m.mean()) * np.hanning(len(run.tip_x_m))
    n_fft = 8 * len(x)
    spectrum = np.abs(np.fft.rfft(x, n_fft))
    freq = np.fft.rfftfreq(n_fft, run.time_s[1] - run.time_s[0])
    keep = freq < 2.5 * run.theory_hz.max()
    ax_spectrum.semilogy(freq[keep], spectrum[keep] / spectrum[keep].max(), lw=0.8, label="spectrum of $e_x$")
    for k, (f, f_th) in enumerate(zip(run.frequencies_hz, run.theory_hz)):
        ax_spectrum.axvline(f, color="C1", ls="-", lw=1, label="fitted" if k == 0 else None)
        ax_spectrum.axvline(f_th, color="k", ls=":", lw=1, label="Euler-Bernoulli" if k == 0 else None)
    ax_spectrum.set(xlabel="frequency [Hz]", ylabel="normalised magnitude")
    ax_spectrum.legend(fontsize=8)


def plot_convergence(axes: Sequence[Any], rows: Sequence[ConvergenceRow], recommended: int | None = None) -> None:
    """Errors against resolution (frequencies, sag, tip trajectory), one panel each, beam and PRB together."""
    panels = [
        ("f1_error_pct", "first frequency error [%]"),
        ("f2_error_pct", "second frequency error [%]"),
        ("sag_small_error_pct", "small-deflection sag error [%]"),
        ("sag_large_vs_beam_pct", "large-deflection sag vs beam [%]"),
        ("tip_rms_over_l", "tip trajectory RMS vs beam [L]"),
    ]
    for ax, (key, label) in zip(axes, panels):
        for plant, marker in (("beam", "s"), ("prb", "o")):
            sel = [r for r in rows if r.plant == plant and math.isfinite(getattr(r, key))]
            if not sel:
                continue
            n = [r.resolution for r in sel]
            v = [max(abs(getattr(r, key)), 1e-4) for r in sel]
            ax.loglog(n, v, marker=marker, label="beam (elements)" if plant == "beam" else "PRB (links)")
        if key.endswith("pct"):
            ax.axhline(2.0, color="k", ls=":", lw=1, label="2 %")
        if recommended is not None:
            ax.axvline(recommended, color="C2", ls="--", lw=1, label=f"recommended n = {recommended}")
        ax.set_xticks(sorted({r.resolution for r in rows}))
        ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set(xlabel="n (links or elements)", ylabel=label)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)


def plot_transfer_matrix(
    ax, rows: Sequence[dict[str, Any]], plant: str, metric: str = "success_rate", vmax: float | None = None
) -> Any:
    """Heat map of one transfer metric (controllers x perturbations) on one plant; the image, for a colour bar."""
    from softpend.study.transfer import transfer_matrix

    controllers, labels, values = transfer_matrix(rows, plant, metric)
    shown = np.where(np.isfinite(values), values, np.nan)
    vmax = vmax if vmax is not None else np.nanmax(shown[np.isfinite(shown)], initial=1.0)
    cmap = "RdYlGn" if metric == "success_rate" else "RdYlGn_r"
    image = ax.imshow(shown, cmap=cmap, vmin=0.0, vmax=vmax, aspect="auto")
    for (i, j), v in np.ndenumerate(values):
        text = "inf" if math.isinf(v) else ("-" if math.isnan(v) else f"{v:.2g}")
        ax.text(j, i, text, ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(labels)), labels, rotation=40, ha="right", fontsize=8)
    ax.set_yticks(range(len(controllers)), controllers, fontsize=8)
    ax.set_title(f"{metric} on the {plant} plant", fontsize=9)
    return image


def markdown_table(rows: Sequence[dict[str, Any]], columns: Sequence[str], digits: int = 3) -> str:
    """A Markdown table of the given columns (floats to ``digits`` significant digits)."""

    def fmt(value: Any) -> str:
        if isinstance(value, float):
            return "inf" if math.isinf(value) else ("nan" if math.isnan(value) else f"{value:.{digits}g}")
        return str(value)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(row.get(c)) for c in columns) + " |" for row in rows]
    return "\n".join(lines)


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
