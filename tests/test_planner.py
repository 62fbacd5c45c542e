"""The MPPI planner on learned dynamics: MPPI on a linear-quadratic problem, the fast ensemble, the counted plant
seconds, fresh starts, and its settings."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
import torch

from softpend.control.lqr import LQRController
from softpend.control.planner import (
    MPPI,
    PlannerConfig,
    PlannerController,
    StackedEnsemble,
    fit_ensemble,
    fresh_start_evaluation,
    run_planner,
)
from softpend.plant import PRBPlant, RodParams
from softpend.study.data_efficiency import planner_config
from softpend.task import Task


def test_mppi_recovers_the_lqr_action_of_a_linear_system():
    dt = 0.1
    a = np.array([[1.0, dt], [0.0, 1.0]])
    b = np.array([[0.0], [dt]])
    q, r = np.diag([1.0, 0.1]), 0.5
    p = scipy.linalg.solve_discrete_are(a, b, q, r)
    gain = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
    x0 = np.array([0.2, -0.1])
    at, bt, qt, pt = (torch.as_tensor(m, dtype=torch.float32) for m in (a, b, q, p))

    def step_fn(x: torch.Tensor, torque: torch.Tensor) -> torch.Tensor:
        return x @ at.T + torque[:, None] * bt.T

    def cost_fn(x: torch.Tensor, torque: torch.Tensor, x_next: torch.Tensor) -> torch.Tensor:
        # x_k' Q x_k + r u_k^2 plus x_{k+1}' P x_{k+1} - x_k' P x_k: summed over k = 0..T-1, the stage costs plus the
        # Riccati terminal cost x_T' P x_T less x_0' P x_0 (the same for every rollout)
        quadratic = lambda y, m: ((y @ m) * y).sum(-1)  # noqa: E731
        return quadratic(x, qt) + r * torque.float() ** 2 + quadratic(x_next, pt) - quadratic(x, pt)

    mppi = MPPI(step_fn, cost_fn, 10.0, 5, 1, 1000, 0.1, temperature=0.01, seed=2)
    mean = torch.zeros(1, 5, dtype=torch.float64)
    for _ in range(30):
        mean = mppi.finish(mppi.begin(x0[None], mean))
    torque = float(mean[0, 0])
    expected = float(-(gain @ x0)[0])
    assert torque == pytest.approx(expected, rel=0.05, abs=0.005)


def test_mppi_keeps_its_mean_where_every_rollout_diverges():
    def step_fn(x: torch.Tensor, torque: torch.Tensor) -> torch.Tensor:
        return torch.where(x[:, :1] > 0, torch.full_like(x, math.nan), x + torque[:, None])  # start 0 diverges

    mppi = MPPI(step_fn, lambda x, u, x_next: x_next[:, 0] ** 2, 1.0, 3, 1, 8, 0.3, temperature=0.1)
    mean = torch.tensor([[0.2, -0.1, 0.3], [0.2, -0.1, 0.3]], dtype=torch.float64)
    out = mppi.finish(mppi.begin(np.array([[1.0], [-1.0]]), mean))
    assert torch.equal(out[0], mean[0])  # no finite rollout: the unperturbed sequence
    assert torch.isfinite(out).all() and not torch.equal(out[1], mean[1])


def test_the_joint_state_tracker_reconstructs_as_the_training_data_does():
    from softpend.control.planner import JointStateTracker, joint_states
    from softpend.envs import SoftPendulumEnv

    task = Task()
    env = SoftPendulumEnv(**task.env_kwargs())
    env.reset(seed=5)
    rng = np.random.default_rng(5)
    observations = [env.report_observation.as_array()]
    for _ in range(150):
        env.step(np.array([rng.uniform(-1.0, 1.0)]))
        observations.append(env.report_observation.as_array())
    tracker = JointStateTracker(task.rod, task.dt_s)
    tracked = np.concatenate([tracker(o[None]) for o in observations])
    positions = np.array(observations)[:, :5]
    pairs = [joint_states(positions[k - 1 : k + 1], task.rod, task.dt_s)[0] for k in range(1, len(positions))]
    assert np.allclose(tracked[1:], np.array(pairs), atol=1e-6)
    assert np.ptp(tracked[:, 1:5]) > 0.05  # the springs did bend


class _Identity:
    def reset(self) -> None:
        pass

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        return observations


@pytest.mark.parametrize("knots_per_plan", [1, 2])
def test_the_controller_spreads_each_plan_over_its_knots_and_holds_its_torques_for_the_next_ones(knots_per_plan):
    # a plan of c committed + 4 planned knots of 2 model steps, spread over the c knots' 5 c calls
    c, hold, planned = knots_per_plan, 5, 4
    calls: list[int] = []

    def step_fn(x: torch.Tensor, torque: torch.Tensor) -> torch.Tensor:
        calls[-1] += 1
        return x + 0.01 * torque[:, None]

    def cost_fn(x: torch.Tensor, torque: torch.Tensor, x_next: torch.Tensor) -> torch.Tensor:
        return (x_next[:, 1] - 10.0) ** 2

    def make_mppi() -> MPPI:
        return MPPI(step_fn, cost_fn, 0.5, planned, hold_steps=2, n_samples=16, noise_std_nm=0.2, temperature=0.01)

    lqr = LQRController.from_params(RodParams(), dt_s=0.01, state="observation", torque_limit_nm=0.5)
    controller = PlannerController(make_mppi(), _Identity(), lqr, 0.4, hold, knots_per_plan=c)
    observation = np.zeros((1, 10))
    observation[0, 1] = math.pi  # hanging: far from the LQR's region
    torques = []
    for k in range(3 * hold * c):
        calls.append(0)
        torques.append(float(controller.torques(observation, k * 0.01)[0]))
    steps = (c + planned) * 2
    assert sum(calls) == 3 * steps and max(calls) == -(-steps // (hold * c))  # each call its share, never more
    assert torques[: hold * c] == [0.0] * hold * c  # no plan is ready during the first stretch
    knots = [torques[i : i + hold] for i in range(hold * c, len(torques), hold)]
    assert all(len(set(knot)) == 1 for knot in knots)  # a planned torque held for its knot
    # the same plans made at once: from the start under the torques committed for the stretch, warm-started
    calls.append(0)
    mppi, mean, held = make_mppi(), torch.zeros(1, planned, dtype=torch.float64), np.zeros((1, c))
    for plan in range(2):
        mean = mppi.finish(mppi.begin(observation, mean, held))
        padded = torch.cat([mean, mean[:, -1:].expand(-1, c)], dim=1)
        held, mean = padded[:, :c].numpy(), padded[:, c : c + planned]
        applied = [knot[0] for knot in knots[plan * c : (plan + 1) * c]]
        assert held[0].tolist() == pytest.approx(applied, abs=1e-12) and max(map(abs, applied)) <= 0.5


def _data(n: int = 200, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    states = np.concatenate([rng.uniform(-0.3, 0.3, (n, 5)), rng.normal(0, 1, (n, 5))], axis=1)
    states[:, 2], states[:, 3] = -0.3 * np.sin(states[:, 1]), 0.3 * np.cos(states[:, 1])
    return states, rng.uniform(-0.06, 0.06, n), states + 0.01 * rng.normal(size=(n, 10))


def test_stacked_ensemble_predicts_as_its_members_row_by_row():
    config = PlannerConfig(ensemble_size=3, hidden_width=8, train_steps=5, n_samples=6)
    ensemble = fit_ensemble(*_data(), Task(), config)
    states, torques, _ = _data(6, seed=1)
    x, u = torch.as_tensor(states, dtype=torch.float32), torch.as_tensor(torques, dtype=torch.float32)
    with torch.no_grad():
        fast = StackedEnsemble(ensemble).predict_next(x, u)
        for i in range(6):
            member = ensemble.predict_next(x[i : i + 1], u[i : i + 1], member=i % 3)
            assert torch.allclose(fast[i], member[0], atol=1e-5)


TINY = dict(
    identify_windows=0,
    excitation_s=0.5,
    trial_s=0.3,
    hold_s=0.2,
    max_trials=2,
    ensemble_size=2,
    hidden_width=8,
    train_steps=5,
    horizon_s=0.15,
    control_dt_s=0.05,
    n_samples=4,
    selection_seeds=(1000, 1001),
)


@pytest.mark.parametrize("model", ["ensemble", "residual"])
def test_counted_plant_seconds_are_the_seconds_the_plant_was_stepped(model, monkeypatch):
    steps = []
    original = PRBPlant.step

    def counted(self, torque_nm):
        steps.append(self.dt_s)
        return original(self, torque_nm)

    monkeypatch.setattr(PRBPlant, "step", counted)
    result = run_planner(PlannerConfig(model=model, **TINY))
    assert len(result.records) == 3  # the excitation and two trials that did not balance
    assert result.plant_seconds == pytest.approx(sum(steps))
    assert result.plant_seconds == pytest.approx(sum(r.plant_s for r in result.records))
    assert result.records[0].plant_s == pytest.approx(0.5)
    assert not result.balanced and math.isinf(result.plant_seconds_to_balance)


def test_trials_start_from_selection_seeds_and_fresh_starts_must_be_disjoint():
    result = run_planner(PlannerConfig(**TINY))
    assert [r.start_seed for r in result.records[1:]] == [1000, 1001]
    with pytest.raises(ValueError, match="selection_seeds"):
        fresh_start_evaluation(result, [20_000, 1001])
    summary = fresh_start_evaluation(result, [20_000, 20_001], duration_s=0.2)
    assert [r.seed for r in summary.results] == [20_000, 20_001]


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"model": "gp"}, "model"),
        ({"excitation_program": "chirp"}, "excitation_program"),
        ({"n_samples": 7}, "n_samples"),
        ({"control_dt_s": 0.015}, "control_dt_s"),
        ({"horizon_s": 0.1}, "horizon_s"),
        ({"hold_s": 20.0}, "hold_s"),
        ({"selection_seeds": ()}, "selection_seeds"),
        ({"capture_rad": -0.1}, "capture_rad"),
        ({"ensemble_size": 0}, "ensemble_size"),
        ({"temperature": 0.0}, "temperature"),
    ],
)
def test_bad_settings_are_refused_naming_the_field(changes, field):
    with pytest.raises(ValueError, match=field):
        PlannerConfig(**changes)


def test_settings_file_is_read_and_checked(tmp_path):
    config = planner_config(Task())
    assert len([f for f in config.__dataclass_fields__]) <= 20
    bad = tmp_path / "planner.yml"
    bad.write_text("horizon_seconds: 1.0\n")
    with pytest.raises(ValueError, match="planner.yml: 'horizon_seconds' is not a PlannerConfig setting"):
        planner_config(Task(), hparams=bad)
