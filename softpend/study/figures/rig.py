"""Figure 9 helpers: a tracked camera frame with the detection overlaid, and rig-data plots."""

from __future__ import annotations

from typing import Optional

import numpy as np


def draw_tracked_frame(
    ax,
    frame_bgr: np.ndarray,
    detection,
    zoom_px: Optional[float] = 45.0,
    markers_px: Optional[np.ndarray] = None,
    truth_px: Optional[np.ndarray] = None,
):
    """A BGR camera frame on ``ax`` with the tracker's contour and centroid, optional marker centres and true tip;
    ``zoom_px``: an inset magnifies the dot.  Returns the inset axis (or None)."""
    rgb = np.ascontiguousarray(frame_bgr[..., ::-1])
    ax.imshow(rgb)
    ax.set_axis_off()

    def _overlay(a):
        if detection is not None and detection.contour is not None:
            c = detection.contour.reshape(-1, 2)
            a.plot(np.r_[c[:, 0], c[0, 0]], np.r_[c[:, 1], c[0, 1]], "-", color="lime", lw=1.2)
        if detection is not None and not detection.lost:
            a.plot(detection.x_px, detection.y_px, "+", color="red", ms=12, mew=2)
        if truth_px is not None:
            a.plot(truth_px[0], truth_px[1], "x", color="yellow", ms=8, mew=1.5)

    _overlay(ax)
    if markers_px is not None:
        ax.plot(markers_px[:, 0], markers_px[:, 1], "o", mfc="none", mec="white", ms=14, mew=1.5)
    if zoom_px and detection is not None and not detection.lost:
        inset = ax.inset_axes([0.68, 0.62, 0.3, 0.36])
        inset.imshow(rgb)
        _overlay(inset)
        inset.set_xlim(detection.x_px - zoom_px / 2, detection.x_px + zoom_px / 2)
        inset.set_ylim(detection.y_px + zoom_px / 2, detection.y_px - zoom_px / 2)
        inset.set(xticks=[], yticks=[])
        for spine in inset.spines.values():
            spine.set_edgecolor("white")
        return inset
    return None


def draw_filmstrip(
    frames,
    n_frames: int = 8,
    span_s: Optional[float] = None,
    centre_px=None,
    half_width_px: Optional[float] = None,
):
    """A figure of ``n_frames`` of ``frames`` (``(time_s, frame_bgr, detection)``) evenly spaced up to ``span_s``,
    with the tracker's overlay, cropped to ``half_width_px`` around ``centre_px`` if given."""
    import matplotlib.pyplot as plt

    frames = [f for f in frames if span_s is None or f[0] <= span_s]
    if not frames:
        raise ValueError("frames must hold at least one frame (within span_s)")
    times = np.array([f[0] for f in frames])
    wanted = np.linspace(times[0], times[-1], min(n_frames, len(frames)))
    chosen = sorted({int(np.argmin(np.abs(times - t))) for t in wanted})
    aspect = 1.0 if half_width_px is not None else frames[0][1].shape[0] / frames[0][1].shape[1]
    fig, axes = plt.subplots(1, len(chosen), figsize=(1.9 * len(chosen), 1.9 * aspect + 0.35), squeeze=False)
    for ax, index in zip(axes[0], chosen):
        time_s, frame, detection = frames[index]
        draw_tracked_frame(ax, frame, detection, zoom_px=None)
        if half_width_px is not None and centre_px is not None:
            ax.set_xlim(centre_px[0] - half_width_px, centre_px[0] + half_width_px)
            ax.set_ylim(centre_px[1] + half_width_px, centre_px[1] - half_width_px)
        ax.set_title(f"t = {time_s:.2f} s", fontsize=9)
    fig.tight_layout()
    return fig


def plot_twin_run(motor_log, truth_log, task, simulator=None, title: Optional[str] = None):
    """``|theta|`` (true and estimated) and torque of one twin run against time, optionally beside ``simulator``'s."""
    import matplotlib.pyplot as plt

    from softpend.io.samplelog import read_sample_log
    from softpend.study.rig import truth_trajectory

    motor = read_sample_log(motor_log)
    t0_device = float(motor["device_time_s"][0])
    truth = truth_trajectory(truth_log, task, end_time_s=float(motor["device_time_s"][-1]))
    commanded = motor["commanded"] > 0
    first_command_s = float(motor["time_s"][commanded][0]) if commanded.any() else 0.0
    fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    axes[0].plot(truth["time_s"] - t0_device, np.abs(truth["theta_rad"]), color="C0", label="twin: true tip angle")
    estimate = dict(color="C1", ls="--", lw=1.0, label="twin: estimate handed to the controller")
    axes[0].plot(motor["est_time_s"], np.abs(motor["est_theta_rad"]), **estimate)
    axes[1].step(motor["time_s"], motor["command_torque_nm"], where="post", color="C0", label="twin: commanded")
    if simulator is not None:
        sim_t = simulator.time_s + first_command_s
        axes[0].plot(sim_t, np.abs(simulator.theta_rad), color="C2", lw=1.0, label="ideal simulator, same start")
        axes[1].step(sim_t, simulator.torque_nm, where="post", color="C2", lw=1.0, label="ideal simulator")
    axes[0].set_ylabel(r"$|\theta|$ [rad]")
    axes[1].set(ylabel="torque [N m]", xlabel="time since the loop's first state [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    axes[0].set_title(title or "")
    fig.tight_layout()
    return fig
