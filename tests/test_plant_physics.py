"""The PRB plant against physics: pendulum period, energy balance, Euler-Bernoulli cantilever."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softpend.plant import PRBPlant, RodParams, SimulationDiverged


def _zero_crossing_times(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Upward zero crossings, linearly interpolated."""
    idx = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
    return t[idx] - x[idx] * (t[idx + 1] - t[idx]) / (x[idx + 1] - x[idx])


@pytest.mark.parametrize("tip_mass_kg", [0.0, 0.02])
def test_single_link_small_oscillation_period_matches_compound_pendulum(tip_mass_kg: float) -> None:
    # n = 1 and no spring: the link swings freely about the hub axis, a compound pendulum
    p = RodParams(
        n_links=1,
        stiffness_scale=0.0,
        tip_mass_kg=tip_mass_kg,
        joint_damping_nms_per_rad=0.0,
        hub_friction_nms_per_rad=0.0,
    )
    plant = PRBPlant(p)
    q, qd = plant.hanging_state()
    q[1] = 0.02  # small swing of the link relative to the (free) hub
    plant.reset(q, qd)
    t, angle = [0.0], [0.02]
    for _ in range(1000):
        plant.step(0.0)
        qq, _ = plant.joint_state()
        t.append(plant.time_s)
        angle.append(qq[0] + qq[1] - math.pi)
    crossings = _zero_crossing_times(np.array(t), np.array(angle))
    period = float(np.mean(np.diff(crossings)))
    m, mt, length, g = p.mass_kg, p.tip_mass_kg, p.length_m, p.gravity_mps2
    inertia = m * length**2 / 3 + mt * length**2
    l_c = (m * length / 2 + mt * length) / (m + mt)
    expected = 2 * math.pi * math.sqrt(inertia / ((m + mt) * g * l_c))
    assert len(crossings) >= 8
    assert abs(period - expected) / expected < 0.005


@pytest.mark.parametrize("n_links", [4, 10])
def test_energy_is_conserved_without_damping_or_torque(n_links: int) -> None:
    p = RodParams(n_links=n_links, joint_damping_nms_per_rad=0.0, hub_friction_nms_per_rad=0.0)
    plant = PRBPlant(p)
    plant.reset(*plant.hanging_state())
    rest = plant.energy_j()["total_j"]
    q, qd = plant.hanging_state()
    q[0] = math.pi / 2  # released straight and horizontal: it swings and bends
    plant.reset(q, qd)
    e0 = plant.energy_j()["total_j"]
    energies, elastic = [], []
    for _ in range(1000):  # 10 s
        plant.step(0.0)
        e = plant.energy_j()
        energies.append(e["total_j"])
        elastic.append(e["elastic_j"])
    drift = np.max(np.abs(np.array(energies) - e0)) / (e0 - rest)
    assert drift < 0.005
    assert max(elastic) > 1e-3 * (e0 - rest)  # the rod really bent on the way


def test_damping_dissipates_energy_monotonically() -> None:
    plant = PRBPlant(RodParams())
    q, qd = plant.hanging_state()
    q[0] = math.pi / 2
    plant.reset(q, qd)
    energies = [plant.energy_j()["total_j"]]
    for _ in range(300):
        plant.step(0.0)
        energies.append(plant.energy_j()["total_j"])
    assert np.all(np.diff(energies) < 1e-6)
    assert energies[-1] < energies[0] - 0.01


def test_motor_work_equals_energy_gain_without_dissipation() -> None:
    p = RodParams(joint_damping_nms_per_rad=0.0, hub_friction_nms_per_rad=0.0)
    plant = PRBPlant(p, substeps=4)
    plant.reset(*plant.hanging_state())
    e0 = plant.energy_j()["total_j"]
    work = 0.0
    torque = 0.04
    for k in range(200):
        phi_before = plant.joint_state()[0][0]
        sign = 1.0 if math.sin(2 * math.pi * 1.1 * k * plant.dt_s) > 0 else -1.0
        plant.step(sign * torque)
        work += sign * torque * (plant.joint_state()[0][0] - phi_before)
    gain = plant.energy_j()["total_j"] - e0
    assert gain > 0.01
    assert abs(gain - work) / gain < 0.01


@pytest.mark.parametrize("n_links", [8, 16, 32])
def test_cantilever_tip_deflection_matches_euler_bernoulli(n_links: int) -> None:
    # stiff enough for small-deflection theory (sag about 1% of L)
    p = RodParams(n_links=n_links, stiffness_scale=20.0)
    plant = PRBPlant(p, hub_locked_at_rad=-math.pi / 2)
    sag = -plant.static_equilibrium().ey_m
    error = abs(sag - p.static_sag_euler_bernoulli_m) / p.static_sag_euler_bernoulli_m
    assert error < 0.05


def test_cantilever_error_shrinks_as_n_grows() -> None:
    errors = []
    for n_links in (4, 8, 16, 32):
        p = RodParams(n_links=n_links, stiffness_scale=20.0, tip_mass_kg=0.0)
        sag = -PRBPlant(p, hub_locked_at_rad=-math.pi / 2).static_equilibrium().ey_m
        errors.append(abs(sag - p.static_sag_euler_bernoulli_m) / p.static_sag_euler_bernoulli_m)
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 0.002


