"""Merge the motor log and the camera CSV into a system-identification dataset: the clock offset from the start-up
wiggle's hub rates, both streams on the motor's grid, gaps marked, the valid stretches cut into trials."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from softpend.io.samplelog import LogContents, read_sample_log
from softpend.plant import RodParams, wrap_angle_rad

#: Position columns of a rig dataset.
RIG_POSITION_NAMES: tuple[str, ...] = ("phi_rad", "theta_rad", "ex_m", "ey_m")


def startup_wiggle_torque(duration_s: float, torque_nm: float, seed: int, dt_s: float = 0.01) -> np.ndarray:
    """The start-up wiggle: +-``torque_nm`` held for random times of 0.08 s to 0.3 s, one torque per control step."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s / dt_s))
    out = np.empty(n)
    k, sign = 0, 1.0
    while k < n:
        hold = max(1, int(round(rng.uniform(0.08, 0.3) / dt_s)))
        out[k : k + hold] = sign * torque_nm
        k += hold
        sign = -sign
    return out


@dataclass(frozen=True)
class ClockOffset:
    """Estimated ``camera clock - motor clock`` [s] and the normalised correlation at the peak."""

    offset_s: float
    peak_correlation: float


@dataclass(frozen=True)
class Gap:
    """A stretch of motor-clock time without usable data."""

    start_s: float
    end_s: float
    reason: str


@dataclass
class SyncResult:
    positions: np.ndarray
    velocities: np.ndarray
    torques_nm: np.ndarray
    dt_s: float
    offset: ClockOffset
    gaps: list[Gap] = field(default_factory=list)
    grid_valid_fraction: float = 1.0
    trial_start_s: list[float] = field(default_factory=list)


def estimate_clock_offset(
    motor_time_s: np.ndarray,
    motor_phi_rad: np.ndarray,
    camera_time_s: np.ndarray,
    camera_theta_rad: np.ndarray,
    window_s: tuple[float, float],
) -> ClockOffset:
    """``camera clock - motor clock`` (within 1 s) from cross-correlating the rates of the hub angle and the camera's
    angle (NaN where lost) over the motor-clock ``window_s``, on a 1 ms grid refined by a parabola at the peak."""
    tm, tc = np.asarray(motor_time_s, float), np.asarray(camera_time_s, float)
    if tm.size < 10 or tc.size < 10:
        raise ValueError("need at least 10 motor and 10 camera samples")
    resolution_s, max_offset_s = 0.001, 1.0
    phi = np.unwrap(np.asarray(motor_phi_rad, float))
    theta_raw = np.asarray(camera_theta_rad, float)
    good = np.isfinite(theta_raw)
    if good.sum() < 2:
        raise ValueError("camera log has fewer than 2 tracked frames")
    theta = np.interp(tc, tc[good], np.unwrap(theta_raw[good]))
    start, end = float(window_s[0]), float(window_s[1])
    if end - start < 20 * resolution_s:
        raise ValueError(f"window_s {window_s} is too short")
    grid = np.arange(start, end, resolution_s)
    motor_rate = np.gradient(np.interp(grid, tm, phi), resolution_s)
    motor_rate -= motor_rate.mean()
    n_lag = int(round(max_offset_s / resolution_s))
    offsets = np.arange(-n_lag, n_lag + 1) * resolution_s
    extended = np.arange(-n_lag, grid.size + n_lag) * resolution_s + start
    inside = (extended >= tc[0]) & (extended <= tc[-1])
    cam_rate = np.where(inside, np.gradient(np.interp(extended, tc, theta), resolution_s), 0.0)
    from scipy.signal import correlate

    m = grid.size
    dot = correlate(cam_rate, motor_rate, mode="valid", method="fft")  # length 2 n_lag + 1
    sums = [np.concatenate([[0.0], np.cumsum(values)]) for values in (cam_rate, cam_rate**2, inside)]
    seg_sum, seg_sq, seg_n = (total[m:] - total[:-m] for total in sums)  # over the window at each lag
    seg_var = np.maximum(seg_sq - seg_sum**2 / m, 0.0)
    denominator = np.sqrt(seg_var * float(motor_rate @ motor_rate))
    scores = np.where(
        (seg_n >= 0.9 * m) & (denominator > 0), dot / np.where(denominator > 0, denominator, 1.0), -np.inf
    )
    best = int(np.argmax(scores))
    if not np.isfinite(scores[best]):
        raise ValueError("the camera and motor records do not overlap for any offset within 1 s")
    refined = offsets[best]
    if 0 < best < len(offsets) - 1 and np.all(np.isfinite(scores[best - 1 : best + 2])):
        y0, y1, y2 = scores[best - 1 : best + 2]
        curvature = y0 - 2 * y1 + y2
        if curvature < 0:
            refined += 0.5 * (y0 - y2) / curvature * resolution_s
    return ClockOffset(float(refined), float(scores[best]))


def _gaps_from_times(t: np.ndarray, reason: str) -> list[Gap]:
    max_step_s = max(1.6 * float(np.median(np.diff(t))), 0.03)
    return [Gap(float(t[i]), float(t[i + 1]), reason) for i in np.nonzero(np.diff(t) > max_step_s)[0]]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    padded = np.concatenate([[False], mask, [False]]).astype(int)
    edges = np.diff(padded)
    return list(zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]))


