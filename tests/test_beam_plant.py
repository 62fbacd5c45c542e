"""The beam plant's interface: same observations, torque input and failure mode as the PRB plant."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import softpend  # noqa: F401  (registers the environments)
from softpend.plant import Observation, PRBPlant, RodParams, SimulationDiverged, make_plant, plant_names
from softpend.plant.base import SolverFailure
from softpend.plant.beam import BeamPlant
from softpend.task import Task


def test_registry_and_state_layout():
    assert "beam" in plant_names()
    plant = make_plant("beam", params=RodParams(), dt_s=0.01, substeps=2, n_elements=6)
    assert isinstance(plant, BeamPlant)
    assert plant.n_coordinates == 1 + 3 * 6
    q, qd = plant.hanging_state()
    observation = plant.reset(q, qd)
    assert isinstance(observation, Observation)
    assert observation.ey_m == pytest.approx(-0.3)
    assert abs(observation.phi_rad) == pytest.approx(math.pi)
    assert plant.link_points_m().shape == (7, 2)
    np.testing.assert_allclose(plant.link_points_m()[-1], [observation.ex_m, observation.ey_m], atol=1e-12)
    locked = BeamPlant(n_elements=4, hub_locked_at_rad=0.3)
    assert locked.n_coordinates == 12
    assert locked.observe().phi_rad == pytest.approx(0.3)
    assert locked.observe().theta_rad == pytest.approx(0.3)


def test_state_round_trip_and_rigid_rotation():
    plant = BeamPlant(n_elements=5)
    rng = np.random.default_rng(0)
    q = rng.normal(scale=0.01, size=plant.n_coordinates)
    q[0] = 2.0
    qd = rng.normal(scale=0.1, size=plant.n_coordinates)
    plant.reset(q, qd)
    q2, qd2 = plant.joint_state()
    np.testing.assert_allclose(q2, q, atol=1e-12)
    np.testing.assert_allclose(qd2, qd, atol=1e-12)
    # a rigid rotation at 2 rad/s: kinetic energy of hub + rod + tip about the axis, tip speed 2 L
    p = plant.params
    q, qd = plant.hanging_state()
    qd[0] = 2.0
    observation = plant.reset(q, qd)
    inertia = (
        p.hub_inertia_kgm2
        + p.mass_kg * p.length_m**2 / 3
        + p.mass_kg * p.depth_m**2 / 12
        + p.tip_mass_kg * p.length_m**2
    )
    assert plant.energy_j()["kinetic_j"] == pytest.approx(0.5 * inertia * 4.0, rel=1e-9)
    assert math.hypot(observation.ex_dot_m_s, observation.ey_dot_m_s) == pytest.approx(2.0 * p.length_m)
    assert observation.theta_dot_rad_s == pytest.approx(2.0)


def test_energy_conserved_without_damping():
    params = RodParams(joint_damping_nms_per_rad=0.0, hub_friction_nms_per_rad=0.0)
    plant = BeamPlant(
        params, dt_s=0.002, substeps=1, n_elements=6, spectral_radius=1.0, newton_relative_tolerance=1e-10
    )
    q, qd = plant.hanging_state()
    q[0] = math.pi - 1.2
    plant.reset(q, qd)
    start = plant.energy_j()
    kinetic = []
    for _ in range(400):
        plant.step(0.0)
        kinetic.append(plant.energy_j()["kinetic_j"])
    end = plant.energy_j()
    assert max(kinetic) > 0.05  # it really swung (about 0.08 J at the bottom)
    assert end["total_j"] == pytest.approx(start["total_j"], abs=1e-3 * max(kinetic))
    # and with the default damping it loses energy
    damped = BeamPlant(RodParams(), dt_s=0.002, substeps=1, n_elements=6)
    damped.reset(q, qd)
    for _ in range(400):
        damped.step(0.0)
    assert damped.energy_j()["total_j"] < start["total_j"] - 0.01 * max(kinetic)


def test_torque_is_clipped_and_drives_the_hub():
    plant = BeamPlant(n_elements=4)
    plant.reset(*plant.hanging_state())
    plant.step(10.0)
    assert plant.last_torque_nm == pytest.approx(plant.params.torque_limit_nm)
    for _ in range(20):
        observation = plant.step(10.0)
    assert observation.phi_dot_rad_s > 0.1  # counter-clockwise torque turns the hub counter-clockwise
    with pytest.raises(ValueError, match="torque_nm"):
        plant.step(math.nan)


def test_same_motion_as_fine_prb_chain():
    """Both plants swing the same rod: after 1 s of the same torque their tips agree to 1 % of L."""
    params = RodParams(n_links=12)
    torque = 0.05 * np.sin(2 * math.pi * 1.0 * np.arange(100) * 0.01)
    tips = []
    for plant in (BeamPlant(params), PRBPlant(params)):
        plant.reset(*plant.hanging_state())
        for t in torque:
            observation = plant.step(float(t))
        tips.append((observation.ex_m, observation.ey_m))
    assert abs(tips[0][0]) > 0.03  # a real swing
    assert math.dist(*tips) < 0.01 * params.length_m


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(n_elements=0), "n_elements"),
        (dict(dt_s=-0.01), "dt_s"),
        (dict(substeps=0), "substeps"),
        (dict(params=RodParams(stiffness_scale=0.0)), "stiffness_scale"),
        (dict(hub_locked_at_rad=math.inf), "hub_locked_at_rad"),
        (dict(spectral_radius=1.5), "spectral_radius"),
    ],
)
def test_bad_input_raises(kwargs, name):
    with pytest.raises(ValueError, match=name):
        BeamPlant(**kwargs)


def test_bad_state_raises():
    plant = BeamPlant(n_elements=3)
    with pytest.raises(ValueError, match="joint_angles_rad"):
        plant.reset(np.zeros(3))


def test_solver_failure_becomes_simulation_diverged(monkeypatch):
    plant = BeamPlant(n_elements=3)

    def fail():
        raise SolverFailure("Newton did not converge")

    monkeypatch.setattr(plant, "advance", fail)
    with pytest.raises(SimulationDiverged, match="Newton"):
        plant.step(0.0)


def test_env_on_the_beam():
    env = gym.make("softpend/SoftPendulum-v0", plant="beam")
    check_env(env.unwrapped, skip_render_check=True)
    observation, info = env.reset(seed=3)
    prb = gym.make("softpend/SoftPendulum-v0", plant="prb")
    observation_prb, info_prb = prb.reset(seed=3)
    assert observation.shape == observation_prb.shape
    assert info["observation"].shape == info_prb["observation"].shape
    np.testing.assert_allclose(observation[:6], observation_prb[:6], atol=1e-6)  # same hanging start draw
    total = 0.0
    for _ in range(50):
        observation, reward, terminated, truncated, info = env.step(np.array([1.0], dtype=np.float32))
        total += reward
        assert env.observation_space.contains(observation)
    assert "truncation_reason" not in info
    assert math.isfinite(total)


def test_fast_swing_does_not_diverge():
    """The swing-up controller drives the beam's hub to > 10 rad/s; the solver refines its step instead
    of failing (this episode failed at t = 1.77 s with a fixed 2-substep solver)."""
    from softpend.evaluation import evaluate_controller
    from softpend.study.transfer import default_transfer_cases

    controller = default_transfer_cases()[1].make_controller()
    summary = evaluate_controller(controller, Task(plant="beam"), seeds=(0,), duration_s=2.5)
    result = summary.results[0]
    assert result.diverged is None
    assert np.abs(result.observations[:, 5]).max() > 5.0  # it really moved fast
