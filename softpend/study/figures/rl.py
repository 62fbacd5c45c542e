"""Figures 4-6: learning curves, the swing-up time course (and its animation as HTML that reads offline) and the upright
error over time."""

from __future__ import annotations

import math
import re
from typing import Any, Mapping, Optional, Sequence

import matplotlib.pyplot as plt
import numpy as np

from softpend.evaluation import SUCCESS_STD_RAD, EvaluationResult
from softpend.plotting import draw_rod
from softpend.rl.curves import interval_band, moving_average, run_to_asymptote, worst_start_std_rad
from softpend.rl.training_log import TrainingLog

COLORS = {"model-free DQN": "C0", "DQN-MBPO": "C1"}


def plot_learning_curves(logs_by_method: Mapping[str, Sequence[TrainingLog]], threshold_rad: float = SUCCESS_STD_RAD):
    """Figure 4: each seed's smoothed return with the median episode reaching the asymptote, and the worst start's
    upright std (IQM over seeds, 95 % band), against episodes and plant seconds."""
    fig, window = plt.figure(figsize=(11, 7)), 10
    axes = fig.subplots(2, 2, sharey="row")
    for i, (method, logs) in enumerate(logs_by_method.items()):
        color = COLORS.get(method, f"C{i}")
        for col, axis in enumerate(("episode", "plant_s")):
            for k, log in enumerate(logs):
                style = dict(color=color, lw=0.8, alpha=0.6, label=method if k == 0 else None)
                axes[0, col].plot(log.column(axis), moving_average(log.column("return"), window), **style)
            if len(logs) >= 2:
                band = interval_band(logs, "max_upright_std_rad", axis=axis, seed=0, failed_as=SUCCESS_STD_RAD)
                axes[1, col].plot(band["x"], band["value"], color=color, label=method)
                axes[1, col].fill_between(band["x"], band["low"], band["high"], color=color, alpha=0.2, lw=0)
            else:
                worst = worst_start_std_rad(logs[0])
                axes[1, col].plot(logs[0].column(axis, "evaluations"), worst, color=color, label=method)
        asym = float(np.median([run_to_asymptote(log, window=window)[0] for log in logs]))
        if math.isfinite(asym):
            axes[0, 0].axvline(asym, color=color, ls=":", lw=1)
    axes[0, 0].set_ylabel(f"episode return ({window}-episode mean)")
    axes[1, 0].set_ylabel(
        f"evaluation upright std [rad]\n(worst start, {SUCCESS_STD_RAD:g} if one failed; IQM over seeds)"
    )
    for ax, xlabel in zip(axes[1], ("training episodes", "real plant time [s]")):
        ax.axhline(threshold_rad, color="k", ls="--", lw=0.8)
        ax.set(yscale="log", xlabel=xlabel)
    axes[0, 0].legend()
    fig.tight_layout()
    return fig


def plot_swingup(result: EvaluationResult, link_points, n_frames: int = 8, fig: Optional[plt.Figure] = None):
    """Figure 5: tip and hub angle and torque of one episode, and ``n_frames`` rod shapes (``link_points(q)``) up to a
    second after the swing-up."""
    fig = fig or plt.figure(figsize=(11, 8))
    grid = fig.add_gridspec(4, 1, height_ratios=[1, 1, 1, 1.3])
    t = result.time_s
    ax = [fig.add_subplot(grid[i]) for i in range(3)]
    ax[0].plot(t, _break_at_wraps(result.theta_rad), color="C0")
    ax[0].axhspan(-0.2, 0.2, color="C2", alpha=0.15, lw=0)
    ax[0].set_ylabel(r"tip angle $\theta$ [rad]")
    ax[1].plot(t, _break_at_wraps(result.phi_rad), color="C1")
    ax[1].set_ylabel(r"hub angle $\phi$ [rad]")
    ax[2].step(t, result.torque_nm, where="post", color="C3")
    ax[2].set(ylabel="torque [N m]", xlabel="time [s]")
    if math.isfinite(result.swing_up_time_s):
        for a in ax:
            a.axvline(result.swing_up_time_s, color="k", ls=":", lw=1)
    end = min(t[-1], (result.swing_up_time_s + 1.0) if math.isfinite(result.swing_up_time_s) else t[-1])
    times = np.linspace(0.0, end, n_frames)
    strip, spacing = fig.add_subplot(grid[3]), 0.7
    for k, time_s in enumerate(times):
        i = int(np.argmin(np.abs(t - time_s)))
        points = np.asarray(link_points(result.joint_angles_rad[i])) + np.array([k * spacing, 0.0])
        draw_rod(strip, points, color="C0")
        strip.plot(k * spacing, 0, "s", color="k", ms=6)
        strip.text(k * spacing, -0.42, f"{t[i]:.2f} s", ha="center", fontsize=8)
    strip.set(ylim=(-0.48, 0.36), xlim=(-0.4, (n_frames - 1) * spacing + 0.4))
    strip.axis("off")
    fig.tight_layout()
    return fig


