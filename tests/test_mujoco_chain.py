"""The MuJoCo model of the PRB chain (the benchmark's comparison) is the Exudyn plant's chain."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip(
    "mujoco",
    reason="MuJoCo is an optional benchmark dependency (pip install softpend[bench]); "
    "these checks run where it is installed",
)

from softpend.plant import RodParams  # noqa: E402
from softpend.plant.prb import PRBPlant  # noqa: E402
from softpend.study.bench import plant as mujoco_chain  # noqa: E402
from softpend.study.bench.plant import MuJoCoChain  # noqa: E402

PARAMS = RodParams(n_links=4)
#: A bent, moving start: a wrong map between the two sets of joint coordinates shows at once.
Q0 = np.array([np.pi - 0.3, 0.05, -0.03, 0.02, 0.01])
QD0 = np.array([0.5, 0.2, -0.1, 0.0, 0.1])
#: 1 s of random torque, some of it beyond the torque limit (the saturation is part of the model).
TORQUES_NM = np.random.default_rng(3).uniform(-1.2, 1.2, 100) * PARAMS.torque_limit_nm
#: Largest joint-angle difference allowed between MuJoCo with 0.25 ms RK4 steps and Exudyn with 200 sub-steps
#: (both converged to well below it: about 1e-6 rad at the hub, 5e-6 rad at the springs).
TOLERANCE_RAD = 2e-5


def _mujoco_angles(q0_mujoco: np.ndarray, substeps: int = 40, integrator: str = "RK4") -> np.ndarray:
    chain = MuJoCoChain(PARAMS, timestep_s=0.01 / substeps, integrator=integrator)
    chain.set_state(q0_mujoco, QD0)
    rows = []
    for torque in TORQUES_NM:
        chain.step(float(torque))
        rows.append(chain.data.qpos.copy())
    assert not chain.diverged
    return np.array(rows)


@pytest.fixture(scope="module")
def exudyn_angles() -> np.ndarray:
    plant = PRBPlant(PARAMS, substeps=200)
    plant.reset(Q0, QD0)
    rows = []
    for torque in TORQUES_NM:
        plant.step(float(torque))
        rows.append(plant.joint_state()[0])
    return np.array(rows)


def test_the_mujoco_chain_follows_the_converged_exudyn_plant(exudyn_angles: np.ndarray) -> None:
    error = np.abs(_mujoco_angles(Q0) - exudyn_angles).max(axis=0)
    assert error.max() < TOLERANCE_RAD, error


def _wrong_clamp_stiffness(monkeypatch: pytest.MonkeyPatch) -> np.ndarray:
    k = PARAMS.joint_stiffness_nm_per_rad
    monkeypatch.setattr(RodParams, "spring_stiffnesses_nm_per_rad", lambda self: [k] * self.n_links)
    return Q0


def _no_tip_mass(monkeypatch: pytest.MonkeyPatch) -> np.ndarray:
    monkeypatch.setattr(
        mujoco_chain,
        "link_inertials",
        lambda p: (
            np.full(p.n_links, p.link_mass_kg),
            np.full(p.n_links, p.link_length_m / 2),
            np.full(p.n_links, p.link_mass_kg * p.link_length_m**2 / 12),
        ),
    )
    return Q0


def _no_hub_friction(monkeypatch: pytest.MonkeyPatch) -> np.ndarray:
    real = mujoco_chain.chain_mjcf
    monkeypatch.setattr(
        mujoco_chain, "chain_mjcf", lambda params, *a, **k: real(params.replace(hub_friction_nms_per_rad=0.0), *a, **k)
    )
    return Q0


def _absolute_angles(monkeypatch: pytest.MonkeyPatch) -> np.ndarray:
    return np.cumsum(Q0)  # link angles from upright instead of the spring angles


@pytest.mark.parametrize("wrong", [_wrong_clamp_stiffness, _no_tip_mass, _no_hub_friction, _absolute_angles])
def test_a_wrong_model_or_state_map_fails_the_check(
    exudyn_angles: np.ndarray, monkeypatch: pytest.MonkeyPatch, wrong
) -> None:
    q0 = wrong(monkeypatch)
    error = np.abs(_mujoco_angles(q0) - exudyn_angles).max()
    assert error > 10 * TOLERANCE_RAD, error


def test_mujoco_rk4_is_the_batched_chains_rk4_to_rounding() -> None:
    """Same equations and the same method: MuJoCo's RK4 with 5 ms steps against the batched chain's RK4 with two
    sub-steps of 5 ms, from the bent start, all joint angles."""
    torch = pytest.importorskip("torch")
    from softpend.plant.batched import BatchedPRBChain

    chain = BatchedPRBChain(PARAMS, batch_size=1, substeps=2)
    with torch.no_grad():
        qs, _ = chain.rollout(torch.tensor(Q0)[None], torch.tensor(QD0)[None], torch.tensor(TORQUES_NM)[:, None])
    assert np.abs(_mujoco_angles(Q0, substeps=2) - qs[:, 0].numpy()).max() < 1e-11


def test_the_mjcf_states_the_rods_constants() -> None:
    text = mujoco_chain.chain_mjcf(PARAMS, timestep_s=0.005, integrator="implicitfast")
    k = PARAMS.joint_stiffness_nm_per_rad
    assert f'stiffness="{2 * k!r}"' in text and text.count(f'stiffness="{k!r}"') == PARAMS.n_links - 1
    assert 'integrator="implicitfast"' in text and 'ctrlrange="-0.06 0.06"' in text
    with pytest.raises(ValueError, match="integrator"):
        mujoco_chain.chain_mjcf(PARAMS, integrator="rk4")
    with pytest.raises(ValueError, match="timestep_s"):
        MuJoCoChain(PARAMS, timestep_s=0.003)


def test_the_large_steps_diverge_at_ten_links_and_are_reported_so() -> None:
    assert mujoco_chain.diverges(10, "RK4", 2, duration_s=0.1)
    assert not mujoco_chain.diverges(4, "RK4", 2, duration_s=0.1)


def test_mujoco_figures_returns_every_key(monkeypatch: pytest.MonkeyPatch) -> None:
    from softpend.study.bench.plant import hub_error_reference

    real_steps, real_rollout = mujoco_chain.steps_per_s, mujoco_chain.rollout_rod_steps_per_s
    monkeypatch.setattr(mujoco_chain, "steps_per_s", lambda *a, n_steps=0: real_steps(*a, n_steps=20, repeats=1))
    monkeypatch.setattr(
        mujoco_chain, "rollout_rod_steps_per_s", lambda *a: real_rollout(*a, batch_size=8, n_steps=2, repeats=1)
    )
    references = {4: hub_error_reference(4, duration_s=0.2), 10: hub_error_reference(10, duration_s=0.05)}
    base = {
        key: 1000.0
        for key in (
            "env_steps_per_s_n4",
            "solver_steps_per_s_n4",
            "batched_rod_steps_per_s_n4",
            "batched_rod_steps_per_s_n10",
            "batched_rk4_rod_steps_per_s_n4",
            "batched_rk4_rod_steps_per_s_n10",
        )
    }
    figures = mujoco_chain.mujoco_figures(base, references)
    expected = {
        "mujoco_rk4_5ms_steps_per_s_n4",
        "mujoco_implicitfast_2p5ms_steps_per_s_n4",
        "mujoco_rk4_stable_steps_per_s_n10",
        "mujoco_implicitfast_0p5ms_steps_per_s_n10",
        "mujoco_rk4_5ms_hub_error_rad_n4",
        "mujoco_implicitfast_2p5ms_hub_error_rad_n4",
        "mujoco_rk4_0p25ms_hub_error_rad_n4",
        "mujoco_rk4_stable_hub_error_rad_n10",
        "mujoco_implicitfast_0p5ms_hub_error_rad_n10",
        "mujoco_rk4_0p25ms_hub_error_rad_n10",
        "mujoco_rk4_5ms_diverges_n10",
        "mujoco_implicitfast_2p5ms_diverges_n10",
        "mujoco_rollout_rk4_5ms_rod_steps_per_s_n4",
        "exudyn_env_over_mujoco_rk4_n4",
        "exudyn_solver_over_mujoco_rk4_n4",
        "batched_over_mujoco_rk4_n4",
        "batched_over_mujoco_rk4_n10",
        "batched_rk4_over_mujoco_rk4_n4",
        "batched_rk4_over_mujoco_rk4_n10",
        "batched_over_mujoco_rollout_n4",
        "batched_rk4_over_mujoco_rollout_n4",
    }
    assert expected <= set(figures)
    assert all(np.isfinite(value) and value > 0 for value in figures.values()), figures
    assert figures["mujoco_rk4_5ms_diverges_n10"] == 1.0 and figures["mujoco_implicitfast_2p5ms_diverges_n10"] == 1.0
    assert figures["mujoco_rk4_0p25ms_hub_error_rad_n4"] < 1e-5
    assert figures["exudyn_env_over_mujoco_rk4_n4"] == pytest.approx(1000.0 / figures["mujoco_rk4_5ms_steps_per_s_n4"])