def test_default_rod_design_targets() -> None:
    p = RodParams()
    sag = -PRBPlant(p, hub_locked_at_rad=-math.pi / 2).static_equilibrium().ey_m
    assert 0.10 <= sag / p.length_m <= 0.30  # visibly bends
    assert p.torque_limit_nm < p.gravity_torque_horizontal_nm  # cannot lift it straight up


def test_observed_rates_match_numerical_derivatives() -> None:
    plant = PRBPlant(RodParams(), dt_s=0.001, substeps=2)
    q, qd = plant.hanging_state()
    q[0] = math.pi - 0.6
    plant.reset(q, qd)
    samples = [plant.observe().as_array()]
    for k in range(400):
        samples.append(plant.step(0.05 * math.sin(6 * k * plant.dt_s)).as_array())
    x = np.array(samples)
    # positions (unwrapped angles) and their reported rates
    for pos, rate in ((0, 5), (1, 6), (2, 7), (3, 8), (4, 9)):
        signal = np.unwrap(x[:, pos]) if pos in (0, 1, 4) else x[:, pos]
        numeric = np.gradient(signal, plant.dt_s)[5:-5]
        scale = np.max(np.abs(x[:, rate]))
        assert np.max(np.abs(numeric - x[5:-5, rate])) < 0.02 * scale + 1e-6


def test_tip_position_is_end_of_link_points_and_theta_consistent() -> None:
    plant = PRBPlant(RodParams(n_links=5))
    plant.reset(np.array([2.5, 0.1, -0.2, 0.05, 0.1, -0.1]), np.zeros(6))
    obs = plant.observe()
    points = plant.link_points_m()
    assert points.shape == (6, 2)
    np.testing.assert_allclose(points[-1], [obs.ex_m, obs.ey_m], atol=1e-12)
    np.testing.assert_allclose(np.diff(points, axis=0).__pow__(2).sum(axis=1), plant.params.link_length_m**2)
    assert math.isclose(obs.theta_rad, math.atan2(-obs.ex_m, obs.ey_m), abs_tol=1e-12)
    assert -math.pi <= obs.theta_rad < math.pi and -math.pi <= obs.phi_rad < math.pi


def test_torque_is_clipped_to_the_limit() -> None:
    plant = PRBPlant(RodParams(torque_limit_nm=0.05))
    plant.step(10.0)
    assert plant.last_torque_nm == pytest.approx(0.05)
    plant.step(-10.0)
    assert plant.last_torque_nm == pytest.approx(-0.05)


@pytest.mark.parametrize(
    "field, value",
    [
        ("n_links", 0),
        ("n_links", 2.5),
        ("mass_kg", 0.0),
        ("mass_kg", -1.0),
        ("length_m", 0.0),
        ("torque_limit_nm", 0.0),
        ("width_m", -0.01),
        ("youngs_modulus_pa", float("nan")),
        ("tip_mass_kg", float("inf")),
        ("joint_damping_nms_per_rad", -1.0),
    ],
)
def test_bad_parameters_raise_value_error_naming_them(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        RodParams(**{field: value})


@pytest.mark.parametrize(
    "kwargs, name", [({"dt_s": 0.0}, "dt_s"), ({"dt_s": float("nan")}, "dt_s"), ({"substeps": 0}, "substeps")]
)
def test_bad_plant_arguments_raise(kwargs: dict, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        PRBPlant(RodParams(), **kwargs)


def test_bad_state_and_torque_raise() -> None:
    plant = PRBPlant(RodParams())
    with pytest.raises(ValueError, match="joint_angles_rad"):
        plant.reset(np.zeros(3), np.zeros(5))
    with pytest.raises(ValueError, match="joint_velocities_rad_s"):
        plant.reset(np.zeros(5), np.array([0, 0, np.nan, 0, 0]))
    with pytest.raises(ValueError, match="torque_nm"):
        plant.step(float("nan"))


def test_divergence_is_reported_not_returned_as_nan() -> None:
    # an undamped 10-link chain released with a sharp kink excites modes the Newton solver cannot follow
    plant = PRBPlant(RodParams(n_links=10, joint_damping_nms_per_rad=0.0, hub_friction_nms_per_rad=0.0))
    q = np.zeros(11)
    q[0], q[1] = 2.0, 0.2
    plant.reset(q, np.zeros(11))
    with pytest.raises(SimulationDiverged) as info:
        for _ in range(1000):
            obs = plant.step(0.0)
            assert np.all(np.isfinite(obs.as_array()))
    assert "solver" in info.value.reason or "non-finite" in info.value.reason


def test_same_inputs_give_identical_trajectories() -> None:
    def run() -> np.ndarray:
        plant = PRBPlant(RodParams())
        plant.reset(*plant.hanging_state())
        torques = np.random.default_rng(3).uniform(-0.06, 0.06, 200)
        return np.array([plant.step(t).as_array() for t in torques])

    np.testing.assert_array_equal(run(), run())
