"""Grey-box identification (multiple shooting on the PRB plant) and the model-quality measures."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support import one_line_error

from softpend.cli import main
from softpend.plant import PRBPlant, RodParams
from softpend.sysid import BabbleProtocol, babble
from softpend.sysid.greybox import GreyBoxConfig, identify, reconstruct_joint_states
from softpend.sysid.quality import (
    prb_one_step_errors,
    prb_rollout_tip_errors,
    rollout_starts,
    tip_rmse_at_s,
    valid_prediction,
)

SMALL = BabbleProtocol(n_trials=3, trial_length_s=1.0)
#: A guess 20-60 % off the truth in every estimated field.
OFF = dict(
    hub_inertia_kgm2=1.4,
    hub_friction_nms_per_rad=0.6,
    youngs_modulus_pa=1.3,
    joint_damping_nms_per_rad=1.5,
    tip_mass_kg=0.8,
)


@pytest.fixture(scope="module")
def small():
    return babble(SMALL, seed=4, progress=False)


def _guess(truth: RodParams) -> RodParams:
    return truth.replace(**{name: getattr(truth, name) * factor for name, factor in OFF.items()})


@pytest.fixture(scope="module")
def fitted(small):
    return identify(
        small, GreyBoxConfig(window_s=0.2, max_windows=8, max_iterations=15), initial_params=_guess(small.params)
    )


def test_identification_recovers_the_parameters_of_simulated_data(small, fitted):
    errors = fitted.relative_errors(small.params)
    assert set(errors) == set(OFF)
    assert max(errors.values()) < 0.01, errors  # from 20-60 % off
    # the initial guess really was off, and the uncertainty is small but positive
    assert all(abs(getattr(fitted.initial_params, n) / getattr(small.params, n) - 1) > 0.15 for n in OFF)
    for name, value in fitted.estimates.items():
        assert 0 < fitted.std[name] < 0.01 * value
    assert fitted.params.torque_limit_nm == small.params.torque_limit_nm
    assert fitted.residual_rms_rad < 1e-5


def test_identification_result_round_trips_through_rod_params_json(fitted, tmp_path):
    path = tmp_path / "identified.json"
    path.write_text(json.dumps(fitted.to_dict()))
    assert RodParams.from_json(path) == fitted.params
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps(fitted.params.to_dict()))
    assert RodParams.from_json(plain) == fitted.params
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"rod_params": {"hub_inertia": 1.0}}))
    with pytest.raises(ValueError, match="bad.json.*hub_inertia"):
        RodParams.from_json(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(ValueError, match="JSON object"):
        RodParams.from_json(bad)


def test_a_dataset_without_torque_cannot_identify_the_torque_gain():
    still = babble(SMALL.replace(torque_std_fraction=0.0, feedback_trial_fraction=0.0), seed=1, progress=False)
    assert not np.any(still.torques_nm)
    with pytest.raises(ValueError, match="torque_gain"):
        identify(still, GreyBoxConfig(parameters=("hub_inertia_kgm2", "torque_gain"), window_s=0.2, max_windows=4))


def test_a_dataset_where_nothing_moves_is_rejected_naming_a_parameter():
    # the straight rod hanging at rest with no torque: no observation depends on any parameter
    at_rest = babble(
        SMALL.replace(
            start="hanging",
            start_angle_std_rad=0.0,
            start_bend_std_rad=0.0,
            start_rate_std_rad_s=0.0,
            torque_std_fraction=0.0,
            feedback_trial_fraction=0.0,
        ),
        seed=1,
        progress=False,
    )
    with pytest.raises(ValueError, match="cannot identify hub_inertia_kgm2"):
        identify(at_rest, GreyBoxConfig(window_s=0.2, max_windows=4))


def test_collinear_stiffness_parameters_are_rejected():
    with pytest.raises(ValueError, match="stiffness_scale"):
        identify(
            babble(SMALL.replace(n_trials=1), seed=0, progress=False),
            GreyBoxConfig(parameters=("youngs_modulus_pa", "stiffness_scale")),
        )


def test_joint_state_reconstruction_puts_the_tip_where_it_was_observed():
    params = RodParams()
    plant = PRBPlant(params)
    q = np.array([0.3, 0.05, -0.02, 0.04, 0.01])
    o = plant.reset(q, np.zeros(5))
    r = reconstruct_joint_states(
        np.array([o.phi_rad]), np.array([o.ex_m]), np.array([o.ey_m]), np.array([o.er_rad]), params
    )[0]
    back = plant.reset(r, np.zeros(5))
    assert r[0] == pytest.approx(q[0], abs=1e-12)
    assert abs(back.ex_m - o.ex_m) < 1e-5 and abs(back.ey_m - o.ey_m) < 1e-5 and abs(back.er_rad - o.er_rad) < 1e-4


def test_valid_prediction_time_on_a_hand_made_trajectory():
    dt, length = 0.01, 0.3
    t = np.arange(101) * dt
    threshold = 0.05 * length  # 15 mm
    errors = np.stack(
        [
            0.01 * t,  # 1 cm/s: never reaches 15 mm within 1 s (censored)
            0.1 * t,  # 10 cm/s: above 15 mm from t = 0.16 s on, valid up to 0.15 s
            threshold * np.exp(6.0 * (t - 0.5)),  # exponential growth through the threshold at 0.5 s
        ]
    )
    result = valid_prediction(errors, dt, length, lyapunov_rate_per_s=6.0)
    np.testing.assert_allclose(result.times_s, [1.0, 0.15, 0.5], atol=1e-12)
    assert result.censored.tolist() == [True, False, False]
    assert result.median_s == pytest.approx(0.5)
    assert result.median_lyapunov == pytest.approx(3.0)
    assert tip_rmse_at_s(errors, dt, 0.5) == pytest.approx(np.sqrt(np.mean(errors[:, 50] ** 2)))
    with pytest.raises(ValueError, match="tip_error_m"):
        valid_prediction(errors[:, :1], dt, length)


def test_prb_rollouts_with_the_true_parameters_reproduce_the_data(small):
    starts = rollout_starts(small, steps=20, stride=25)
    exact = prb_rollout_tip_errors(small.params, small, starts, 20)
    assert exact.shape == (starts.shape[0], 21) and exact.max() < 1e-9
    off = prb_rollout_tip_errors(small.params, small, starts, 20, hub_offset_rad=1e-3)
    assert off[:, 0].min() > 0.9 * 1e-3 * small.params.length_m * 0.5  # the tip moved with the hub
    assert prb_one_step_errors(small.params, small, trials=[0])["mse"] < 1e-18
    wrong = prb_one_step_errors(small.params.replace(hub_inertia_kgm2=4e-4), small, trials=[0])
    assert wrong["mse"] > 1e-12


def test_identify_command_writes_json_that_rod_params_loads(small, tmp_path, capsys):
    from softpend.sysid import write_dataset

    data = write_dataset(tmp_path / "d.npz", small)
    guess = tmp_path / "guess.json"
    guess.write_text(json.dumps(_guess(small.params).to_dict()))
    out = tmp_path / "id.json"
    code = main(
        [
            "identify",
            str(data),
            "--initial-params",
            str(guess),
            "--out",
            str(out),
            "--window-s",
            "0.2",
            "--max-windows",
            "4",
            "--max-iterations",
            "3",
            "--parameters",
            "hub_inertia_kgm2,tip_mass_kg",
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "hub_inertia_kgm2" in printed and "tip_mass_kg" in printed
    loaded = RodParams.from_json(out)
    assert loaded.youngs_modulus_pa == _guess(small.params).youngs_modulus_pa  # not estimated: the guess
    assert json.loads(out.read_text())["std"].keys() == {"hub_inertia_kgm2", "tip_mass_kg"}
    assert main(["identify", str(data), "--parameters", "no_such_field"]) == 2
    one_line_error(capsys, "parameters")
    other = tmp_path / "other.json"
    other.write_text("{}")
    assert main(["identify", str(data), "--out", str(other)]) == 2
    one_line_error(capsys, "refusing")


def test_torque_gain_and_encoder_offset_are_recovered(small):
    from softpend.sysid import TrajectoryDataset

    # the rig's torque constant 10 % low (recorded torque = true / 1.1) and its encoder 0.02 rad off
    phi = small.position_names.index("phi_rad")
    positions = small.positions.copy()
    positions[..., phi] = (positions[..., phi] + 0.02 + np.pi) % (2 * np.pi) - np.pi
    rig = TrajectoryDataset(
        positions=positions,
        velocities=small.velocities,
        torques_nm=small.torques_nm / 1.1,
        metadata=dict(small.metadata, plant_params=None),
    )
    config = GreyBoxConfig(
        parameters=("hub_inertia_kgm2", "tip_mass_kg", "torque_gain", "encoder_offset_rad", "torque_delay_s"),
        window_s=0.2,
        max_windows=8,
        max_iterations=15,
    )
    result = identify(rig, config, initial_params=small.params.replace(hub_inertia_kgm2=3e-4, tip_mass_kg=0.008))
    assert result.torque_gain == pytest.approx(1.1, rel=1e-3)
    assert result.encoder_offset_rad == pytest.approx(0.02, abs=1e-4)
    assert abs(result.torque_delay_s) < 1e-5  # the torque acted when it was recorded
    assert result.estimates["hub_inertia_kgm2"] == pytest.approx(small.params.hub_inertia_kgm2, rel=1e-2)
    assert result.to_dict()["calibration"]["torque_gain"] == result.torque_gain


def test_joint_states_estimated_from_the_past_match_the_recorded_ones(small):
    from softpend.sysid.greybox import estimate_joint_states

    samples = np.array([[0, 40], [1, 75], [2, 99]])
    estimated = estimate_joint_states(small.params, small, samples, lookback_s=0.1)
    recorded = np.concatenate(
        [
            small.joint_positions_rad[samples[:, 0], samples[:, 1]],
            small.joint_velocities_rad_s[samples[:, 0], samples[:, 1]],
        ],
        axis=1,
    )
    estimated[:, 0] = (
        recorded[:, 0] + (estimated[:, 0] - recorded[:, 0] + np.pi) % (2 * np.pi) - np.pi
    )  # hub angle mod 2 pi
    np.testing.assert_allclose(estimated, recorded, atol=1e-6)
    with pytest.raises(ValueError, match="look 0.1 s back"):
        estimate_joint_states(small.params, small, np.array([[0, 5]]), lookback_s=0.1)


def test_a_camera_delay_is_recovered(small):
    from softpend.sysid import TrajectoryDataset

    # the camera's tip half a sample late: each sample shows the mean of the tip at this sample and the one before
    positions = small.positions.copy()
    for name in ("ex_m", "ey_m", "er_rad"):
        i = small.position_names.index(name)
        positions[:, 1:, i] = 0.5 * (small.positions[:, 1:, i] + small.positions[:, :-1, i])
    rig = TrajectoryDataset(
        positions=positions,
        velocities=small.velocities,
        torques_nm=small.torques_nm,
        metadata=dict(small.metadata, plant_params=None),
    )
    config = GreyBoxConfig(
        parameters=("hub_inertia_kgm2", "camera_delay_s"), window_s=0.2, max_windows=8, max_iterations=15
    )
    result = identify(rig, config, initial_params=small.params.replace(hub_inertia_kgm2=3e-4))
    assert result.camera_delay_s == pytest.approx(0.5 * small.dt_s, abs=2e-4)
    assert result.estimates["hub_inertia_kgm2"] == pytest.approx(small.params.hub_inertia_kgm2, rel=1e-2)


def test_identification_of_a_whirling_rod_from_the_default_guess_with_rig_observations():
    """An unknown rod (fields 0.5x-2x, torque gain 2: every mass-like field halved) driven by the commissioning's
    multisine whirls; from the rig's observations (no tip angle) and the default rod as the guess, the fit (warm-up on
    short windows, windows whose simulation diverges left out) recovers every parameter."""
    from softpend.study.unknown_rod import UnknownRod
    from softpend.sysid.dataset import TrajectoryDataset, dataset_metadata

    base = RodParams()
    drawn = base.replace(
        hub_inertia_kgm2=3.8e-4,
        hub_friction_nms_per_rad=1.05e-3,
        youngs_modulus_pa=3.8e7,
        joint_damping_nms_per_rad=3.3e-4,
        tip_mass_kg=0.0113,
    )
    rod = UnknownRod(drawn, 2.0).effective_rod()
    protocol = BabbleProtocol(
        n_trials=1,
        trial_length_s=6.0,
        start="hanging",
        start_angle_std_rad=0.0,
        start_bend_std_rad=0.0,
        start_rate_std_rad_s=0.0,
        feedback_trial_fraction=0.0,
        program="multisine",
        torque_bandwidth_hz=6.0,
    )
    data = babble(protocol, params=rod, seed=0, progress=False)
    names = ("phi_rad", "theta_rad", "ex_m", "ey_m")
    cols = [data.position_names.index(n) for n in names]
    positions = data.positions[:, :, cols]
    rig = TrajectoryDataset(
        metadata=dataset_metadata(positions, dt_s=data.dt_s, position_names=names, plant_params=base),
        positions=positions,
        velocities=data.velocities[:, :, cols],
        torques_nm=data.torques_nm,
    )
    assert np.abs(rig.velocities[:, :, 0]).max() > 30.0  # it whirls
    parameters = tuple(OFF) + ("mass_kg",)
    result = identify(
        rig, GreyBoxConfig(parameters=parameters, window_s=0.3, max_windows=12, max_iterations=15), initial_params=base
    )
    errors = {name: abs(value / getattr(rod, name) - 1) for name, value in result.estimates.items()}
    assert max(errors.values()) < 1e-3, errors
    assert result.residual_rms_rad < 1e-6