def _break_at_wraps(angle_rad: np.ndarray) -> np.ndarray:
    """A copy with NaN where a wrapped angle jumps across +-pi."""
    out = np.array(angle_rad, dtype=float)
    out[1:][np.abs(np.diff(out)) > np.pi] = np.nan
    return out


def animate_swingup(result: EvaluationResult, link_points, length_m: float, every: int = 4):
    """An animation of the rod over an evaluation episode (``every`` plant steps per frame), for the HTML book."""
    from matplotlib import animation

    fig, ax = plt.subplots(figsize=(4, 4))
    ax.set(xlim=(-1.2 * length_m, 1.2 * length_m), ylim=(-1.2 * length_m, 1.2 * length_m), aspect="equal")
    ax.axis("off")
    (line,) = ax.plot([], [], "-o", color="C0", lw=2.5, ms=3)
    text = ax.text(0.02, 0.95, "", transform=ax.transAxes)
    frames = range(0, len(result.time_s), every)

    def update(i):
        points = np.asarray(link_points(result.joint_angles_rad[i]))
        line.set_data(points[:, 0], points[:, 1])
        text.set_text(f"t = {result.time_s[i]:.2f} s")
        return line, text

    anim = animation.FuncAnimation(
        fig, update, frames=frames, interval=1000 * every * float(result.time_s[1] - result.time_s[0]), blit=True
    )
    plt.close(fig)
    return anim


#: The Font Awesome 4 stylesheet that matplotlib's JavaScript player links from a CDN (its button icons).
_CDN_STYLESHEET = re.compile(r'<link rel="stylesheet"\s+href="https://[^"]*font-awesome[^"]*">\s*')


def offline_jshtml(animation: Any, **kwargs: Any) -> str:
    """``animation.to_jshtml(**kwargs)`` without its CDN stylesheet link; ``ValueError`` unless there is one."""
    html = animation.to_jshtml(**kwargs)
    stripped, count = _CDN_STYLESHEET.subn("", html)
    if count != 1:
        raise ValueError(f"expected one CDN stylesheet link in the animation's HTML, found {count}")
    return stripped


def plot_upright_error(
    results_by_method: Mapping[str, Sequence[EvaluationResult]],
    window_s: float = 0.5,
    threshold_rad: float = SUCCESS_STD_RAD,
):
    """Figure 6: each method's upright error ``|theta|`` (``window_s`` moving average): median and 25-75 % band."""
    _, ax = plt.subplots(figsize=(8, 4))
    for i, (method, results) in enumerate(results_by_method.items()):
        n = min(len(r.time_s) for r in results)  # the shortest episode's steps
        t = results[0].time_s[:n]
        window = max(1, int(round(window_s / float(t[1] - t[0]))))
        errors = np.array([moving_average(np.abs(r.theta_rad[:n]), window) for r in results])
        color = COLORS.get(method, f"C{i}")
        ax.plot(t, np.median(errors, axis=0), color=color, label=f"{method} (median of {len(results)})")
        if len(results) > 1:
            low, high = np.percentile(errors, [25, 75], axis=0)
            ax.fill_between(t, low, high, color=color, alpha=0.2, lw=0)
    ax.axhline(threshold_rad, color="k", ls="--", lw=0.8, label=f"{threshold_rad:g} rad")
    ax.set(xlabel="time [s]", ylabel=rf"$|\theta|$, {window_s:g} s moving average [rad]", yscale="log")
    ax.legend()
    return ax
