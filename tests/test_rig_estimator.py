"""The rig's state estimator on data with known truth: a simulated plant run, a quantised 100 Hz encoder and
a camera whose frames arrive 25 ms after capture with 1 mm noise (all from fixed seeds, no wall clock)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from softpend.hardware.estimator import DeviceClock, EstimatorConfig, RigStateEstimator
from softpend.plant import wrap_angle_rad
from softpend.sysid.babble import band_limited_noise
from softpend.task import Task

COUNTS_PER_REV = 4096
CAMERA_FPS = 60.0
CAMERA_DELAY_S = 0.025
TIP_NOISE_M = 0.001


@dataclass
class Run:
    task: Task
    time_s: np.ndarray
    q: np.ndarray
    q_dot: np.ndarray
    theta: np.ndarray
    theta_dot: np.ndarray
    torque: np.ndarray
    frames: list  # (capture_s, delivered_s, x_m, y_m)


def _encoder(phi_rad: float) -> float:
    step = 2 * math.pi / COUNTS_PER_REV
    return math.pi + math.floor((phi_rad - math.pi) / step + 0.5) * step


def simulate(task: Task, true_task: Task, n_steps: int = 400, seed: int = 0) -> Run:
    plant = true_task.make_plant()
    rng = np.random.default_rng(seed)
    q, qd = plant.hanging_state()
    q[0] += 0.05
    plant.reset(q, qd)
    limit = task.torque_limit_nm
    torque = np.clip(band_limited_noise(rng, n_steps, 0.8 * limit, 2.0, task.dt_s), -limit, limit)
    qs, qds, theta, theta_dot = [], [], [], []
    for k in range(n_steps):
        a, b = plant.joint_state()
        observation = plant.observe()
        qs.append(a), qds.append(b), theta.append(observation.theta_rad), theta_dot.append(observation.theta_dot_rad_s)
        plant.step(float(torque[k]))
    time_s = np.arange(n_steps) * task.dt_s
    qs = np.array(qs)
    frames = []
    for capture in np.arange(0.02, time_s[-1] - 0.05, 1.0 / CAMERA_FPS):
        i = int(capture / task.dt_s)
        w = capture / task.dt_s - i
        tip = plant.link_points_m((1 - w) * qs[i] + w * qs[i + 1])[-1]
        frames.append((capture, capture + CAMERA_DELAY_S, *(tip + rng.normal(0.0, TIP_NOISE_M, 2))))
    return Run(task, time_s, qs, np.array(qds), np.array(theta), np.array(theta_dot), torque, frames)


def run_estimator(
    run: Run, compensate: bool = True, config: EstimatorConfig | None = None, blind_from_s: float = math.inf
):
    """Feed the run as the loop does (frames when they are delivered); returns per-step errors
    ``(theta, theta_dot, max |q|)`` from 0.5 s on, and the estimator."""
    estimator = RigStateEstimator(run.task, config or EstimatorConfig(lead_steps=0))
    estimator.reset(0.0, _encoder(run.q[0, 0]), run.q_dot[0, 0], run.torque[0])
    frames = iter(run.frames)
    frame = next(frames)
    errors = []
    for k in range(1, len(run.time_s)):
        t = run.time_s[k]
        estimator.update_encoder(t, _encoder(run.q[k, 0]), run.q_dot[k, 0], run.torque[k])
        while frame is not None and frame[1] <= t + 1e-9:
            capture, _, x, y = frame
            if capture < blind_from_s:
                estimator.update_tip(capture if compensate else t, x, y)
            frame = next(frames, None)
        estimate = estimator.estimate()
        errors.append(
            (
                wrap_angle_rad(estimate.observation.theta_rad - run.theta[k]),
                estimate.observation.theta_dot_rad_s - run.theta_dot[k],
                np.max(np.abs(estimate.q - run.q[k])),
            )
        )
    return np.array(errors)[49:], estimator


@pytest.fixture(scope="module")
def nominal() -> Run:
    return simulate(Task(), Task())


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def test_estimate_tracks_the_true_state_and_delay_compensation_pays(nominal):
    errors, estimator = run_estimator(nominal)
    assert _rms(errors[:, 0]) < 0.006  # tip angle [rad]; one frame alone is good to ~0.003 rad
    assert _rms(errors[:, 1]) < 0.08  # tip angle rate [rad/s] (the swing reaches ~5 rad/s)
    assert np.max(errors[:, 2]) < 0.02  # every joint coordinate [rad]
    assert estimator.stats()["tips_refused"] == 0
    late, _ = run_estimator(nominal, compensate=False)  # the same frames taken as if they were current
    assert _rms(late[:, 0]) > 5 * _rms(errors[:, 0])
    assert _rms(late[:, 1]) > 5 * _rms(errors[:, 1])


def test_estimate_survives_a_rod_that_differs_from_the_model():
    heavier_softer = Task().replace(
        mass_kg=1.15 * 0.058, youngs_modulus_pa=0.85 * 50e6, hub_friction_nms_per_rad=2.6e-3
    )
    errors, estimator = run_estimator(simulate(Task(), heavier_softer, seed=1))
    assert _rms(errors[:, 0]) < 0.04 and _rms(errors[:, 1]) < 1.5
    assert estimator.stats()["tips_refused"] <= 2


def test_lost_frames_are_bridged_then_the_estimate_is_declared_blind(nominal):
    config = EstimatorConfig(lead_steps=0, max_blind_s=0.3)
    errors, estimator = run_estimator(nominal, config=config, blind_from_s=3.0)
    after = np.arange(len(errors)) + 50  # step index of each error row
    bridged = (after * 0.01 > 3.0) & (after * 0.01 < 3.2)
    assert np.max(np.abs(errors[bridged, 0])) < 0.05  # 0.2 s on the model and the encoder alone
    assert estimator.is_blind and estimator.blind_s > 0.3
    assert not run_estimator(nominal, config=config)[1].is_blind


def test_outliers_are_refused_and_lead_predicts_ahead(nominal):
    estimator = RigStateEstimator(Task(), EstimatorConfig(lead_steps=1))
    estimator.reset(0.0, _encoder(nominal.q[0, 0]), nominal.q_dot[0, 0], nominal.torque[0])
    frames = [f for f in nominal.frames if f[1] <= 0.6]
    for k in range(1, 61):
        estimator.update_encoder(nominal.time_s[k], _encoder(nominal.q[k, 0]), nominal.q_dot[k, 0], nominal.torque[k])
        for capture, delivered, x, y in frames:
            if nominal.time_s[k - 1] < delivered <= nominal.time_s[k] + 1e-9:
                assert estimator.update_tip(capture, x, y)
    accepted = estimator.counts["tips_accepted"]
    capture, _, x, y = frames[-1]
    assert not estimator.update_tip(capture, x + 0.05, y)  # 5 cm off: a reflection, not the dot
    assert not estimator.update_tip(-1.0, x, y)  # older than the history
    assert not estimator.update_tip(capture, math.nan, y)
    assert estimator.stats() == {
        "tips_accepted": float(accepted),
        "tips_refused": 1.0,
        "tips_too_old": 1.0,
        "tips_deferred": 0.0,
        "encoder_gaps": 0.0,
    }
    ahead = estimator.estimate()
    assert ahead.time_s == pytest.approx(nominal.time_s[60] + 0.01)
    estimator.config = EstimatorConfig(lead_steps=0)
    now = estimator.estimate()
    assert abs(ahead.q[0] - nominal.q[61, 0]) < 0.2 * abs(now.q[0] - nominal.q[61, 0])


def test_estimator_needs_a_reset_and_checks_its_config():
    estimator = RigStateEstimator(Task())
    with pytest.raises(ValueError, match="reset"):
        estimator.update_encoder(0.01, math.pi, 0.0, 0.0)
    for field, value in (("tip_std_m", 0.0), ("max_blind_s", -1.0), ("lead_steps", -1), ("counts_per_rev", 2)):
        with pytest.raises(ValueError, match=field):
            EstimatorConfig(**{field: value})


def test_device_clock_takes_the_smallest_delay_less_the_link_latency():
    clock = DeviceClock(one_way_latency_s=0.002, window=4)
    for device, delay in ((1.0, 0.004), (1.01, 0.0025), (1.02, 0.009)):
        clock.observe(100.0 + device + delay, device)
    assert clock.offset_s == pytest.approx(100.0005)
    assert clock.to_device(101.5005) == pytest.approx(1.5)
    for device in (1.03, 1.04, 1.05):  # the smallest delay leaves the window
        clock.observe(100.0 + device + 0.003, device)
    assert clock.offset_s == pytest.approx(100.001)


def test_a_frame_from_after_the_newest_encoder_sample_waits_for_it(nominal):
    estimator = RigStateEstimator(Task(), EstimatorConfig(lead_steps=0))
    estimator.reset(0.0, _encoder(nominal.q[0, 0]), nominal.q_dot[0, 0], nominal.torque[0])
    capture, _, x, y = nominal.frames[3]  # captured at 0.07 s
    assert (
        estimator.update_tip(capture, x, y)
        and estimator.counts["tips_deferred"] == 1
        and estimator.counts["tips_accepted"] == 0
    )
    for k in range(1, 10):
        estimator.update_encoder(nominal.time_s[k], _encoder(nominal.q[k, 0]), nominal.q_dot[k, 0], nominal.torque[k])
    assert estimator.counts["tips_accepted"] == 1
    assert not estimator.update_tip(10.0, x, y)  # seconds ahead: a clock error
