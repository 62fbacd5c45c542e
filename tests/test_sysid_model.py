"""Learned dynamics model: state layouts, training, metrics, rollouts, files, command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from softpend.sysid import (
    BabbleProtocol,
    DynamicsEnsemble,
    DynamicsModel,
    StateLayout,
    TrajectoryDataset,
    babble,
    fit_dynamics_model,
    load_model,
    one_step_errors,
    rollout,
    rollout_errors,
    rollout_trial,
    save_model,
)


def _select_trials(dataset: TrajectoryDataset, trials: list[int]) -> TrajectoryDataset:
    """A dataset with only the given trials."""
    arrays = {name: value[np.asarray(trials)] for name, value in dataset.arrays().items()}
    return TrajectoryDataset(metadata=dict(dataset.metadata, n_trials=len(trials)), **arrays)


@pytest.fixture(scope="module")
def data() -> tuple[TrajectoryDataset, TrajectoryDataset]:
    torch.set_num_threads(1)
    protocol = BabbleProtocol(n_trials=10, trial_length_s=2.0)
    return babble(protocol, seed=1, progress=False), babble(protocol.replace(n_trials=3), seed=2, progress=False)


@pytest.fixture(scope="module")
def fitted(data):
    train, _ = data
    # full information with 3 past frames (the recommended setting; see test_default_state_is_the_reports)
    return fit_dynamics_model(
        train, history=3, max_epochs=60, batch_size=128, learning_rate=5e-3, patience=60, seed=0, progress=False
    )


# ------------------------------------------------------------------ layouts
def test_layouts_and_history(data):
    train, _ = data
    full, limited = StateLayout.full(), StateLayout.limited(history=2)
    assert full.dim == 10 and full.names[:5] == ("phi_rad", "theta_rad", "ex_m", "ey_m", "er_rad")
    assert limited.dim == 12 and limited.names[6:9] == ("phi_rad_lag1", "ex_m_lag1", "ey_m_lag1")
    states = limited.states(train)
    assert states.shape == (10, train.n_samples - 2, 12)
    # lag k of state i is the position of dataset sample i + history - k
    np.testing.assert_array_equal(states[:, :, limited.index("ex_m_lag2")], train.column("ex_m")[:, :-2])
    np.testing.assert_array_equal(states[:, :, limited.index("ex_m_lag1")], train.column("ex_m")[:, 1:-1])
    assert limited.torques(train).shape == (10, train.n_samples - 3)
    with pytest.raises(ValueError, match="information"):
        StateLayout("partial")
    rig_like = _select_trials(train, [0])
    rig_like = TrajectoryDataset(
        positions=rig_like.positions[..., [0, 2, 3]],
        velocities=rig_like.velocities[..., [0, 2, 3]],
        torques_nm=rig_like.torques_nm,
        metadata=dict(
            rig_like.metadata,
            position_names=["phi_rad", "ex_m", "ey_m"],
            velocity_names=["phi_dot_rad_s", "ex_dot_m_s", "ey_dot_m_s"],
        ),
    )
    with pytest.raises(ValueError, match="use information='limited'"):
        full.states(rig_like)
    assert limited.states(rig_like).shape[-1] == 12


# ------------------------------------------------------------------ training and metrics
def test_training_beats_the_trivial_predictor_on_held_out_trials(fitted, data):
    _, test = data
    assert fitted.val_loss[0][fitted.best_epochs[0] - 1] <= min(fitted.val_loss[0]) * 1.001  # best weights kept
    errors = one_step_errors(fitted.model, test)
    # held-out trials: far below "next = current" in the network's loss and in the report's units
    assert errors["mse_normalised"] < 0.3 * errors["mse_normalised_trivial"]
    assert errors["mse"] < 0.4 * errors["mse_trivial"]
    assert errors["n_transitions"] == 3 * (test.n_samples - 1 - 3)  # 3 samples feed the first lags
    by_variable = errors["mse_by_variable"]
    assert errors["one_step_tip_rmse_m"] == pytest.approx(np.sqrt(by_variable["ex_m"] + by_variable["ey_m"]))
    # split by trial, no overlap
    assert set(fitted.train_trials).isdisjoint(fitted.val_trials)
    assert len(fitted.train_trials) + len(fitted.val_trials) == 10


def test_default_state_is_the_reports(data):
    """The default model uses the report's state (no history); it also beats "next = current"."""
    train, test = data
    fit = fit_dynamics_model(train, max_epochs=30, batch_size=128, learning_rate=5e-3, seed=0, progress=False)
    assert fit.model.layout == StateLayout.full() and fit.model.hidden_widths == (16, 16, 16)
    errors = one_step_errors(fit.model, test)
    assert errors["mse_normalised"] < 0.9 * errors["mse_normalised_trivial"]
    assert errors["mse"] < errors["mse_trivial"]


