"""The MPPI planner on learned dynamics: MPPI on a linear-quadratic problem, the fast ensemble, the counted plant
seconds, fresh starts, and its settings."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import torch

from softpend.control.planner import (
    MPPI,
    PlannerConfig,
    StackedEnsemble,
    fit_ensemble,
    fresh_start_evaluation,
    run_planner,
)
from softpend.plant import PRBPlant
from softpend.task import Task

HPARAMS = Path(__file__).resolve().parents[1] / "book" / "hparams" / "planner.yml"


def test_mppi_recovers_the_lqr_action_of_a_linear_system():
    dt = 0.1
    a = np.array([[1.0, dt], [0.0, 1.0]])
    b = np.array([[0.0], [dt]])
    q, r = np.diag([1.0, 0.1]), 0.5
    p = scipy.linalg.solve_discrete_are(a, b, q, r)
    gain = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
    x0 = np.array([0.2, -0.1])
    at, bt, qt, pt = (torch.as_tensor(m, dtype=torch.float32) for m in (a, b, q, p))

    def rollout_fn(x: torch.Tensor, torques: torch.Tensor) -> torch.Tensor:
        states = [x]
        for k in range(torques.shape[1]):
            states.append(states[-1] @ at.T + torques[:, k : k + 1] * bt.T)
        return torch.stack(states, dim=1)

    def cost_fn(states: torch.Tensor, torques: torch.Tensor) -> torch.Tensor:
        # x_k' Q x_k + r u_k^2 for k = 0..T-1 (states holds x_1..x_T), plus the Riccati terminal cost x_T' P x_T
        previous = torch.cat(
            [torch.as_tensor(x0, dtype=torch.float32).expand(states.shape[0], 1, 2), states[:, :-1]], 1
        )
        cost = ((previous @ qt) * previous).sum(-1) + r * torques.float() ** 2
        cost[:, -1] += ((states[:, -1] @ pt) * states[:, -1]).sum(-1)
        return cost

    mppi = MPPI(
        rollout_fn, cost_fn, 10.0, 5, 1, n_samples=1000, noise_std_nm=0.1, temperature=0.01, seed=2, iterations=30
    )
    torque = float(mppi.optimise(x0[None], torch.zeros(1, 5, dtype=torch.float64))[0, 0])
    expected = float(-(gain @ x0)[0])
    assert torque == pytest.approx(expected, rel=0.05, abs=0.005)


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
    horizon_s=0.1,
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
        ({"n_samples": 7}, "n_samples"),
        ({"control_dt_s": 0.015}, "control_dt_s"),
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
    config = PlannerConfig.from_yaml(HPARAMS)
    assert len([f for f in config.__dataclass_fields__]) <= 20
    bad = tmp_path / "planner.yml"
    bad.write_text("horizon_seconds: 1.0\n")
    with pytest.raises(ValueError, match="planner.yml"):
        PlannerConfig.from_yaml(bad)
