"""Linearisation about upright: Exudyn vs the hand derivation (n = 1), vs the simulator's step map, the
observation-coordinate condensation, and autograd linearisation of a learned model."""

import numpy as np
import pytest
import torch

from softpend.control.linearise import (
    LinearModel,
    SecondOrderModel,
    discretise,
    linearise_exudyn,
    observation_coordinates_matrix,
    reduce_to_observation_coordinates,
)
from softpend.control.lqr import LQRController
from softpend.plant import PRBPlant, RodParams
from softpend.task import Task


def linearise_step_map(params: RodParams, dt_s: float = 0.01, substeps: int = 2) -> LinearModel:
    """Discrete model from central differences of one control step of the PRB plant about upright at rest."""
    state_step, torque_step_nm = 1e-6, 1e-5
    plant = PRBPlant(params, dt_s=dt_s, substeps=substeps)
    n = plant.n_coordinates

    def step(x: np.ndarray, torque: float) -> np.ndarray:
        plant.reset(x[:n], x[n:])
        plant.step(torque)
        return np.concatenate(plant.joint_state())

    a = np.column_stack([(step(e, 0.0) - step(-e, 0.0)) / (2 * state_step) for e in state_step * np.eye(2 * n)])
    zero = np.zeros(2 * n)
    b = (step(zero, torque_step_nm) - step(zero, -torque_step_nm)) / (2 * torque_step_nm)
    return LinearModel(a=a, b=b.reshape(-1, 1), dt_s=float(dt_s))


def _unstable(eig: np.ndarray) -> float:
    return float(np.max(np.abs(eig)) if np.iscomplexobj(eig) else np.max(eig))


def analytic_linearisation_one_link(params: RodParams) -> SecondOrderModel:
    """Hand derivation for ``n_links = 1``: ``T = J phi_d^2/2 + I_O (phi_d + q1_d)^2/2``,
    ``V = m g c cos(phi + q_1) + k q_1^2/2``, linearised about upright."""
    length = params.length_m
    m_rod, m_tip = params.mass_kg, params.tip_mass_kg
    m = m_rod + m_tip
    c = (m_rod * length / 2 + m_tip * length) / m
    inertia_axis = m_rod * length**2 / 3 + m_tip * length**2
    k = params.spring_stiffnesses_nm_per_rad()[0]
    d = params.spring_dampings_nms_per_rad()[0]
    mgc = m * params.gravity_mps2 * c
    mass = np.array([[params.hub_inertia_kgm2 + inertia_axis, inertia_axis], [inertia_axis, inertia_axis]])
    stiffness = np.array([[-mgc, -mgc], [-mgc, k - mgc]])
    damping = np.diag([params.hub_friction_nms_per_rad, d])
    return SecondOrderModel(mass, stiffness, damping, np.array([1.0, 0.0]))


def test_exudyn_matches_analytic_one_link():
    params = RodParams(n_links=1)
    exu_model = linearise_exudyn(params)
    hand = analytic_linearisation_one_link(params)
    for name in ("mass", "stiffness", "damping", "input_vector"):
        np.testing.assert_allclose(getattr(exu_model, name), getattr(hand, name), rtol=1e-9, atol=1e-12, err_msg=name)
    # the upright rod is unstable: exactly one eigenvalue in the right half-plane, at sqrt(m g c / I) scale
    eig = hand.state_space().eigenvalues()
    assert np.sum(eig.real > 0) == 1


def test_step_map_matches_exudyn_one_link():
    params = RodParams(n_links=1)
    zoh = discretise(linearise_exudyn(params).state_space(), 0.01)
    step = linearise_step_map(params, dt_s=0.01)
    np.testing.assert_allclose(step.a, zoh.a, atol=0.01 * np.abs(zoh.a).max())
    np.testing.assert_allclose(step.b, zoh.b, rtol=0.01, atol=0.01 * np.abs(zoh.b).max())


def test_step_map_matches_exudyn_default_rod_slow_modes():
    params = RodParams()
    zoh = discretise(linearise_exudyn(params).state_space(), 0.01)
    step = linearise_step_map(params, dt_s=0.01)
    # the unstable (falling) mode and the slowest stable mode agree; the fast bending modes are where
    # the implicit integrator (2 sub-steps, numerical damping) differs from the exact ZOH map
    z, s = np.sort(np.abs(zoh.eigenvalues())), np.sort(np.abs(step.eigenvalues()))
    assert z[-1] > 1.05 and abs(s[-1] - z[-1]) < 1e-3
    # hub response to the torque over one step
    assert step.b[0, 0] == pytest.approx(zoh.b[0, 0], rel=0.03)
    # the gain designed on Exudyn's matrices also stabilises the step map (another linearisation of the plant)
    gain = LQRController.from_params(params).gain.reshape(1, -1)
    assert np.max(np.abs(np.linalg.eigvals(step.a - step.b @ gain))) < 1.0
    n = params.n_links + 1
    assert step.b[n, 0] == pytest.approx(zoh.b[n, 0], rel=0.03)


