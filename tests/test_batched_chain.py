"""The batched torch PRB chain against the Exudyn plant: same equations, energy balance, gradients, checks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from softpend.plant import PRBPlant, RodParams
from softpend.plant.batched import (
    ROSENBROCK_SUBSTEPS,
    BatchedPRBChain,
    BatchedRodParams,
    _accelerations,
    _rosenbrock_step,
    stable_substeps,
)

DT_S = 0.01


def _rods(n_links: int) -> list[RodParams]:
    base = RodParams(n_links=n_links)
    return [
        base,
        base.replace(mass_kg=0.066, youngs_modulus_pa=43e6, tip_mass_kg=0.004, hub_friction_nms_per_rad=3e-3),
    ]


def _one_rod_with(**changes: float | list[float]) -> BatchedRodParams:
    """One default rod with some fields changed (checked again)."""
    tensors = {name: torch.tensor(np.atleast_1d(value), dtype=torch.float64) for name, value in changes.items()}
    return dataclasses.replace(BatchedRodParams.from_params(RodParams()), **tensors)


def _start(n_links: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The straight rod at rest with the hub turned and spinning (as the environments start it)."""
    q = np.zeros(n_links + 1)
    qd = np.zeros(n_links + 1)
    q[0] = np.pi + rng.uniform(-0.5, 0.5)
    qd[0] = rng.uniform(-2.0, 2.0)
    return q, qd


def _exudyn_hub(params: RodParams, q0, qd0, torques_nm, substeps: int) -> np.ndarray:
    plant = PRBPlant(params, dt_s=DT_S, substeps=substeps)
    plant.reset(q0, qd0)
    hub = []
    for torque in torques_nm:
        plant.step(torque)
        hub.append(plant.joint_state()[0][0])
    return np.array(hub)


def _exudyn_reference(params, q0, qd0, torques_nm) -> np.ndarray:
    """Converged Exudyn hub angles: Richardson extrapolation of 100 and 200 generalised-alpha sub-steps per
    10 ms (the method is second order; the two runs' extrapolation differs from 200 sub-steps by ~1e-6 rad)."""
    coarse = _exudyn_hub(params, q0, qd0, torques_nm, 100)
    fine = _exudyn_hub(params, q0, qd0, torques_nm, 200)
    return (4 * fine - coarse) / 3


def _batched_hub(rods, starts, torques_nm, substeps=None, integrator="rk4") -> tuple[np.ndarray, BatchedPRBChain]:
    chain = BatchedPRBChain(BatchedRodParams.from_params(rods), dt_s=DT_S, substeps=substeps, integrator=integrator)
    q = torch.tensor(np.array([s[0] for s in starts]))
    qd = torch.tensor(np.array([s[1] for s in starts]))
    qs, _ = chain.rollout(q, qd, torch.tensor(torques_nm).T)
    return qs[:, :, 0].numpy().T, chain


@pytest.mark.parametrize("n_links", [4, 10])
def test_hub_angle_matches_converged_exudyn_plant_over_one_second(n_links: int) -> None:
    rng = np.random.default_rng(n_links)
    rods = _rods(n_links)
    starts = [_start(n_links, rng) for _ in rods]
    torques = rng.uniform(-1.2, 1.2, (len(rods), 100)) * np.array([[r.torque_limit_nm] for r in rods])  # some saturate
    batched, _ = _batched_hub(rods, starts, torques, substeps=20)
    for i, rod in enumerate(rods):
        reference = _exudyn_reference(rod, *starts[i], torques[i])
        error = np.abs(batched[i] - reference).max()
        assert error < 1e-6, f"rod {i}: hub angle differs from Exudyn by {error:.2e} rad"
        assert np.ptp(reference) > 0.1  # the rod really moved