def test_training_is_deterministic(data):
    train, _ = data
    small = _select_trials(train, [0, 1, 2])
    a = fit_dynamics_model(small, max_epochs=3, seed=4, progress=False)
    b = fit_dynamics_model(small, max_epochs=3, seed=4, progress=False)
    for (name, pa), pb in zip(a.model.state_dict().items(), b.model.state_dict().values()):
        assert torch.equal(pa, pb), name
    c = fit_dynamics_model(small, max_epochs=3, seed=5, progress=False)
    assert not torch.equal(a.model.net[0].weight, c.model.net[0].weight)


class _Drift:
    """Hand-made model for a resting rod: the tip moves +c in x and the hub +a per step."""

    def __init__(self, c: float, a: float) -> None:
        self.layout = StateLayout.limited()
        self.c, self.a = c, a

    def predict_next(self, state, torque_nm, generator=None):
        out = state.clone()
        out[:, self.layout.index("ex_m")] += self.c
        out[:, self.layout.index("phi_rad")] += self.a
        return out


def test_rollout_errors_on_a_hand_made_case():
    n_trials, n_samples = 2, 40
    positions = np.zeros((n_trials, n_samples, 3))
    positions[..., 2] = 0.3  # rod at rest, upright
    data = TrajectoryDataset(
        positions=positions,
        velocities=np.zeros_like(positions),
        torques_nm=np.zeros((n_trials, n_samples - 1)),
        metadata={
            "schema": "softpend.sysid.dataset",
            "schema_version": 1,
            "softpend_version": "test",
            "source": "rig",
            "dt_s": 0.01,
            "n_trials": n_trials,
            "n_samples": n_samples,
            "position_names": ["phi_rad", "ex_m", "ey_m"],
            "velocity_names": ["phi_dot_rad_s", "ex_dot_m_s", "ey_dot_m_s"],
            "differentiation": "backward",
            "plant": None,
            "plant_params": None,
            "seed": None,
            "protocol": {},
            "notes": "",
        },
    )
    errors = rollout_errors(_Drift(c=0.001, a=0.002), data, horizon_s=0.2, start_stride=5)
    k = np.arange(21)
    np.testing.assert_allclose(errors.horizon_s, k * 0.01)
    np.testing.assert_allclose(errors.tip_rmse_m, 0.001 * k, atol=1e-12)
    np.testing.assert_allclose(errors.phi_rmse_rad, 0.002 * k, atol=1e-12)
    np.testing.assert_allclose(errors.hold_tip_rmse_m, 0.0, atol=1e-15)
    assert errors.n_rollouts == 2 * len(range(0, 40 - 20, 5))
    assert errors.at(0.1)["tip_rmse_m"] == pytest.approx(0.01)
    with pytest.raises(ValueError, match="horizon_s"):
        rollout_errors(_Drift(0.0, 0.0), data, horizon_s=1.0)


