"""The rig's figures: its dimensioned drawing, to scale, from a :class:`~softpend.hardware.rig_design.RigDesign`;
a tracked camera frame with the detection overlaid (Figure 9), a film strip of them and a twin run's plots."""

from __future__ import annotations

import math
from typing import Optional

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle, Polygon, Rectangle

from softpend.hardware.rig_design import MARKER_RADIUS_M, RigDesign

_TPU = "#e3a33b"
_MOUNT = "#8c8c8c"
_STEEL = "#5b6770"
_BLUE = "#1f4fd1"
_GREEN = "#2ca02c"
_MAGENTA = "#c218c8"


def _dimension(ax, p0, p1, text: str, offset, fontsize: float = 8.0) -> None:
    """A dimension line from ``p0`` to ``p1`` shifted by ``offset`` [m], with extension lines and ``text``."""
    p0, p1, off = np.asarray(p0, float), np.asarray(p1, float), np.asarray(offset, float)
    a, b = p0 + off, p1 + off
    for p, q in ((p0, a), (p1, b)):
        ax.plot([p[0], q[0]], [p[1], q[1]], color="0.45", lw=0.5)
    ax.annotate("", xy=b, xytext=a, arrowprops=dict(arrowstyle="<->", lw=0.7, color="0.2", shrinkA=0, shrinkB=0))
    mid = (a + b) / 2
    box = dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.9)
    ax.text(mid[0], mid[1], text, fontsize=fontsize, ha="center", va="center", gid="dimension", bbox=box)


def _arrow(ax, text: str, xy, xytext, fontsize: float = 7, **kw) -> None:
    """A label with an arrow to ``xy``."""
    ax.annotate(text, xy=xy, xytext=xytext, fontsize=fontsize, arrowprops=dict(arrowstyle="->", lw=0.6), **kw)


def _front(ax, d: RigDesign) -> None:
    """Front view: the rod hanging in the camera's plane (hub axis at the origin, y up), metres."""
    p, hub, add = d.params, d.hub, ax.add_patch
    L, D = p.length_m, d.beam_thickness_m
    fov_w, fov_h = d.field_of_view_m
    cx, cy = d.camera_model.centre_px
    x0, y0 = -cx * d.pixel_size_m, -(d.camera.height_px - cy) * d.pixel_size_m
    add(Rectangle((x0, y0), fov_w, fov_h, fill=False, ls="--", lw=0.8, ec="0.3"))
    field = (
        f"camera field {fov_w * 1e3:.0f} x {fov_h * 1e3:.0f} mm, "
        f"{d.camera.width_px} x {d.camera.height_px} px: pixel {d.pixel_size_m * 1e3:.2f} mm"
    )
    ax.text(x0 + fov_w / 2, y0 + fov_h - 0.01, field, fontsize=8, va="top", ha="center", gid="dimension")
    swing = f"swing circle of the dot, radius {d.swing_radius_m * 1e3:.0f} mm"
    add(Circle((0, 0), d.swing_radius_m, fill=False, ls=":", lw=0.8, ec=_BLUE, label=swing))
    keep_out = f"keep clear while powered, radius {d.keep_out_radius_m * 1e3:.0f} mm"
    add(Circle((0, 0), d.keep_out_radius_m, fill=False, ls="-.", lw=0.8, ec="#d62728", label=keep_out))
    # beam hanging along -y, from the pocket to the tip
    add(Rectangle((-D / 2, -L), D, d.beam_length_m, fc=_TPU, ec="k", lw=0.6))
    # mount boss, square bore, marker flag
    add(Circle((0, 0), hub.clamp_radius_m, fc=_MOUNT, ec="k", lw=0.6))
    s = hub.shaft_side_m / 2
    add(Polygon([(-s, -s), (s, -s), (s, s), (-s, s)], closed=True, fc="white", ec="k", lw=0.5))
    flag_w = 2 * (hub.hub_marker_dot_radius_m + 0.002)
    add(Rectangle((-flag_w / 2, -d.flag_length_m), flag_w, d.flag_length_m, fc=_MOUNT, ec="k", lw=0.6, alpha=0.85))
    add(Circle((0, -hub.hub_marker_radius_m), hub.hub_marker_dot_radius_m, fc=_MAGENTA, ec="k", lw=0.4))
    # tip disc and dot
    add(Circle((0, -L), d.dot_radius_m, fc=_BLUE, ec="k", lw=0.6))
    for i, (x, y) in enumerate(d.markers_m):
        add(Circle((x, y), MARKER_RADIUS_M, fc=_GREEN, ec="k", lw=0.5))
        label = f"M{i + 1} ({x * 1e3:.0f}, {y * 1e3:.0f})"
        ax.text(x, y + 1.8 * MARKER_RADIUS_M, label, fontsize=7, ha="center", gid="dimension")
    _dimension(ax, (0, 0), (0, -L), f"L = {L * 1e3:.0f} mm", (-0.09, 0.0))
    _arrow(ax, f"D = {D * 1e3:.2f} mm (in plane)", (D / 2, -0.6 * L), (0.06, -0.6 * L), 8, gid="dimension")
    _arrow(ax, f"hub marker at {hub.hub_marker_radius_m * 1e3:.0f} mm", (0, -hub.hub_marker_radius_m), (0.06, -0.09))
    tip = f"tip mass {p.tip_mass_kg * 1e3:.3g} g, dot diameter {2e3 * d.dot_radius_m:.0f} mm"
    _arrow(ax, tip, (0, -L), (0.05, -L - 0.01))
    ax.legend(loc="upper center", fontsize=7, framealpha=0.9, bbox_to_anchor=(0.5, -0.11), ncol=2)
    ax.set(xlim=(x0 - 0.03, x0 + fov_w + 0.03), ylim=(y0 - 0.03, y0 + fov_h + 0.03))
    ax.set(aspect="equal", title="front view (camera plane), rod hanging", xlabel="x [m]", ylabel="y [m]")