def test_observation_matrix_matches_plant_kinematics():
    params = RodParams()
    plant = PRBPlant(params)
    c = observation_coordinates_matrix(params)
    q = 1e-6 * np.array([1.0, -2.0, 0.5, 3.0, -1.0])
    o = plant.observation_from_state(q, np.zeros_like(q))
    np.testing.assert_allclose(c @ q, [o.phi_rad, o.theta_rad, o.er_rad], rtol=1e-5, atol=1e-12)


def test_condensation_keeps_the_unstable_mode():
    params = RodParams()
    full = linearise_exudyn(params)
    reduced, shape, names = reduce_to_observation_coordinates(full, params)
    assert names == ("phi_rad", "theta_rad", "er_rad")
    np.testing.assert_allclose(observation_coordinates_matrix(params) @ shape, np.eye(3), atol=1e-9)
    full_eig = full.state_space().eigenvalues()
    red_eig = reduced.state_space().eigenvalues()
    assert _unstable(red_eig.real) == pytest.approx(_unstable(full_eig.real), rel=0.01)
    # n = 1: theta and e_r coincide, so one is dropped
    _, _, names1 = reduce_to_observation_coordinates(linearise_exudyn(RodParams(n_links=1)), RodParams(n_links=1))
    assert names1 == ("phi_rad", "theta_rad")


def test_learned_linearisation_is_the_jacobian_of_the_model():
    """Autograd Jacobians equal central differences of ``predict_next`` on a real DynamicsModel."""
    from softpend.control.learned import linearise_learned_model, upright_state_vector
    from softpend.sysid.layout import StateLayout
    from softpend.sysid.model import DynamicsModel

    torch.manual_seed(0)
    model = DynamicsModel(StateLayout.full(), dt_s=0.01, torque_limit_nm=0.06).double()
    params = RodParams()
    lin = linearise_learned_model(model, params)
    x0 = upright_state_vector(model, params)
    assert x0[model.layout.index("ey_m")] == pytest.approx(params.length_m)

    def f(x, u):
        with torch.no_grad():
            return model.predict_next(
                torch.as_tensor(x).reshape(1, -1), torch.tensor([u], dtype=torch.float64)
            ).numpy()[0]

    h = 1e-6
    for i in (0, 1, 6):
        e = np.zeros_like(x0)
        e[i] = h
        np.testing.assert_allclose(lin.a[:, i], (f(x0 + e, 0.0) - f(x0 - e, 0.0)) / (2 * h), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(lin.b[:, 0], (f(x0, h) - f(x0, -h)) / (2 * h), rtol=1e-5, atol=1e-7)
    assert lin.dt_s == 0.01 and lin.state_names == model.layout.names


def test_reduction_matrices_are_consistent():
    from softpend.control.learned import reduction_matrices
    from softpend.sysid.layout import StateLayout

    params = RodParams()
    for layout in (StateLayout.full(), StateLayout.limited(2)):
        s, p, z = reduction_matrices(layout.names, params, 0.01)
        np.testing.assert_allclose(s @ p, np.eye(len(z)), atol=1e-12)
        assert z[:2] == ("phi_rad", "theta_rad")
        # the straight rod tilted by a small angle: ex = -L theta, lagged frames one step behind
        z0 = np.zeros(len(z))
        z0[z.index("theta_rad")] = 0.01
        z0[z.index("theta_dot_rad_s")] = 1.0
        x = p @ z0
        assert x[layout.index("ex_m")] == pytest.approx(-params.length_m * 0.01)
        assert x[layout.index("ex_dot_m_s")] == pytest.approx(-params.length_m)
        if layout.history:
            assert x[layout.index("ex_m_lag1")] == pytest.approx(-params.length_m * (0.01 - 0.01 * 1.0))


@pytest.fixture(scope="module")
def trained_model():
    from softpend.study.classical import train_learned_model

    torch.set_num_threads(1)
    return train_learned_model(n_trials=60, max_epochs=300, seed=0)


@pytest.mark.expensive
def test_learned_linearisation_agrees_with_true_model(trained_model):
    from softpend.control.learned import linearise_learned_model, reduce_learned_model

    params = RodParams()
    reduced, _ = reduce_learned_model(linearise_learned_model(trained_model, params), params)
    true = discretise(linearise_exudyn(params).state_space(), 0.01)
    assert np.max(np.abs(reduced.eigenvalues())) == pytest.approx(np.max(np.abs(true.eigenvalues())), abs=0.03)


@pytest.mark.expensive
def test_lqr_from_learned_model_stabilises_true_plant(trained_model):
    from softpend.control.learned import lqr_from_learned_model
    from softpend.evaluation import evaluate_controller

    params = RodParams()
    controller = lqr_from_learned_model(trained_model, params)
    q = np.zeros(params.n_links + 1)
    q[0] = 0.2
    result = evaluate_controller(
        controller, Task(start="upright"), seeds=(0,), duration_s=6.0, initial_state=(q, 0 * q)
    ).results[0]
    assert result.diverged is None and result.upright_std_rad < 0.02
    assert np.all(np.abs(result.theta_rad[-100:]) < 0.01)