def test_rollout_api_batched_and_wrap_aware(fitted, data):
    model = fitted.model
    _, test = data
    x0 = torch.as_tensor(model.layout.states(test)[:, 0], dtype=torch.float32)
    torques = torch.as_tensor(model.layout.torques(test)[:, :15], dtype=torch.float32)
    with torch.inference_mode():
        path = rollout(model, x0, torques)
        assert path.shape == (3, 16, 10 + 3 * 5)
        # lagged frames are shifted in: lag 1 of step t + 1 is the position of step t
        torch.testing.assert_close(path[:, 1:, 10:15], path[:, :-1, :5])
        torch.testing.assert_close(path[:, 0], x0)
        x = x0
        for t in range(15):  # batched rollout == stepping row by row
            x = torch.cat([model.predict_next(x[i : i + 1], torques[i : i + 1, t]) for i in range(3)])
        torch.testing.assert_close(path[:, -1], x, rtol=1e-3, atol=1e-4)  # float32 matmul order
        # angles stay wrapped; a state just across the seam gives the same prediction as its twin
        near = x0.clone()
        near[:, 0] = np.pi - 1e-4
        twin = near.clone()
        twin[:, 0] = near[:, 0] - 2 * np.pi  # the same angle, unwrapped the other way
        a, b = model.predict_next(near, torques[:, 0]), model.predict_next(twin, torques[:, 0])
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)
        assert torch.all(path[..., [0, 1, 4]].abs() <= np.pi + 1e-6)
    with pytest.raises(ValueError, match="state must have shape"):
        model.predict_next(torch.zeros(2, 7), torch.zeros(2))
    with pytest.raises(ValueError, match="torques_nm must have shape"):
        rollout(model, x0, torques[:2])
    # the figure helper: theta from the tip position at limited information too
    curves = rollout_trial(model, test, trial=0, start_s=0.1, duration_s=0.5)
    assert curves["phi_rad_model"].shape == (51,) and curves["phi_rad"][0] == pytest.approx(
        curves["phi_rad_model"][0], abs=1e-6
    )
    assert curves["time_s"][0] == pytest.approx(0.1 + 0.03)  # start_s counts from the first full state


def test_jacobian_at_upright_is_finite(fitted):
    model = fitted.model.double()
    try:
        d = model.layout.dim
        x0 = torch.zeros(d, dtype=torch.float64)
        for name in ("ey_m", "ey_m_lag1", "ey_m_lag2", "ey_m_lag3"):
            x0[model.layout.index(name)] = 0.3
        jac = torch.autograd.functional.jacobian(
            lambda x: model.predict_next(x[None], torch.zeros(1, dtype=torch.float64))[0], x0
        )
        assert jac.shape == (d, d) and torch.all(torch.isfinite(jac))
        # input matrix: a positive torque speeds the hub up counter-clockwise
        torque_jac = torch.autograd.functional.jacobian(
            lambda u: model.predict_next(x0[None], u)[0], torch.zeros(1, dtype=torch.float64)
        )
        assert float(torque_jac[model.layout.index("phi_dot_rad_s"), 0]) > 0
    finally:
        model.float()


def test_ensemble_rollouts_and_files(tmp_path, data):
    train, test = data
    small = _select_trials(train, [0, 1, 2, 3])
    fit = fit_dynamics_model(small, max_epochs=3, ensemble_size=3, hidden_widths=(8, 8), seed=1, progress=False)
    ensemble = fit.model
    assert isinstance(ensemble, DynamicsEnsemble) and len(ensemble) == 3
    x0 = torch.as_tensor(StateLayout.full().states(test)[:, 0], dtype=torch.float32).repeat(20, 1)
    torques = torch.zeros(60, 10)
    with torch.inference_mode():
        a = rollout(ensemble, x0, torques, generator=torch.Generator().manual_seed(0))
        b = rollout(ensemble, x0, torques, generator=torch.Generator().manual_seed(0))
        c = rollout(ensemble, x0, torques, generator=torch.Generator().manual_seed(1))
        torch.testing.assert_close(a, b)
        assert not torch.equal(a, c)  # members differ and are drawn per row
        member_2 = ensemble.members[2].predict_next(x0[:4], torques[:4, 0])
        torch.testing.assert_close(ensemble.predict_next(x0[:4], torques[:4, 0], member=2), member_2)
    weights, meta = save_model(tmp_path / "ens", ensemble, fit.metadata())
    loaded, metadata = load_model(weights)
    assert isinstance(loaded, DynamicsEnsemble) and metadata["train_trials"] == fit.train_trials.tolist()
    for key, value in ensemble.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[key], value)
    # weights that do not match the metadata are refused with a clear error
    info = json.loads(meta.read_text())
    info["config"]["hidden_widths"] = [16, 16]
    meta.write_text(json.dumps(info))
    with pytest.raises(ValueError, match="do not match"):
        load_model(tmp_path / "ens")
    with pytest.raises(ValueError, match="member"):
        ensemble.predict_next(x0[:2], torques[:2, 0], member=5)