def _hub_detail(ax, d: RigDesign) -> None:
    """The hub mount enlarged, front view: boss, square bore, beam pocket and marker flag (millimetres)."""
    hub, add = d.hub, ax.add_patch
    mm = 1e3
    r, s, D = hub.clamp_radius_m * mm, hub.shaft_side_m * mm / 2, d.beam_thickness_m * mm
    flag, pocket, marker = d.flag_length_m * mm, hub.pocket_start_m * mm, hub.hub_marker_radius_m * mm
    add(Rectangle((-D / 2, -flag - 8), D, flag + 8 - pocket, fc=_TPU, ec="k", lw=0.6))
    add(Circle((0, 0), r, fc=_MOUNT, ec="k", lw=0.6, alpha=0.9))
    add(Rectangle((-D / 2, -r), D, r - pocket, fc=_TPU, ec="k", lw=0.5, ls="--"))
    add(Polygon([(-s, -s), (s, -s), (s, s), (-s, s)], closed=True, fc="white", ec="k", lw=0.6))
    flag_w = 2 * (hub.hub_marker_dot_radius_m + 0.002) * mm
    add(Rectangle((-flag_w / 2, -flag), flag_w, flag - r, fc=_MOUNT, ec="k", lw=0.6, alpha=0.6))
    add(Circle((0, -marker), hub.hub_marker_dot_radius_m * mm, fc=_MAGENTA, ec="k", lw=0.4))
    _dimension(ax, (0, 0), (r, 0), f"R {r:.0f}", (0, r + 4), fontsize=7)
    _arrow(ax, f"bore {2 * s:.3f} square", (s, s), (r + 3, r + 1), gid="dimension")
    _dimension(ax, (0, -pocket), (0, -r), f"pocket {r - pocket:.0f}", (-r - 6, 0), fontsize=7)
    _dimension(ax, (0, 0), (0, -flag), f"flag {flag:.0f}", (r + 8, 0), fontsize=7)
    _dimension(ax, (0, 0), (0, -marker), f"{marker:.0f}", (-flag_w / 2 - 5, 0), fontsize=7)
    note = f"flag {hub.flag_gap_m * mm:.0f} mm in front of the beam,\nmount {hub.mount_thickness_m * mm:.0f} mm thick (PLA/PETG)"
    ax.text(0, -flag - 12, note, fontsize=7, ha="center", va="top")
    ax.set(aspect="equal", xlim=(-r - 14, r + 20), ylim=(-flag - 24, r + 10), title="hub mount [mm]")