@pytest.mark.parametrize(
    "n_links, integrator, factor", [(4, "rk4", 10), (4, "rosenbrock", 1.5), (10, "rosenbrock", 1.5)]
)
def test_default_substeps_are_more_accurate_than_the_default_exudyn_plant(
    n_links: int, integrator: str, factor: float
) -> None:
    """With its default sub-steps each integrator's hub angle is closer to the converged plant than the default
    Exudyn plant's (RK4 ten times closer at n = 4; Rosenbrock, two sub-steps, at least 1.5 times)."""
    rng = np.random.default_rng(7)
    rod = RodParams(n_links=n_links)
    start = _start(n_links, rng)
    torques = rng.uniform(-1, 1, (1, 100)) * rod.torque_limit_nm
    reference = _exudyn_reference(rod, *start, torques[0])
    batched, chain = _batched_hub([rod], [start], torques, integrator=integrator)
    if integrator == "rk4":
        assert chain.substeps == stable_substeps(rod, DT_S) == 2
    else:
        assert chain.substeps == ROSENBROCK_SUBSTEPS == 2
    exudyn_default = _exudyn_hub(rod, *start, torques[0], substeps=2)
    batched_error = np.abs(batched[0] - reference).max()
    exudyn_error = np.abs(exudyn_default - reference).max()
    assert batched_error < exudyn_error / factor, (batched_error, exudyn_error)


def test_rosenbrock_converges_at_second_order_to_the_rk4_chain() -> None:
    rng = np.random.default_rng(4)
    rods = _rods(4)
    starts = [_start(4, rng) for _ in rods]
    torques = rng.uniform(-1, 1, (len(rods), 60)) * 0.06
    reference, _ = _batched_hub(rods, starts, torques, substeps=20)  # within 1e-7 rad of the converged plant
    errors = [
        np.abs(_batched_hub(rods, starts, torques, substeps=k, integrator="rosenbrock")[0] - reference).max()
        for k in (8, 16, 32)
    ]
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(3.5 < r < 4.5 for r in ratios), (errors, ratios)
    assert errors[-1] < 1e-4


def test_rosenbrock_is_stable_where_rk4_diverges() -> None:
    """One sub-step per 10 ms at n = 10: far beyond RK4's stability limit (14 sub-steps); the linearly implicit
    method stays finite and bounded."""
    rods = _rods(10)
    torques = torch.tensor(np.random.default_rng(0).uniform(-0.06, 0.06, (200, len(rods))))
    results = {}
    for integrator in ("rk4", "rosenbrock"):
        chain = BatchedPRBChain(BatchedRodParams.from_params(rods), substeps=1, integrator=integrator)
        q, qd = chain.hanging_state()
        with torch.no_grad():
            results[integrator] = chain.rollout(q, qd, torques)
    assert not torch.isfinite(results["rk4"][0]).all()
    q, qd = results["rosenbrock"]
    assert torch.isfinite(q).all() and qd.abs().max() < 100.0


