"""Time synchronisation of the motor log and the camera CSV, with a known clock offset."""

from __future__ import annotations

import numpy as np
import pytest

from softpend.hardware.closed_loop import LOOP_LOG_COLUMNS
from softpend.hardware.sync import build_rig_dataset, estimate_clock_offset, startup_wiggle_torque, synchronise
from softpend.io.samplelog import SampleLog, read_sample_log
from softpend.plant import RodParams, make_plant
from softpend.vision.track_video import TRACK_COLUMNS

TRUE_OFFSET_S = 0.2345


@pytest.fixture(scope="module")
def trajectory():
    """A simulated babbling run at 1 ms resolution (hub angle, tip position, torque)."""
    params = RodParams()
    plant = make_plant("prb", params=params, dt_s=0.002)
    rng = np.random.default_rng(0)
    wiggle = np.repeat(startup_wiggle_torque(2.0, 0.05, seed=1), 5)
    noise = np.repeat(np.clip(0.03 * rng.standard_normal(600), -0.06, 0.06), 10)
    torque = np.concatenate([wiggle, noise])[:4500]
    q, qd = plant.hanging_state()
    plant.reset(q, qd)
    rows = []
    for k, u in enumerate(torque):
        o = plant.observe()
        rows.append((k * 0.002, plant.joint_state()[0][0], o.ex_m, o.ey_m, u))
        plant.step(u)
    return np.array(rows), params


def _write_logs(tmp_path, trajectory, lost_frames=(), drop_motor=()):
    data, _ = trajectory
    t, phi, ex, ey, u = data.T
    rng = np.random.default_rng(1)
    motor_idx = np.arange(0, len(t), 5)  # 100 Hz on the motor clock (device time = scene time)
    motor_idx = np.array([i for j, i in enumerate(motor_idx) if j not in set(drop_motor)])
    with SampleLog(tmp_path / "motor.csv", LOOP_LOG_COLUMNS) as log:
        for i in motor_idx:
            log.append([t[i] + 100.0, t[i], i, phi[i], 0.0, u[i], u[i], 0])
    cam_t = np.arange(0.05, t[-1] - 0.05, 1 / 90)  # a 90 fps camera on its own clock
    with SampleLog(tmp_path / "camera.csv", TRACK_COLUMNS) as log:
        for k, tc in enumerate(cam_t):
            x = np.interp(tc, t, ex) + 2e-4 * rng.standard_normal()
            y = np.interp(tc, t, ey) + 2e-4 * rng.standard_normal()
            hub = np.interp(tc, t, phi)
            lost = k in set(lost_frames)
            nan = np.nan
            log.append(
                [
                    k,
                    tc + TRUE_OFFSET_S,
                    nan,
                    nan,
                    50.0,
                    nan if lost else x,
                    nan if lost else y,
                    nan if lost else np.arctan2(-x, y),
                    int(lost),
                    (hub + np.pi) % (2 * np.pi) - np.pi,
                    0,
                ]
            )
    return tmp_path / "motor.csv", tmp_path / "camera.csv"


def test_offset_recovered_from_the_wiggle_with_hub_marker(tmp_path, trajectory):
    motor, camera = _write_logs(tmp_path, trajectory)
    m, c = read_sample_log(motor), read_sample_log(camera)
    estimate = estimate_clock_offset(
        m["device_time_s"], m["phi_rad"], c["camera_time_s"], c["hub_angle_rad"], window_s=(0.0, 4.0)
    )
    assert estimate.offset_s == pytest.approx(TRUE_OFFSET_S, abs=0.001)
    assert estimate.peak_correlation > 0.95


def test_tip_angle_alone_gives_a_biased_offset(tmp_path, trajectory):
    """Why the rig has a hub marker: the tip lags the hub, so correlating with it shifts the estimate."""
    motor, camera = _write_logs(tmp_path, trajectory)
    m, c = read_sample_log(motor), read_sample_log(camera)
    estimate = estimate_clock_offset(
        m["device_time_s"], m["phi_rad"], c["camera_time_s"], c["theta_rad"], window_s=(0.0, 4.0)
    )
    assert abs(estimate.offset_s - TRUE_OFFSET_S) > 0.01


def test_synchronise_resamples_reports_gaps_and_writes_a_dataset(tmp_path, trajectory):
    data, params = trajectory
    lost = range(300, 306)  # six camera frames without a dot (about 3.3 s .. 3.4 s)
    motor, camera = _write_logs(tmp_path, trajectory, lost_frames=lost, drop_motor=(700, 701, 702))
    result = synchronise(read_sample_log(motor), read_sample_log(camera), dt_s=0.01, trial_length_s=1.0)
    assert result.offset.offset_s == pytest.approx(TRUE_OFFSET_S, abs=0.001)
    reasons = [g.reason for g in result.gaps]
    assert any("tip lost in 6 frame" in r for r in reasons)
    assert any("motor states missing" in r for r in reasons)
    lost_gap = next(g for g in result.gaps if "tip lost" in g.reason)
    assert lost_gap.start_s < 0.05 + 300 / 90 and lost_gap.end_s > 0.05 + 305 / 90
    # no trial straddles a gap
    for start in result.trial_start_s:
        for gap in result.gaps:
            assert not (start - 0.01 < gap.end_s and gap.start_s < start + 1.0)
    assert result.positions.shape[1:] == (100, 4) and result.torques_nm.shape[1:] == (99,)
    # resampled tip positions agree with the truth at the grid times
    t, phi, ex, ey, u = data.T
    grid = result.trial_start_s[1] + np.arange(100) * 0.01
    np.testing.assert_allclose(result.positions[1, :, 2], np.interp(grid, t, ex), atol=2e-3)
    np.testing.assert_allclose(
        result.positions[1, :, 0], (np.interp(grid, t, phi) + np.pi) % (2 * np.pi) - np.pi, atol=1e-6
    )
    # torque is the zero-order hold of the applied torque
    np.testing.assert_allclose(result.torques_nm[1], np.interp(grid[:-1], t, u), atol=0.031)
    # velocities are backward differences of the positions
    np.testing.assert_allclose(result.velocities[1, 1:, 2], np.diff(result.positions[1, :, 2]) / 0.01, atol=1e-9)

    from softpend.sysid import load_dataset

    dataset, _ = build_rig_dataset(motor, camera, tmp_path / "rig.npz", params=params, trial_length_s=1.0)
    loaded = load_dataset(tmp_path / "rig.npz")
    assert loaded.metadata["source"] == "rig" and loaded.n_trials == dataset.n_trials >= 5
    assert loaded.metadata["protocol"]["clock_offset_s"] == pytest.approx(TRUE_OFFSET_S, abs=0.001)


def test_synchronise_rejects_bad_input(tmp_path, trajectory):
    motor, camera = _write_logs(tmp_path, trajectory)
    m, c = read_sample_log(motor), read_sample_log(camera)
    with pytest.raises(ValueError, match="trial_length_s"):
        synchronise(m, c, trial_length_s=0.001)
    with pytest.raises(ValueError, match="motor log is missing"):
        synchronise(c, c)
    with pytest.raises(ValueError, match="less than one trial"):
        synchronise(m, c, trial_length_s=60.0)