def _side(ax, d: RigDesign) -> None:
    """Side view: the motor, the mount, the beam's width and the camera at its distance (z towards the camera)."""
    p, hub, add = d.params, d.hub, ax.add_patch
    L, W, t = p.length_m, d.beam_width_m, hub.mount_thickness_m
    # motor body behind the mount (not to scale in depth), the mount boss and the flag in front of the beam
    add(Rectangle((-0.06, -0.035), 0.05, 0.07, fc="0.25", ec="k", lw=0.6))
    ax.text(-0.035, 0.045, "V5 motor", fontsize=7, ha="center")
    add(Rectangle((-0.01, -hub.clamp_radius_m), t, 2 * hub.clamp_radius_m, fc=_MOUNT, ec="k", lw=0.6))
    z_beam = -0.01 + (t - W) / 2
    add(Rectangle((z_beam, -L), W, L - hub.pocket_start_m, fc=_TPU, ec="k", lw=0.6))
    z_flag = z_beam + W + hub.flag_gap_m
    add(Rectangle((z_flag, -d.flag_length_m), 0.003, d.flag_length_m, fc=_MOUNT, ec="k", lw=0.6))
    disc = d.tip_disc_thickness_m
    add(Rectangle((z_beam + W, -L - d.dot_radius_m), disc, 2 * d.dot_radius_m, fc=_STEEL, ec="k", lw=0.6))
    _arrow(ax, f"W = {W * 1e3:.0f} mm (out of plane)", (z_beam + W, -0.75 * L), (0.05, -0.75 * L), 8, gid="dimension")
    _arrow(ax, f"tip disc {disc * 1e3:.1f} mm", (z_beam + W + disc, -L), (0.05, -L + 0.03), gid="dimension")
    # the camera on the optical axis through the hub axis, looking back at the plane
    zc = z_beam + W + d.camera_distance_m
    half = math.radians(d.camera.horizontal_fov_deg) / 2
    reach = d.camera_distance_m * math.tan(half)
    cone = [(zc, 0), (zc - d.camera_distance_m, reach), (zc - d.camera_distance_m, -reach)]
    add(Polygon(cone, closed=True, fc=_BLUE, alpha=0.06, ec=_BLUE, lw=0.6, ls="--"))
    add(Rectangle((zc, -0.02), 0.04, 0.04, fc="0.2", ec="k"))
    ax.text(zc + 0.02, 0.03, "camera", fontsize=7, ha="center")
    distance = f"{d.camera_distance_m * 1e3:.0f} mm to the rod plane"
    _dimension(ax, (z_beam + W, 0.0), (zc, 0.0), distance, (0.0, reach + 0.05))
    fov = f"horizontal field of view {d.camera.horizontal_fov_deg:g} deg"
    ax.text(zc - 0.02, -reach + 0.02, fov, fontsize=7, ha="right")
    ax.set(aspect="equal", xlim=(-0.08, zc + 0.08), ylim=(-max(L, reach) - 0.06, reach + 0.1))
    ax.set(title="side view: the camera square on to the plane", xlabel="z, towards the camera [m]", ylabel="y [m]")


def draw_rig_design(design: RigDesign, figsize=(15.0, 5.8)):
    """The front view, the hub mount enlarged and the side view of ``design`` in one figure."""
    fig, (front, detail, side) = plt.subplots(1, 3, figsize=figsize, gridspec_kw={"width_ratios": [1.15, 0.45, 1.0]})
    _front(front, design)
    _hub_detail(detail, design)
    _side(side, design)
    fig.suptitle(
        f"rig for a {design.params.length_m * 1e3:.0f} mm rod, EI = {design.params.bending_stiffness_nm2:.3g} "
        f"N m², printed at E = {design.print_modulus_pa / 1e6:.3g} MPa",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def draw_tracked_frame(
    ax,
    frame_bgr: np.ndarray,
    detection,
    zoom_px: Optional[float] = 45.0,
    markers_px: Optional[np.ndarray] = None,
    truth_px: Optional[np.ndarray] = None,
):
    """A BGR camera frame on ``ax`` with the tracker's contour and centroid, optional marker centres and true tip;
    ``zoom_px``: an inset magnifies the dot."""
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


def draw_filmstrip(
    frames, n_frames: int = 8, span_s: Optional[float] = None, centre_px=None, half_width_px: Optional[float] = None
):
    """A figure of ``n_frames`` of ``frames`` (``(time_s, frame_bgr, detection)``) evenly spaced up to ``span_s``,
    with the tracker's overlay, cropped to ``half_width_px`` around ``centre_px`` if given."""
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
    from softpend.io.samplelog import read_sample_log
    from softpend.study.rig_runs import truth_trajectory

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