def synchronise(motor: LogContents, camera: LogContents, dt_s: float = 0.01, trial_length_s: float = 5.0) -> SyncResult:
    """Merge a motor log (``LOOP_LOG_COLUMNS``) and a camera CSV (``TRACK_COLUMNS``) into gap-free trials of
    ``trial_length_s`` every ``dt_s``, the clock offset estimated from the first 4 s (the wiggle)."""
    for name, log, needed in (
        ("motor", motor, ("device_time_s", "phi_rad", "applied_torque_nm")),
        ("camera", camera, ("camera_time_s", "x_m", "y_m", "lost")),
    ):
        missing = [c for c in needed if c not in log.columns]
        if missing:
            raise ValueError(f"{name} log is missing columns {missing}")
    if not (dt_s > 0 and trial_length_s >= 2 * dt_s):
        raise ValueError(f"dt_s must be positive and trial_length_s >= 2 dt_s, got {dt_s}, {trial_length_s}")
    tm, phi, torque = motor["device_time_s"], np.unwrap(motor["phi_rad"]), motor["applied_torque_nm"]
    tc_cam, lost = camera["camera_time_s"], camera["lost"] > 0.5
    x_m, y_m = camera["x_m"], camera["y_m"]
    if "hub_angle_rad" in camera.columns and np.isfinite(camera["hub_angle_rad"]).mean() > 0.5:
        reference = np.where(camera["hub_lost"] > 0.5, np.nan, camera["hub_angle_rad"])
    else:  # no hub marker: the tip angle (biased by the rod's lag)
        reference = np.where(lost, np.nan, np.arctan2(-x_m, y_m))
    offset = estimate_clock_offset(tm, phi, tc_cam, reference, (tm[0], tm[0] + 4.0))
    tc = tc_cam - offset.offset_s  # camera frames on the motor clock

    gaps = _gaps_from_times(tm, "motor states missing") + _gaps_from_times(tc, "camera frames missing")
    gaps += [
        Gap(float(tc[max(a - 1, 0)]), float(tc[min(b, len(tc) - 1)]), f"tip lost in {b - a} frame(s)")
        for a, b in _runs(lost)
    ]
    gaps.sort(key=lambda g: g.start_s)

    good = ~lost
    start, end = max(tm[0], tc[good][0]), min(tm[-1], tc[good][-1])
    if end - start < trial_length_s:
        raise ValueError(f"the motor and camera records overlap for {max(end - start, 0):.3f} s, less than one trial")
    first = tm[0] + math.ceil((start - tm[0]) / dt_s - 1e-9) * dt_s
    grid = np.arange(first, end + 1e-12, dt_s)
    valid = np.ones(grid.size, dtype=bool)
    for gap in gaps:
        valid &= ~((grid > gap.start_s) & (grid < gap.end_s))

    ex_g, ey_g = (np.interp(grid, tc[good], values[good]) for values in (x_m, y_m))
    torque_g = torque[np.clip(np.searchsorted(tm, grid + 1e-9, side="right") - 1, 0, len(tm) - 1)]  # held

    from softpend.sysid.variables import backward_difference

    n = int(round(trial_length_s / dt_s))
    phi_g, theta_g = np.interp(grid, tm, phi), np.arctan2(-ex_g, ey_g)
    raw = np.column_stack([wrap_angle_rad(phi_g), wrap_angle_rad(theta_g), ex_g, ey_g])
    angle_mask = np.array([True, True, False, False])
    ks = [k for a, b in _runs(valid) for k in range(a, b - n, n + 1)]  # trials of n + 1 samples, the first for rates
    if not ks:
        raise ValueError(f"no gap-free stretch of {trial_length_s} s in the synchronised record")
    positions = np.stack([raw[k + 1 : k + n + 1] for k in ks])
    velocities = np.stack([backward_difference(raw[k : k + n + 1], dt_s, angle_mask) for k in ks])
    torques = np.stack([torque_g[k + 1 : k + n] for k in ks])
    starts = [float(grid[k + 1]) for k in ks]
    return SyncResult(positions, velocities, torques, dt_s, offset, gaps, float(valid.mean()), starts)


def build_rig_dataset(
    motor_log: str | Path,
    camera_csv: str | Path,
    out_path: str | Path,
    params: Optional[RodParams] = None,
    dt_s: float = 0.01,
    trial_length_s: float = 5.0,
    notes: str = "",
):
    """Synchronise a motor log and a camera CSV into a ``source="rig"`` dataset; ``(dataset, sync_result)``."""
    from softpend.sysid.dataset import save_dataset

    result = synchronise(read_sample_log(motor_log), read_sample_log(camera_csv), dt_s, trial_length_s)
    protocol = {
        "kind": "rig babbling, motor log + tracked camera (softpend.hardware.sync)",
        "clock_offset_s": result.offset.offset_s,
        "offset_peak_correlation": result.offset.peak_correlation,
        "gaps": [[g.start_s, g.end_s, g.reason] for g in result.gaps],
        "grid_valid_fraction": result.grid_valid_fraction,
        "trial_start_s": result.trial_start_s,
        "motor_log": str(motor_log),
        "camera_csv": str(camera_csv),
    }
    meta: dict[str, Any] = dict(dt_s=dt_s, position_names=RIG_POSITION_NAMES, source="rig", plant_params=params)
    meta.update(protocol=protocol, notes=notes)
    return save_dataset(out_path, result.positions, result.velocities, result.torques_nm, **meta), result