def test_compiled_chain_equals_the_eager_one_and_differentiates_eagerly() -> None:
    rods = BatchedRodParams.from_params(_rods(4))
    # one sub-step: the compiled graph unrolls the sub-step loop, and its C++ build time grows with it
    eager = BatchedPRBChain(rods, integrator="rosenbrock", substeps=1)
    compiled = BatchedPRBChain(rods, integrator="rosenbrock", substeps=1, compiled=True)
    q, qd = eager.hanging_state()
    q[:, 0] -= torch.tensor([0.3, 1.2], dtype=torch.float64)
    torques = torch.tensor([[0.06, -0.02]] * 20, dtype=torch.float64)
    with torch.no_grad():
        for a, b in zip(eager.rollout(q, qd, torques), compiled.rollout(q, qd, torques)):
            np.testing.assert_allclose(b.numpy(), a.numpy(), rtol=1e-12, atol=1e-12)
    assert compiled._compiled_integrate is not None
    mass = torch.tensor([0.058, 0.066], dtype=torch.float64, requires_grad=True)
    grads = []
    for chain in (eager, compiled):
        chain.set_params(dataclasses.replace(rods, mass_kg=mass))
        (grad,) = torch.autograd.grad(chain.step(q, qd, torques[0])[0].sum(), mass)
        grads.append(grad)
    torch.testing.assert_close(grads[1], grads[0], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("n_links", [1, 4, 10])
def test_energy_and_observations_equal_the_exudyn_plant_on_random_states(n_links: int) -> None:
    rng = np.random.default_rng(3)
    rods = _rods(n_links)
    chain = BatchedPRBChain(BatchedRodParams.from_params(rods), substeps=1)
    q = rng.uniform(-3, 3, (len(rods), n_links + 1))
    qd = rng.uniform(-5, 5, (len(rods), n_links + 1))
    energies = chain.energy_j(torch.tensor(q), torch.tensor(qd))
    observations = chain.observations(torch.tensor(q), torch.tensor(qd)).numpy()
    for i, rod in enumerate(rods):
        plant = PRBPlant(rod)
        expected = plant.energy_j(q[i], qd[i])
        for key, value in expected.items():
            assert float(energies[key][i]) == pytest.approx(value, rel=1e-12, abs=1e-14), key
        np.testing.assert_allclose(
            observations[i], plant.observation_from_state(q[i], qd[i]).as_array(), rtol=1e-12, atol=1e-13
        )


def _step_with_work(chain: BatchedPRBChain, q, qd, torque):
    """One control step of ``chain`` and the motor work and the dissipated energy over it [J] (RK4's stages, or the
    trapezoidal rule for Rosenbrock)."""
    d, h = chain._d, chain.dt_s / chain.substeps
    x, v = chain._absolute_state(q, qd)
    torque = chain._check_torque(torque)

    def powers(v):
        dissipated = d.hub_friction_nms_per_rad * v[0] ** 2 + (d.damping_nms_per_rad * (v[1:] - v[:-1]) ** 2).sum(0)
        return torque * v[0], dissipated

    work_in = work_out = torch.zeros_like(torque)
    for _ in range(chain.substeps):
        if chain.integrator == "rosenbrock":
            x_next, v_next = _rosenbrock_step(d, x, v, torque, h)
            p = [powers(v), powers(v_next)]
            work_in = work_in + (h / 2) * (p[0][0] + p[1][0])
            work_out = work_out + (h / 2) * (p[0][1] + p[1][1])
            x, v = x_next, v_next
            continue
        a1 = _accelerations(d, x, v, torque)
        x2, v2 = torch.add(x, v, alpha=h / 2), torch.add(v, a1, alpha=h / 2)
        a2 = _accelerations(d, x2, v2, torque)
        x3, v3 = torch.add(x, v2, alpha=h / 2), torch.add(v, a2, alpha=h / 2)
        a3 = _accelerations(d, x3, v3, torque)
        x4, v4 = torch.add(x, v3, alpha=h), torch.add(v, a3, alpha=h)
        a4 = _accelerations(d, x4, v4, torque)
        p = [powers(vv) for vv in (v, v2, v3, v4)]
        work_in = work_in + (h / 6) * (p[0][0] + 2 * p[1][0] + 2 * p[2][0] + p[3][0])
        work_out = work_out + (h / 6) * (p[0][1] + 2 * p[1][1] + 2 * p[2][1] + p[3][1])
        x = torch.add(x, torch.add(torch.add(v + v4, v2, alpha=2.0), v3, alpha=2.0), alpha=h / 6)
        v = torch.add(v, torch.add(torch.add(a1 + a4, a2, alpha=2.0), a3, alpha=2.0), alpha=h / 6)
    return chain._relative(x), chain._relative(v), work_in, work_out


@pytest.mark.parametrize(
    "integrator, substeps, tolerance",
    [("rk4", 20, 1e-7), ("rk4", None, 2e-2), ("rosenbrock", 32, 3e-4), ("rosenbrock", None, 6e-2)],
)
def test_energy_change_equals_motor_work_minus_dissipation(integrator: str, substeps, tolerance: float) -> None:
    """Energy balance over 1 s of random torque; with the default sub-steps both integrators damp the stiffest
    bending mode numerically, which shows as a residual below 1 % (RK4) or 6 % (Rosenbrock, L-stable) of the
    dissipated energy; with more sub-steps the residual vanishes at each method's order."""
    rng = np.random.default_rng(11)
    rods = _rods(4)
    chain = BatchedPRBChain(BatchedRodParams.from_params(rods), substeps=substeps, integrator=integrator)
    starts = [_start(4, rng) for _ in rods]
    q = torch.tensor(np.array([s[0] for s in starts]))
    qd = torch.tensor(np.array([s[1] for s in starts]))
    e0 = chain.energy_j(q, qd)["total_j"]
    work = torch.zeros(len(rods), dtype=torch.float64)
    dissipated = torch.zeros_like(work)
    for _ in range(100):
        torque = torch.tensor(rng.uniform(-1, 1, len(rods)) * 0.06)
        q, qd, w_in, w_out = _step_with_work(chain, q, qd, torque)
        work, dissipated = work + w_in, dissipated + w_out
    change = chain.energy_j(q, qd)["total_j"] - e0
    assert torch.all(dissipated > 1e-3) and torch.all(work.abs() > 1e-4)
    residual = (change - (work - dissipated)).abs()
    assert torch.all(residual < tolerance * dissipated), (residual, dissipated)


def test_torque_saturates_at_each_rods_limit() -> None:
    rods = [RodParams(n_links=3), RodParams(n_links=3, torque_limit_nm=0.03)]
    chain = BatchedPRBChain(BatchedRodParams.from_params(rods))
    q, qd = chain.hanging_state()
    big = chain.step(q, qd, torch.tensor([5.0, -5.0]))
    exact = chain.step(q, qd, torch.tensor([0.06, -0.03], dtype=torch.float64))
    assert torch.equal(big[0], exact[0]) and torch.equal(big[1], exact[1])


@pytest.mark.parametrize("integrator", ["rk4", "rosenbrock"])
def test_gradients_match_finite_differences(integrator: str) -> None:
    rod = RodParams(n_links=2)
    base = BatchedRodParams.from_params(rod, batch_size=2)

    def simulate(q, qd, torque, mass_kg, youngs_modulus_pa):
        params = dataclasses.replace(base, mass_kg=mass_kg, youngs_modulus_pa=youngs_modulus_pa)
        chain = BatchedPRBChain(params, dt_s=0.005, substeps=2, integrator=integrator)
        q1, qd1 = chain.step(q, qd, torque)
        q2, qd2 = chain.step(q1, qd1, -torque)
        return torch.cat([q2, qd2], dim=1)

    rng = np.random.default_rng(0)
    inputs = (
        torch.tensor(rng.uniform(-1, 1, (2, 3)), requires_grad=True),
        torch.tensor(rng.uniform(-1, 1, (2, 3)), requires_grad=True),
        torch.tensor([0.02, -0.01], dtype=torch.float64, requires_grad=True),
        torch.tensor([0.058, 0.05], dtype=torch.float64, requires_grad=True),
        torch.tensor([50e6, 40e6], dtype=torch.float64, requires_grad=True),
    )
    assert torch.autograd.gradcheck(simulate, inputs, eps=1e-7, atol=1e-6, rtol=1e-4)


def test_stable_substeps_grow_with_the_number_of_links() -> None:
    assert stable_substeps(RodParams(n_links=4)) == 2
    assert stable_substeps(RodParams(n_links=10)) > stable_substeps(RodParams(n_links=6)) > 2


@pytest.mark.parametrize(
    "build, name",
    [
        (lambda: _one_rod_with(mass_kg=-1.0), "mass_kg"),
        (lambda: _one_rod_with(hub_inertia_kgm2=0.0), "hub_inertia_kgm2"),
        (lambda: _one_rod_with(joint_damping_nms_per_rad=float("nan")), "joint_damping_nms_per_rad"),
        (lambda: _one_rod_with(mass_kg=[0.05, 0.06]), "mass_kg has shape"),
        (lambda: BatchedRodParams.from_params(RodParams(), batch_size=0), "batch_size"),
        (lambda: BatchedRodParams.from_params([RodParams(n_links=3), RodParams(n_links=4)]), "n_links"),
        (lambda: BatchedPRBChain(RodParams(), dt_s=0.0), "dt_s"),
        (lambda: BatchedPRBChain(RodParams(), substeps=0), "substeps"),
        (lambda: BatchedPRBChain(RodParams(), integrator="euler"), "integrator"),
        (lambda: BatchedPRBChain(RodParams(), compiled="yes"), "compiled"),
        (
            lambda: BatchedPRBChain(RodParams(), batch_size=2).step(torch.zeros(2, 4), torch.zeros(2, 5), 0.0),
            "joint_angles_rad",
        ),
        (
            lambda: BatchedPRBChain(RodParams(), batch_size=2).step(
                torch.zeros(2, 5), torch.zeros(2, 5), [0.0, float("nan")]
            ),
            "torque_nm",
        ),
        (
            lambda: BatchedPRBChain(RodParams(), batch_size=2).step(
                torch.zeros(2, 5), torch.zeros(2, 5), [0.0, 0.0, 0.0]
            ),
            "torque_nm",
        ),
    ],
)
def test_bad_input_raises_value_error_naming_the_parameter(build, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        build()
