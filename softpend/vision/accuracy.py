"""Tracker accuracy against the synthetic camera's ground truth (used by the benchmark and Figure 9)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from softpend.vision.camera import CameraEffects, SyntheticCamera
from softpend.vision.tracker import TipTracker


def babbling_trajectory(n_steps: int, seed: int = 0):
    """A babbling trajectory of the default rod: times [s], link points ``(T, n + 1, 2)`` [m], hub angles [rad]."""
    from softpend.plant import RodParams, make_plant
    from softpend.sysid.babble import band_limited_noise

    plant = make_plant("prb", params=RodParams())
    q, qd = plant.hanging_state()
    q[0] = 2.2
    plant.reset(q, qd)
    limit = plant.params.torque_limit_nm
    noise = band_limited_noise(np.random.default_rng(seed), n_steps, 0.7 * limit, 2.0, plant.dt_s)
    points, hub = [], []
    for torque in np.clip(noise, -limit, limit):
        points.append(plant.link_points_m())
        hub.append(plant.joint_state()[0][0])
        plant.step(float(torque))
    return np.arange(n_steps) * plant.dt_s, np.array(points), np.array(hub)


@dataclass
class TrackingErrors:
    """Per-frame tracked minus true pixel position ``error_px`` (F, 2) (NaN when lost)."""

    time_s: np.ndarray
    error_px: np.ndarray
    lost: np.ndarray

    @property
    def rmse_px(self) -> float:
        """Root-mean-square Euclidean error over the tracked frames [px]."""
        return float(np.sqrt(np.nanmean(np.sum(self.error_px**2, axis=1))))


def tracking_errors(
    trajectory, effects: Optional[CameraEffects] = None, n_frames: int = 300, seed: int = 0, keep_frames: bool = False
):
    """:class:`TrackingErrors` (and the frames if ``keep_frames``) of ``n_frames`` frames of ``trajectory``."""
    times, points, hub = trajectory
    if not 1 <= n_frames < len(times):
        raise ValueError(f"n_frames must be in [1, {len(times) - 1}], got {n_frames!r}")
    camera = SyntheticCamera(effects=effects, seed=seed)
    tracker = TipTracker()
    frame_times = times[1 : n_frames + 1]
    errors, lost, frames = [], [], []
    for frame, truth in camera.frames(times, points, frame_times, hub):
        d = tracker.track(frame)
        errors.append([d.x_px - truth[0], d.y_px - truth[1]])
        lost.append(d.lost)
        if keep_frames:
            frames.append(frame)
    result = TrackingErrors(frame_times, np.array(errors), np.array(lost))
    return (result, frames) if keep_frames else result
