"""The one evaluation used by every controller in the project (RL, LQR, PID, PILCO, on any plant).

A *controller* is any object with ``reset()`` and ``__call__(observation, q, q_dot, time_s) -> torque_nm``
(see :class:`Controller`); it sees the report's observed variables and, for model-based designs such as
LQR on the true model, the plant's full joint state.  :func:`evaluate_controller` runs it on the true plant
from the environment's start distribution and reports, per seed:

* ``swing_up_time_s`` -- the first time ``t`` such that ``|theta| < 0.2 rad`` throughout ``[t, t + 1 s]``
  (``inf`` if that never happens);
* ``upright_std_rad`` -- the standard deviation of ``theta`` about upright (``sqrt(mean(theta**2))``) after
  swing-up; ``upright_mean_abs_rad`` -- the mean of ``|theta|`` after swing-up (both over the final 50 %
  of the run if it never swung up, so a failure shows as a large number rather than a missing one);
* ``peak_torque_nm`` -- the largest applied torque magnitude (after saturation);
* ``energy_used_j`` -- the mechanical work the motor does, ``sum |tau * phi_dot| * dt``;
* ``success`` -- swung up and ``upright_std_rad <= success_std_rad``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Protocol, Sequence

import numpy as np

from softpend.checks import positive
from softpend.plant import OBSERVATION_NAMES, Observation, SimulationDiverged
from softpend.stats import wilson_interval
from softpend.task import Task

__all__ = [
    "Controller",
    "EvaluationResult",
    "EvaluationSummary",
    "FunctionController",
    "GymPolicyController",
    "evaluate_controller",
    "metrics_from_trajectory",
    "run_episode",
]


class Controller(Protocol):
    """What :func:`evaluate_controller` drives."""

    def reset(self) -> None:
        """Clear internal state (integrators, filters, bonus trackers) before an episode."""

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        """Base torque [N m] for the current step (the plant saturates it at its limit)."""


@dataclass
class FunctionController:
    """Wrap a plain function ``f(observation, q, q_dot, time_s) -> torque_nm`` as a :class:`Controller`."""

    function: Callable[[Observation, np.ndarray, np.ndarray, float], float]

    def reset(self) -> None:
        pass

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        return float(self.function(observation, q, q_dot, time_s))


class GymPolicyController:
    """Run a policy trained on a softpend Gymnasium environment (e.g. a stable-baselines3 model).

    The environment's observation vector (including the reward's bonus state) is rebuilt from the
    plant's observation exactly as the environment builds it, and the policy's action is mapped to a
    torque with the environment's own ``torque_from_action``.

    Parameters
    ----------
    predict : callable
        ``predict(obs_vector) -> action`` (for SB3: ``lambda o: model.predict(o, deterministic=True)[0]``).
    env : SoftPendulumEnv
        An environment instance with the same settings the policy was trained on (only its observation
        and action conventions are used; it is not stepped).
    """

    def __init__(self, predict: Callable[[np.ndarray], Any], env: Any) -> None:
        self.predict = predict
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env

    def reset(self) -> None:
        self.env._bonus = 0.0
        self._first = True

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        env = self.env
        if getattr(self, "_first", True):
            env._bonus = 1.0 if abs(observation.theta_rad) < env.reward_params.epsilon_rad else 0.0
            self._first = False
        else:  # advance the bonus exactly as the environment's reward does
            env._reward(observation.theta_rad)
        action = self.predict(env._vector(observation))
        return env.torque_from_action(action)


def metrics_from_trajectory(
    time_s: np.ndarray,
    theta_rad: np.ndarray,
    torque_nm: np.ndarray,
    phi_dot_rad_s: np.ndarray,
    upright_threshold_rad: float = 0.2,
    hold_s: float = 1.0,
    success_std_rad: float = 0.2,
) -> dict[str, float]:
    """Evaluation metrics of one sampled trajectory (see the module docstring).

    Parameters
    ----------
    time_s : array (T,)
        Sample times, uniformly spaced [s].
    theta_rad : array (T,)
        Tip angle from upright at those times [rad].
    torque_nm : array (T,)
        Applied torque held from each sample to the next [N m] (the last value is unused for energy).
    phi_dot_rad_s : array (T,)
        Hub angular rate [rad/s].
    """
    t = np.asarray(time_s, dtype=float)
    theta = np.asarray(theta_rad, dtype=float)
    torque = np.asarray(torque_nm, dtype=float)
    phi_dot = np.asarray(phi_dot_rad_s, dtype=float)
    if not (t.ndim == theta.ndim == torque.ndim == phi_dot.ndim == 1):
        raise ValueError("time_s, theta_rad, torque_nm and phi_dot_rad_s must be 1-D arrays")
    if not (len(t) == len(theta) == len(torque) == len(phi_dot)) or len(t) < 2:
        raise ValueError(
            f"time_s, theta_rad, torque_nm and phi_dot_rad_s must have the same length >= 2, got "
            f"{len(t)}, {len(theta)}, {len(torque)}, {len(phi_dot)}"
        )
    for name, values in (("time_s", t), ("theta_rad", theta), ("torque_nm", torque), ("phi_dot_rad_s", phi_dot)):
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{name} contains non-finite values")
    dt = float(np.median(np.diff(t)))
    if dt <= 0:
        raise ValueError("time_s must be increasing")
    hold_steps = int(round(hold_s / dt))
    inside = np.abs(theta) < upright_threshold_rad
    start_index: Optional[int] = None
    # first index i such that inside[i : i + hold_steps + 1] is all true
    run = 0
    for i in range(len(inside) - 1, -1, -1):
        run = run + 1 if inside[i] else 0
        if run > hold_steps:
            start_index = i
    # the loop above scans backwards, so start_index ends as the earliest qualifying index
    if start_index is not None:
        after = theta[start_index:]
        swing_up_time = float(t[start_index] - t[0])
    else:
        after = theta[len(theta) // 2 :]
        swing_up_time = math.inf
    upright_std = float(np.sqrt(np.mean(after**2)))
    return {
        "swing_up_time_s": swing_up_time,
        "upright_std_rad": upright_std,
        "upright_mean_abs_rad": float(np.mean(np.abs(after))),
        "peak_torque_nm": float(np.max(np.abs(torque))),
        "energy_used_j": float(np.sum(np.abs(torque[:-1] * phi_dot[:-1])) * dt),
        "success": bool(start_index is not None and upright_std <= success_std_rad),
    }


@dataclass
class EvaluationResult:
    """Metrics and trajectory of one evaluation episode."""

    seed: int
    swing_up_time_s: float
    upright_std_rad: float
    upright_mean_abs_rad: float
    peak_torque_nm: float
    energy_used_j: float
    success: bool
    time_s: np.ndarray = field(repr=False)
    observations: np.ndarray = field(repr=False)  # (T, 10) in OBSERVATION_NAMES order
    torque_nm: np.ndarray = field(repr=False)
    joint_angles_rad: np.ndarray = field(repr=False)  # (T, n_coordinates)
    diverged: Optional[str] = None

    @property
    def theta_rad(self) -> np.ndarray:
        return self.observations[:, OBSERVATION_NAMES.index("theta_rad")]

    @property
    def phi_rad(self) -> np.ndarray:
        return self.observations[:, OBSERVATION_NAMES.index("phi_rad")]

    def metrics(self) -> dict[str, float]:
        return {
            "seed": self.seed,
            "swing_up_time_s": self.swing_up_time_s,
            "upright_std_rad": self.upright_std_rad,
            "upright_mean_abs_rad": self.upright_mean_abs_rad,
            "peak_torque_nm": self.peak_torque_nm,
            "energy_used_j": self.energy_used_j,
            "success": self.success,
        }


@dataclass
class EvaluationSummary:
    """Results over several seeds."""

    name: str
    results: list[EvaluationResult]

    @property
    def success_rate(self) -> float:
        return float(np.mean([r.success for r in self.results]))

    @property
    def successes(self) -> int:
        """Episodes that succeeded."""
        return int(sum(r.success for r in self.results))

    def success_interval(self, confidence: float = 0.95) -> tuple[float, float]:
        """Wilson score interval of the success rate over these episodes (:func:`softpend.stats.wilson_interval`)."""
        return wilson_interval(self.successes, len(self.results), confidence)

    def median(self, metric: str) -> float:
        return float(np.median([getattr(r, metric) for r in self.results]))

    def mean(self, metric: str) -> float:
        return float(np.mean([getattr(r, metric) for r in self.results]))

    def row(self) -> dict[str, Any]:
        """One table row: medians over seeds plus the success rate and its Wilson 95 % interval."""
        low, high = self.success_interval()
        return {
            "controller": self.name,
            "seeds": len(self.results),
            "success_rate": self.success_rate,
            "success_low": low,
            "success_high": high,
            "swing_up_time_s": self.median("swing_up_time_s"),
            "upright_std_rad": self.median("upright_std_rad"),
            "upright_mean_abs_rad": self.median("upright_mean_abs_rad"),
            "peak_torque_nm": self.median("peak_torque_nm"),
            "energy_used_j": self.median("energy_used_j"),
        }


def run_episode(
    controller: Controller,
    env: Any,
    seed: int,
    duration_s: float,
    start: Optional[str] = None,
    initial_state: Optional[tuple[np.ndarray, np.ndarray]] = None,
) -> EvaluationResult:
    """Run one closed-loop episode of ``controller`` on ``env``'s plant (see :func:`evaluate_controller`)."""
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    plant = env.plant
    options = {"start": start} if start is not None else None
    env.reset(seed=int(seed), options=options)
    observation = plant.reset(*initial_state) if initial_state is not None else env.report_observation
    n_steps = int(round(duration_s / plant.dt_s))
    if n_steps < 2:
        raise ValueError(f"duration_s must cover at least two steps of {plant.dt_s} s, got {duration_s!r}")
    controller.reset()
    observations = np.empty((n_steps + 1, len(OBSERVATION_NAMES)))
    torques = np.zeros(n_steps + 1)
    times = np.arange(n_steps + 1) * plant.dt_s
    q, q_dot = plant.joint_state()
    angles = np.empty((n_steps + 1, len(q)))
    observations[0] = observation.as_array()
    angles[0] = q
    diverged = None
    last = n_steps
    for k in range(n_steps):
        torque = float(controller(observation, q, q_dot, k * plant.dt_s))
        if not math.isfinite(torque):
            raise ValueError(f"controller returned a non-finite torque at t = {k * plant.dt_s:.2f} s: {torque!r}")
        try:
            observation = plant.step(torque)
        except SimulationDiverged as exc:
            diverged = exc.reason
            last = k
            break
        torques[k] = plant.last_torque_nm
        q, q_dot = plant.joint_state()
        observations[k + 1] = observation.as_array()
        angles[k + 1] = q
    observations, torques, times, angles = observations[: last + 1], torques[: last + 1], times[: last + 1], angles[: last + 1]
    if last >= 1:
        metrics = metrics_from_trajectory(
            times, observations[:, OBSERVATION_NAMES.index("theta_rad")], torques,
            observations[:, OBSERVATION_NAMES.index("phi_dot_rad_s")],
        )
    else:
        metrics = {"swing_up_time_s": math.inf, "upright_std_rad": math.pi, "upright_mean_abs_rad": math.pi,
                   "peak_torque_nm": 0.0, "energy_used_j": 0.0, "success": False}
    if diverged is not None:
        metrics["success"] = False
    return EvaluationResult(
        seed=int(seed), time_s=times, observations=observations, torque_nm=torques, joint_angles_rad=angles,
        diverged=diverged, **metrics,
    )