def test_limited_information_model_and_cli(tmp_path, data):
    from softpend.cli import main

    train, _ = data
    fit = fit_dynamics_model(train, information="limited", history=2, max_epochs=5, progress=False)
    assert isinstance(fit.model, DynamicsModel) and fit.model.layout.dim == 12
    # the command line: babble a tiny set, fit, evaluate on a held-out file
    assert main(["babble", str(tmp_path / "d.npz"), "--n-trials", "3", "--trial-length-s", "1", "--no-progress"]) == 0
    assert (
        main(
            [
                "babble",
                str(tmp_path / "t.npz"),
                "--n-trials",
                "2",
                "--trial-length-s",
                "1",
                "--seed",
                "9",
                "--no-progress",
            ]
        )
        == 0
    )
    code = main(
        [
            "fit-model",
            str(tmp_path / "d.npz"),
            str(tmp_path / "m"),
            "--max-epochs",
            "2",
            "--hidden-widths",
            "8,8",
            "--test-data",
            str(tmp_path / "t.npz"),
            "--no-progress",
        ]
    )
    assert code == 0
    model, metadata = load_model(tmp_path / "m")
    assert model.hidden_widths == (8, 8)
    assert np.isfinite(metadata["metrics"]["test"]["mse"]) and "tip_rmse_m@0.5s" in metadata["metrics"]["test"]
    assert main(["fit-model", str(tmp_path / "d.npz"), str(tmp_path / "m"), "--hidden-widths", "8,x"]) == 2


def test_perturbed_simulator_yardstick_grows_with_the_offset(data):
    from softpend.sysid import perturbed_simulator_errors

    _, test = data
    one = _select_trials(test, [0])
    exact = perturbed_simulator_errors(one, hub_offset_rad=0.0, horizon_s=0.3, start_stride=50)
    off = perturbed_simulator_errors(one, hub_offset_rad=1e-2, horizon_s=0.3, start_stride=50)
    assert exact.n_rollouts == off.n_rollouts == 4
    assert exact.tip_rmse_m[-1] < 1e-3  # restarting the simulator from a recorded state reproduces the data
    assert off.phi_rmse_rad[0] == pytest.approx(1e-2)
    assert off.tip_rmse_m[-1] > 10 * exact.tip_rmse_m[-1] + 1e-3


def test_tip_is_kept_within_the_rods_reach(tmp_path, fitted, data):
    layout = StateLayout.full()
    model = DynamicsModel(layout, dt_s=0.01, torque_limit_nm=0.06, hidden_widths=(4,), tip_reach_m=0.3)
    free = DynamicsModel(layout, dt_s=0.01, torque_limit_nm=0.06, hidden_widths=(4,))
    with torch.no_grad():
        for m in (model, free):  # a network that predicts no velocity change: positions coast on
            m.net[-1].weight.zero_()
            m.net[-1].bias.zero_()
    ex, ey, ex_dot, ey_dot = (layout.index(n) for n in ("ex_m", "ey_m", "ex_dot_m_s", "ey_dot_m_s"))
    x = torch.zeros(3, layout.dim)
    angle = 0.4
    x[0, ey], x[0, ey_dot] = 0.3, 1.0  # straight up, moving outwards: would reach 0.31 m
    x[1, ex], x[1, ey] = -0.3 * np.sin(angle), 0.3 * np.cos(angle)  # tilted, moving outwards along the rod
    x[1, ex_dot], x[1, ey_dot] = -2.0 * np.sin(angle), 2.0 * np.cos(angle)
    x[2, ey], x[2, ey_dot] = 0.2, 1.0  # well inside: untouched
    with torch.no_grad():
        y, y_free = model.predict_next(x, torch.zeros(3)), free.predict_next(x, torch.zeros(3))
    radius = torch.hypot(y[:, ex], y[:, ey])
    assert float(torch.hypot(y_free[0, ex], y_free[0, ey])) == pytest.approx(0.31, abs=1e-6)
    torch.testing.assert_close(radius[:2], torch.full((2,), 0.3))
    assert float(torch.atan2(-y[1, ex], y[1, ey])) == pytest.approx(angle, abs=1e-6)  # pulled back radially
    assert float(y[1, layout.index("theta_rad")]) == pytest.approx(angle, abs=1e-6)  # theta follows the tip
    # differenced velocities stay consistent with the corrected positions: the radial motion is stopped
    torch.testing.assert_close(y[:, [ex_dot, ey_dot]], (y[:, [ex, ey]] - x[:, [ex, ey]]) / 0.01)
    assert abs(float(y[0, ey_dot])) < 1e-4
    torch.testing.assert_close(y[2], y_free[2])
    # kept in the file; trained models get the rod length plus the slack
    save_model(tmp_path / "reach", model)
    assert load_model(tmp_path / "reach")[0].tip_reach_m == 0.3
    from softpend.sysid.training import TIP_REACH_SLACK

    assert fitted.model.tip_reach_m == pytest.approx(data[0].params.length_m * (1 + TIP_REACH_SLACK))
    assert (
        fit_dynamics_model(
            _select_trials(data[0], [0, 1]), max_epochs=1, limit_tip_reach=False, progress=False
        ).model.tip_reach_m
        is None
    )
    with pytest.raises(ValueError, match="tip_reach_m"):
        DynamicsModel(layout, dt_s=0.01, torque_limit_nm=0.06, tip_reach_m=-0.3)


