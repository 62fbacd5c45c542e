"""End to end on the digital twin (simulated time): babbling over the emulated serial link, video, tracking, sync,
training."""

from __future__ import annotations

import numpy as np
import pytest

from softpend.hardware.twin import compare_with_simulator_model, run_twin_session, truth_link_points
from softpend.io.samplelog import read_sample_log
from softpend.task import Task


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return run_twin_session(
        tmp_path_factory.mktemp("twin"),
        duration_s=7.0,
        seed=3,
        trial_length_s=2.0,
        clock_offset_s=0.311,
        progress=False,
    )


def test_twin_session_produces_a_synchronised_rig_dataset(session):
    from softpend.sysid import load_dataset

    assert session.loop.samples == 701 and session.loop.dropped_states == 0  # 100 Hz for 7 s, simulated time
    assert (
        abs(session.sync.offset.offset_s - session.true_clock_offset_s) < 0.005
    )  # clock offset recovered from the wiggle (hub marker)
    dataset = load_dataset(session.dataset_path)
    assert dataset.metadata["source"] == "rig" and dataset.n_trials >= 2 and dataset.n_samples == 200
    camera = read_sample_log(session.camera_csv)
    assert camera["lost"].sum() == 0 and len(camera) > 600
    # the synchronised tip positions agree with the emulator's ground truth at the same motor-clock times
    times, points, _ = truth_link_points(session.truth_log, dataset.params)
    start = session.sync.trial_start_s[0]
    grid = start + np.arange(dataset.n_samples) * dataset.dt_s
    truth_x = np.interp(grid, times, points[:, -1, 0])
    truth_y = np.interp(grid, times, points[:, -1, 1])
    err = np.hypot(dataset.column("ex_m")[0] - truth_x, dataset.column("ey_m")[0] - truth_y)
    assert np.sqrt(np.mean(err**2)) < 0.004  # metres: tracking + calibration + sync together
    # torques in the dataset are the ones the device applied (within the limit, not all zero)
    assert 0 < np.abs(dataset.torques_nm).max() <= dataset.params.torque_limit_nm + 1e-7


def test_models_train_on_twin_and_simulator_data(session):
    result = compare_with_simulator_model(session.dataset, seed=0, n_test_trials=2, max_epochs=3, history=1)
    for key in ("tip_rmse_m_twin", "tip_rmse_m_sim", "ratio"):
        assert np.isfinite(result[key]) and result[key] > 0


def test_truth_log_of_a_beam_twin_draws_the_beam(tmp_path):
    """The emulator logs the plant's full state; the twin redraws the rod with the same plant (PRB joints or
    beam nodes), so the camera films the plant the rig ran."""
    from softpend.hardware.emulator import RigConfig, truth_columns
    from softpend.io.samplelog import SampleLog
    from softpend.plant import RodParams, make_plant

    beam = make_plant("beam", params=RodParams())
    q, qd = beam.hanging_state()
    beam.reset(q, qd)
    rows = []
    for k in range(5):
        beam.step(0.05)
        q, qd = beam.joint_state()
        rows.append([0.01 * (k + 1), 0.05, *q, *qd])
    with SampleLog(tmp_path / "truth.csv", truth_columns(beam.n_coordinates)) as log:
        for row in rows:
            log.append(row)
    times, points, hub = truth_link_points(tmp_path / "truth.csv", RodParams(), plant="beam")
    assert points.shape == (5, len(beam.link_points_m()), 2)
    np.testing.assert_allclose(points[-1], beam.link_points_m(), atol=1e-6)
    np.testing.assert_allclose(np.hypot(*points[:, -1].T), RodParams().length_m, rtol=0.02)  # nearly straight
    with pytest.raises(ValueError, match="plant"):
        RigConfig(task=Task(plant="rubber"))


@pytest.mark.expensive
def test_twin_model_is_within_2x_of_the_simulator_model(tmp_path):
    session = run_twin_session(tmp_path, duration_s=65.0, seed=0, progress=False)
    result = compare_with_simulator_model(session.dataset, seed=0)
    assert result["ratio"] <= 2.0