def evaluate_controller(
    controller: Controller,
    task: Optional[Task] = None,
    *,
    name: str = "controller",
    seeds: Sequence[int] = (0, 1, 2),
    duration_s: float = 10.0,
    initial_state: Optional[tuple[np.ndarray, np.ndarray]] = None,
    env_kwargs: Optional[dict[str, Any]] = None,
) -> EvaluationSummary:
    """Evaluate a controller on the true plant of ``task`` over several seeds.

    Parameters
    ----------
    controller : Controller
        The controller under test (its ``reset()`` is called before each episode).
    task : Task, optional
        Plant, rod, time step and start distribution (default: ``Task()``, the default rod hanging).
    seeds : sequence of int
        One episode per seed; the seed draws the start-state noise through the environment's ``reset``.
    duration_s : float
        Episode length [s].
    initial_state : (q, q_dot), optional
        Exact initial joint state, overriding the task's start distribution (e.g. a 0.2 rad tilt for LQR).
    env_kwargs : dict, optional
        Further :class:`softpend.envs.SoftPendulumEnv` arguments (e.g. ``reward_params``).

    Returns
    -------
    EvaluationSummary
        Per-seed :class:`EvaluationResult` objects (metrics and trajectories).
    """
    from softpend.envs import SoftPendulumEnv

    task = task if task is not None else Task()
    if not isinstance(task, Task):
        raise ValueError(f"task must be a Task, got {type(task).__name__}")
    if len(seeds) == 0:
        raise ValueError("seeds must not be empty")
    positive("duration_s", duration_s)
    env = SoftPendulumEnv(**task.env_kwargs(), **(env_kwargs or {}))
    results = [run_episode(controller, env, seed, duration_s, initial_state=initial_state) for seed in seeds]
    return EvaluationSummary(name=name, results=results)