def test_perturbed_simulator_rate_offset_and_torque_noise(data):
    from softpend.sysid import perturbed_simulator_errors

    _, test = data
    one = _select_trials(test, [0])
    dt, length = test.dt_s, test.params.length_m
    kwargs = dict(hub_offset_rad=0.0, horizon_s=0.3, start_stride=50)
    # the hub 1e-2 rad/s faster with the springs' rates unchanged: the whole rod turns faster and the tip
    # is about dt * L * 1e-2 off after one step; near upright the error then grows
    rate = perturbed_simulator_errors(one, hub_rate_offset_rad_s=1e-2, **kwargs)
    assert rate.tip_rmse_m[1] == pytest.approx(dt * length * 1e-2, rel=0.2)
    assert rate.tip_rmse_m[-1] > 5 * rate.tip_rmse_m[1]
    # an unmodelled hub torque of sigma for one step turns the hub by at most sigma dt^2 / (2 J_hub) (less:
    # the clamp spring already drags the rod along)
    sigma = 1e-3
    one_step = perturbed_simulator_errors(
        one, hub_offset_rad=0.0, horizon_s=dt, start_stride=1, torque_noise_std_nm=sigma
    )
    free_hub = sigma * dt**2 / (2 * test.params.hub_inertia_kgm2)
    assert one_step.n_rollouts > 150 and 0.6 * free_hub < one_step.phi_rmse_rad[1] < 1.05 * free_hub
    noisy = perturbed_simulator_errors(one, torque_noise_std_nm=sigma, seed=3, **kwargs)
    again = perturbed_simulator_errors(one, torque_noise_std_nm=sigma, seed=3, **kwargs)
    np.testing.assert_array_equal(noisy.tip_rmse_m, again.tip_rmse_m)
    louder = perturbed_simulator_errors(one, torque_noise_std_nm=10 * sigma, seed=3, **kwargs)
    assert louder.tip_rmse_m[-1] > 5 * noisy.tip_rmse_m[-1]
    with pytest.raises(ValueError, match="torque_noise_std_nm"):
        perturbed_simulator_errors(one, torque_noise_std_nm=-1.0, **kwargs)


def test_simulator_yardsticks_match_the_model_one_step_error(data):
    from softpend.study.bench.sysid import simulator_yardsticks

    _, test = data
    one = _select_trials(test, [0])
    out = simulator_yardsticks(one, model_one_step_tip_m=2e-5, history=3, horizon_s=0.5)
    # the calibrated hub-rate offset makes the perfect simulator miss by the model's one-step error once
    assert out["simulator_one_best_model_step_one_step_tip_rmse_m"] == pytest.approx(2e-5, rel=0.1)
    assert out["simulator_one_best_model_step_hub_rate_offset_rad_s"] == pytest.approx(
        2e-5 / (test.dt_s * test.params.length_m), rel=0.2
    )
    for prefix in ("simulator_1e-4rad_off", "simulator_one_best_model_step", "simulator_torque_noise_1e-4nm"):
        assert out[f"{prefix}_tip_rmse_m_0.5s"] > out[f"{prefix}_one_step_tip_rmse_m"]  # errors grow near upright
    assert "simulator_1e-4rad_off_tip_rmse_m_1s" not in out  # beyond the horizon asked for
    with pytest.raises(ValueError, match="model_one_step_tip_m"):
        simulator_yardsticks(one, model_one_step_tip_m=0.0)


class _TorquePush:
    """Hand-made exact model of a hand-made system: the tip moves by ``c * torque`` per step."""

    def __init__(self, c: float, history: int) -> None:
        self.layout = StateLayout.limited(history)
        self.c = c

    def predict_next(self, state, torque_nm, generator=None):
        p = self.layout.n_positions
        out = state.clone()
        out[:, self.layout.index("ex_m")] += self.c * torque_nm
        if self.layout.history:  # shift the lags
            out[:, 3 * p :] = state[:, 2 * p : -p]
            out[:, 2 * p : 3 * p] = state[:, :p]
        return out


def test_rollout_metric_aligns_torques_and_history():
    """An exact model scores zero only if each torque is paired with the state it acts on (with lags)."""
    rng = np.random.default_rng(0)
    n_trials, n_samples, c = 2, 60, 0.01
    torques = rng.normal(size=(n_trials, n_samples - 1))
    positions = np.zeros((n_trials, n_samples, 3))
    positions[..., 2] = 0.3
    positions[:, 1:, 1] = c * np.cumsum(torques, axis=1)  # ex[t + 1] = ex[t] + c * torque[t]
    data = TrajectoryDataset(
        positions=positions,
        velocities=np.concatenate([np.zeros((n_trials, 1, 3)), np.diff(positions, axis=1) / 0.01], axis=1),
        torques_nm=torques,
        metadata={
            "schema": "softpend.sysid.dataset",
            "schema_version": 1,
            "softpend_version": "test",
            "source": "rig",
            "dt_s": 0.01,
            "n_trials": n_trials,
            "n_samples": n_samples,
            "position_names": ["phi_rad", "ex_m", "ey_m"],
            "velocity_names": ["phi_dot_rad_s", "ex_dot_m_s", "ey_dot_m_s"],
            "differentiation": "backward",
            "plant": None,
            "plant_params": None,
            "seed": None,
            "protocol": {},
            "notes": "",
        },
    )
    for history in (0, 2):
        errors = rollout_errors(_TorquePush(c, history), data, horizon_s=0.3, start_stride=7)
        np.testing.assert_allclose(errors.tip_rmse_m, 0.0, atol=1e-12)
        assert errors.hold_tip_rmse_m[-1] > 0.01  # the tip does move
    shifted = TrajectoryDataset(
        positions=positions, velocities=data.velocities, torques_nm=np.roll(torques, 1, axis=1), metadata=data.metadata
    )
    assert (
        rollout_errors(_TorquePush(c, 2), shifted, horizon_s=0.3, start_stride=7).tip_rmse_m[1] > 1e-3
    )  # one step off: caught


@pytest.mark.expensive
def test_best_full_information_model_accuracy_on_the_default_protocol():
    """The published Figure 3 setting on the report's protocol: the measured accuracy holds (the issue's
    target, 15 mm at 1 s, is not reached; see the fig03 notebook for why)."""
    from softpend.study.bench.sysid import BEST_FULL_CONFIG, TEST_SEED, TRAIN_SEED
    from softpend.sysid import evaluate_model

    torch.set_num_threads(1)
    protocol = BabbleProtocol()
    train = babble(protocol, seed=TRAIN_SEED, progress=False)
    test = babble(protocol.replace(n_trials=12), seed=TEST_SEED, progress=False)
    fit = fit_dynamics_model(train, BEST_FULL_CONFIG, progress=False)
    metrics = evaluate_model(fit.model, test, horizons_s=(0.5, 1.0, 2.0))
    assert metrics["tip_rmse_m@0.5s"] < 0.01  # measured 5.6 mm
    assert metrics["tip_rmse_m@1s"] < 0.1 < metrics["hold_tip_rmse_m@1s"]  # measured 62 mm; "hold" 176 mm
    assert metrics["tip_rmse_m@2s"] < 2 * test.params.length_m  # kept within the rod's reach
    assert metrics["mse_normalised"] < 0.002 * metrics["mse_normalised_trivial"]
