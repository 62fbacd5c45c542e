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

Many starts at once
-------------------
:func:`evaluate_batched` runs one episode per seed, all at once, on
:class:`~softpend.envs.vector.SoftPendulumVectorEnv` (or its discrete twin), which steps every rod together on
:class:`~softpend.plant.batched.BatchedPRBChain`.  Episode ``i`` starts exactly where
:class:`~softpend.envs.SoftPendulumEnv` reset with ``seeds[i]`` starts (each rod seeded with its own seed), the
policy sees the ``(B, 11)`` batch of observation vectors (the reward's bonus state included) every
``action_repeat`` plant steps and its actions are held in between, as
:class:`softpend.rl.training_env.HeldActionController` holds them; no episode is reset within the duration.
:func:`evaluate_controllers_batched` does the same for :class:`Controller` objects (LQR, PID, energy swing-up),
one copy per rod, each called with its rod's observation and joint state.  Both fill the same
:class:`EvaluationResult` fields as :func:`evaluate_controller` (trajectories, and the metrics of
:func:`metrics_from_trajectory` computed from them); a rod whose state stops being finite ends its episode at
its last finite state with ``diverged`` set and ``success`` false.

The batched plant is the RK4 chain, not the Exudyn plant of ``task.substeps``: at its default
(stability-limited) sub-steps it is more accurate than the Exudyn plant at its default 2 sub-steps, so that a
closed loop sensitive to small differences (a swing-up that catches the rod on one swing or the next) can end
differently from :func:`evaluate_controller` on the default task.  ``tests/test_evaluation_batched.py``
compares both against a converged Exudyn plant.
"""

from __future__ import annotations

import collections
import copy
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Protocol, Sequence

import numpy as np

from softpend.checks import boolean, check_work_size, in_unit_interval, int_at_least, non_negative, positive, positive_int
from softpend.plant import OBSERVATION_NAMES, Observation, SimulationDiverged, wrap_angle_rad
from softpend.stats import wilson_interval
from softpend.task import Task

__all__ = [
    "SUCCESS_STD_RAD",
    "TEST_EPISODE_S",
    "Controller",
    "DelayLine",
    "EvaluationResult",
    "EvaluationSummary",
    "FunctionController",
    "GymPolicyController",
    "LateNoisyController",
    "evaluate_batched",
    "evaluate_controller",
    "evaluate_controllers_batched",
    "metrics_from_trajectory",
    "run_episode",
]

#: Length of the episodes from hanging that decide whether a controller balances [s]: the tests that select an
#: agent or stop a learning run (``DQNConfig.eval_duration_s``, ``PilcoConfig.eval_duration_s``) and the fresh
#: starts every reported figure is measured on.  One length for both, so that a policy which holds the rod for the
#: selection tests and falls later is caught before it is selected.
TEST_EPISODE_S = 10.0

#: Largest upright std [rad] of an episode that counts as a success (``success``, see the module docstring).
SUCCESS_STD_RAD = 0.2


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


class DelayLine:
    """What arrives ``delay_steps`` pushes late: :meth:`push` stores a value and returns the one pushed
    ``delay_steps`` calls earlier; until that many have been pushed, the first value of the episode stands in for
    the older ones (a rig shows nothing before it starts)."""

    def __init__(self, delay_steps: int) -> None:
        self.delay_steps = int_at_least("delay_steps", delay_steps, 0)
        self._past: collections.deque = collections.deque(maxlen=self.delay_steps + 1)

    def clear(self) -> None:
        """Forget every value (a new episode)."""
        self._past.clear()

    def push(self, value: Any) -> Any:
        if not self._past:
            self._past.extend([value] * self.delay_steps)
        self._past.append(value)
        return self._past[0]


class LateNoisyController:
    """What a controller sees on a rig: the plant's observation ``delay_steps`` plant steps late, its hub and tip
    angles (``phi_rad``, ``theta_rad``) each perturbed by Gaussian noise of ``noise_rad`` [rad] drawn from
    ``rng`` (and wrapped to ``[-pi, pi)``); the joint state passed on is the current one.  The first observation
    of an episode stands in for the older ones the rig has not shown yet."""

    def __init__(self, controller: Controller, delay_steps: int = 0, noise_rad: float = 0.0,
                 rng: Optional[np.random.Generator] = None) -> None:
        self.controller = controller
        self._late = DelayLine(delay_steps)
        self.delay_steps = self._late.delay_steps
        self.noise_rad = non_negative("noise_rad", noise_rad)
        self.rng = rng if rng is not None else np.random.default_rng(0)

    def reset(self) -> None:
        self._late.clear()
        self.controller.reset()

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        seen = self._late.push(observation)
        if self.noise_rad > 0:
            phi, theta = self.rng.normal(0.0, self.noise_rad, size=2)
            seen = seen._replace(phi_rad=float(wrap_angle_rad(seen.phi_rad + phi)),
                                 theta_rad=float(wrap_angle_rad(seen.theta_rad + theta)))
        return self.controller(seen, q, q_dot, time_s)


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
    success_std_rad: float = SUCCESS_STD_RAD,
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
    duration_s: float = TEST_EPISODE_S,
    initial_state: Optional[tuple[np.ndarray, np.ndarray]] = None,
    env_kwargs: Optional[dict[str, Any]] = None,
    stop_at_first_failure: bool = False,
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
    stop_at_first_failure : bool
        Run the seeds in order and stop after the first episode that does not succeed (``success`` false):
        the summary then holds the episodes up to and including that one.  Each episode is the one a full
        evaluation runs (the same environment, reset with the same seed), so whether *every* seed succeeds is
        decided exactly, at the cost of the episodes up to the first failure only.

    Returns
    -------
    EvaluationSummary
        Per-seed :class:`EvaluationResult` objects (metrics and trajectories), in the order of ``seeds``.
    """
    from softpend.envs import SoftPendulumEnv

    task = task if task is not None else Task()
    if not isinstance(task, Task):
        raise ValueError(f"task must be a Task, got {type(task).__name__}")
    if len(seeds) == 0:
        raise ValueError("seeds must not be empty")
    positive("duration_s", duration_s)
    boolean("stop_at_first_failure", stop_at_first_failure)
    env = SoftPendulumEnv(**task.env_kwargs(), **(env_kwargs or {}))
    results = []
    for seed in seeds:
        results.append(run_episode(controller, env, seed, duration_s, initial_state=initial_state))
        if stop_at_first_failure and not results[-1].success:
            break
    return EvaluationSummary(name=name, results=results)


# ---------------------------------------------------------------------- many starts at once (module docstring)

_THETA = OBSERVATION_NAMES.index("theta_rad")
_PHI_DOT = OBSERVATION_NAMES.index("phi_dot_rad_s")

#: ``policy(k, vectors, observations, q, q_dot) -> actions`` for the vector environment at plant step ``k``.
_StepPolicy = Callable[[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray], Any]


def _check_seeds(seeds: Sequence[int]) -> list[int]:
    try:
        values = list(seeds)
    except TypeError:
        raise ValueError(f"seeds must be a sequence of integers >= 0, got {seeds!r}") from None
    if not values:
        raise ValueError("seeds must not be empty")
    return [int_at_least("seeds", s, 0) for s in values]


def _rods(task: Task, seeds: list[int], rod_spread: float, rod_seed: int) -> Any:
    """The rod of each episode as a :class:`~softpend.plant.batched.BatchedRodParams` (``None``: every episode on
    ``task.rod``)."""
    from softpend.plant.batched import BatchedRodParams
    from softpend.plant.randomisation import randomised_rod

    if rod_spread == 0:
        return None
    rods = [randomised_rod(task.rod, np.random.default_rng(rod_seed + s), rod_spread) for s in seeds]
    return BatchedRodParams.from_params(rods)


def _initial_joint_state(initial_state: tuple[Any, Any], batch: int, n_coordinates: int) -> tuple[Any, Any]:
    """``(q, q_dot)`` torch tensors of shape ``(batch, n_coordinates)`` from one state or one per rod."""
    import torch

    try:
        q, q_dot = initial_state
    except (TypeError, ValueError):
        raise ValueError("initial_state must be a pair (q, q_dot)") from None
    out = []
    for name, value in (("initial_state q", q), ("initial_state q_dot", q_dot)):
        array = np.asarray(value, dtype=np.float64)
        if array.shape == (n_coordinates,):
            array = np.broadcast_to(array, (batch, n_coordinates))
        if array.shape != (batch, n_coordinates):
            raise ValueError(f"{name} must have shape ({n_coordinates},) or ({batch}, {n_coordinates}), got {array.shape}")
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{name} must be finite")
        out.append(torch.tensor(array, dtype=torch.float64))
    return out[0], out[1]


def _run(
    policy: _StepPolicy,
    task: Optional[Task],
    seeds: Sequence[int],
    duration_s: float,
    *,
    n_torque_levels: Optional[int],
    rod_spread: float,
    rod_seed: int,
    substeps: Optional[int],
    initial_state: Optional[tuple[Any, Any]],
    name: str,
    reset_policy: Callable[[int], None] = lambda batch: None,
) -> EvaluationSummary:
    """The batched episodes of :func:`evaluate_batched` and :func:`evaluate_controllers_batched`."""
    from softpend.envs.observation_vector import observation_vector
    from softpend.envs.reward import next_bonus
    from softpend.envs.vector import SoftPendulumDiscreteVectorEnv, SoftPendulumVectorEnv
    from softpend.plant.batched import stable_substeps

    task = task if task is not None else Task()
    if not isinstance(task, Task):
        raise ValueError(f"task must be a Task, got {type(task).__name__}")
    if task.plant != "prb":
        raise ValueError(f"task.plant must be 'prb' (the batched chain simulates the PRB rod), got {task.plant!r}")
    seeds = _check_seeds(seeds)
    duration_s = positive("duration_s", duration_s)
    n_steps = int(round(duration_s / task.dt_s))
    if n_steps < 2:
        raise ValueError(f"duration_s must cover at least two steps of {task.dt_s} s, got {duration_s!r}")
    rod_spread = in_unit_interval("rod_spread", rod_spread, include_one=False)
    rod_seed = int_at_least("rod_seed", rod_seed, 0)
    batch = len(seeds)
    n_coordinates = task.rod.n_links + 1
    per_step = 8 * (len(OBSERVATION_NAMES) + 2 + n_coordinates)
    check_work_size(f"evaluating {batch} episode(s) of {duration_s:g} s", batch * (n_steps + 1) * per_step,
                    f"{n_steps + 1} steps of {task.dt_s:g} s per episode, {per_step} bytes of trajectory a step")

    rods = _rods(task, seeds, rod_spread, rod_seed)
    if rods is not None:
        stable = stable_substeps(rods, task.dt_s)
        if substeps is None:
            substeps = max(stable, stable_substeps(task.rod, task.dt_s))
        elif int_at_least("substeps", substeps, 1) < stable:
            raise ValueError(f"substeps must be at least {stable} for the rods drawn with rod_spread = {rod_spread:g} "
                             f"(softpend.plant.batched.stable_substeps), got {substeps!r}")
    kwargs: dict[str, Any] = dict(num_envs=batch, params=task.rod, dt_s=task.dt_s, substeps=substeps, start=task.start,
                                  start_noise_rad=task.start_noise_rad, max_episode_steps=n_steps + 1)
    if n_torque_levels is not None:
        env: Any = SoftPendulumDiscreteVectorEnv(n_torque_levels=n_torque_levels, **kwargs)
    else:
        env = SoftPendulumVectorEnv(**kwargs)
    if rods is not None:
        # each rod its own parameters; actions keep mapping to torques with the task's torque limit (the agent's
        # model of the motor), which the chain then saturates at the rod's own limit
        env.chain.set_params(rods)
    limits = env.chain.params.torque_limit_nm.numpy()

    vectors, info = env.reset(seed=seeds)
    observations = info["observation"]
    if initial_state is not None:
        q0, qd0 = _initial_joint_state(initial_state, batch, n_coordinates)
        env._q, env._qd = q0.contiguous(), qd0.contiguous()
        observations = env._observe()
        env._observations = observations
        env._bonus = next_bonus(observations[:, _THETA], np.zeros(batch), env.dt_s, env.reward_params)
        vectors = observation_vector(observations, env._bonus, env)
    q, q_dot = (x.numpy() for x in env.joint_state())
    reset_policy(batch)

    recorded_obs = np.empty((n_steps + 1, batch, len(OBSERVATION_NAMES)))
    recorded_torque = np.zeros((n_steps + 1, batch))
    recorded_q = np.empty((n_steps + 1, batch, n_coordinates))
    recorded_obs[0] = observations
    recorded_q[0] = q
    last = np.full(batch, n_steps)
    reasons: list[Optional[str]] = [None] * batch
    active = np.ones(batch, dtype=bool)
    for k in range(n_steps):
        actions = policy(k, vectors, observations, q, q_dot)
        torques = np.clip(env.torques_from_actions(actions), -limits, limits)
        vectors, _, _, _, info = env.step(actions)
        if "_truncation_reason" in info:
            failed = info["_truncation_reason"] & active
            for i in np.flatnonzero(failed):
                last[i], reasons[i] = k, str(info["truncation_reason"][i])
            active &= ~failed
        observations = info["observation"]
        q, q_dot = (x.numpy() for x in env.joint_state())
        recorded_torque[k, active] = torques[active]
        recorded_obs[k + 1] = observations
        recorded_q[k + 1] = q
        if not active.any():
            break

    times = np.arange(n_steps + 1) * task.dt_s
    results = []
    for i, seed in enumerate(seeds):
        end = int(last[i]) + 1
        obs_i, torque_i = recorded_obs[:end, i].copy(), recorded_torque[:end, i].copy()
        if end >= 2:
            metrics = metrics_from_trajectory(times[:end], obs_i[:, _THETA], torque_i, obs_i[:, _PHI_DOT])
        else:
            metrics = {"swing_up_time_s": math.inf, "upright_std_rad": math.pi, "upright_mean_abs_rad": math.pi,
                       "peak_torque_nm": 0.0, "energy_used_j": 0.0, "success": False}
        if reasons[i] is not None:
            metrics["success"] = False
        results.append(EvaluationResult(seed=seed, time_s=times[:end].copy(), observations=obs_i, torque_nm=torque_i,
                                        joint_angles_rad=recorded_q[:end, i].copy(), diverged=reasons[i], **metrics))
    return EvaluationSummary(name=name, results=results)


def evaluate_batched(
    predict_batch: Callable[[np.ndarray], Any],
    task: Optional[Task] = None,
    seeds: Sequence[int] = (0, 1, 2),
    duration_s: float = TEST_EPISODE_S,
    *,
    action_repeat: int = 1,
    n_torque_levels: Optional[int] = None,
    rod_spread: float = 0.0,
    rod_seed: int = 0,
    substeps: Optional[int] = None,
    initial_state: Optional[tuple[Any, Any]] = None,
    name: str = "policy",
) -> EvaluationSummary:
    """Evaluate a policy of the softpend environments on ``len(seeds)`` starts at once (see the module docstring).

    Parameters
    ----------
    predict_batch : callable
        ``predict_batch(vectors) -> actions``: the ``(B, 11)`` float32 batch of observation vectors in, one
        action per rod out (for stable-baselines3: ``lambda v: model.predict(v, deterministic=True)[0]``):
        integers of shape ``(B,)`` when ``n_torque_levels`` is set, else fractions of the torque limit of shape
        ``(B, 1)`` or ``(B,)`` (clipped to ``[-1, 1]``).  Called at plant steps ``0, action_repeat, ...``.
    task : Task, optional
        Rod, time step and start distribution (default ``Task()``); ``task.plant`` must be ``"prb"``, and
        ``task.substeps`` (the Exudyn plant's) is not used.
    seeds : sequence of int
        One episode per seed (integers >= 0); episode ``i`` starts where the single environment reset with
        ``seeds[i]`` starts.
    duration_s : float
        Episode length [s] (at least two plant steps).
    action_repeat : int
        Plant steps each action is held.
    n_torque_levels : int, optional
        Discrete actions (:class:`~softpend.envs.SoftPendulumDiscreteEnv` levels) when set.
    rod_spread : float
        Rods that differ from ``task.rod``: the episode seeded ``s`` runs on
        :func:`softpend.plant.randomisation.randomised_rod` of ``task.rod`` drawn from
        ``numpy.random.default_rng(rod_seed + s)`` with this spread (0: every episode on ``task.rod``).  Actions
        map to torques with ``task.rod``'s torque limit; each rod saturates them at its own.
    rod_seed : int
        Offset of the rods' generators (0: the rods of :func:`softpend.study.fresh_starts.perturbed_rod_row`).
    substeps : int, optional
        RK4 sub-steps per plant step (default: the stability limit of the stiffest rod,
        :func:`softpend.plant.batched.stable_substeps`; fewer are refused).
    initial_state : (q, q_dot), optional
        Exact initial joint state, shapes ``(n + 1,)`` (every rod) or ``(B, n + 1)``, overriding the start
        distribution (as for :func:`~softpend.evaluation.evaluate_controller`).
    name : str
        Name of the summary.

    Returns
    -------
    EvaluationSummary
        One :class:`~softpend.evaluation.EvaluationResult` per seed, in the order of ``seeds``.
    """
    if not callable(predict_batch):
        raise ValueError(f"predict_batch must be callable, got {type(predict_batch).__name__}")
    repeat = positive_int("action_repeat", action_repeat)
    held: dict[str, Any] = {}

    def policy(k: int, vectors: np.ndarray, observations: np.ndarray, q: np.ndarray, q_dot: np.ndarray) -> Any:
        if k % repeat == 0:
            actions = np.asarray(predict_batch(vectors))
            if actions.shape == (len(vectors), 1) and n_torque_levels is not None:
                actions = actions[:, 0]
            held["actions"] = actions
        return held["actions"]

    return _run(policy, task, seeds, duration_s, n_torque_levels=n_torque_levels, rod_spread=rod_spread,
                rod_seed=rod_seed, substeps=substeps, initial_state=initial_state, name=name)


def evaluate_controllers_batched(
    controller: Controller | Sequence[Controller],
    task: Optional[Task] = None,
    seeds: Sequence[int] = (0, 1, 2),
    duration_s: float = TEST_EPISODE_S,
    *,
    rod_spread: float = 0.0,
    rod_seed: int = 0,
    substeps: Optional[int] = None,
    initial_state: Optional[tuple[Any, Any]] = None,
    name: str = "controller",
) -> EvaluationSummary:
    """:func:`evaluate_batched` for :class:`~softpend.evaluation.Controller` objects (torque out, full joint state in).

    ``controller`` is one controller, copied (``copy.deepcopy``) for every rod, or a sequence of ``len(seeds)``
    controllers, rod ``i`` driven by the ``i``-th; each is reset before the episode and called every plant step
    with its rod's :class:`~softpend.plant.Observation`, joint state ``(q, q_dot)`` and time, as
    :func:`~softpend.evaluation.evaluate_controller` calls it.  Torques are clipped to the task's torque limit
    (the continuous environment's action range) and then to each rod's own.  The other parameters are those
    of :func:`evaluate_batched`.
    """
    task = task if task is not None else Task()
    if isinstance(controller, (list, tuple)):
        controllers = list(controller)
        if len(controllers) != len(_check_seeds(seeds)):
            raise ValueError(f"controller holds {len(controllers)} controllers for {len(list(seeds))} seeds")
    else:
        try:
            controllers = [copy.deepcopy(controller) for _ in _check_seeds(seeds)]
        except Exception as exc:  # objects holding a simulator or a file handle cannot be copied
            raise ValueError(f"controller cannot be copied for every rod ({exc}); pass one controller per seed") from exc
    for c in controllers:
        if not callable(c) or not hasattr(c, "reset"):
            raise ValueError(f"controller must have reset() and be callable, got {type(c).__name__}")
    limit = task.rod.torque_limit_nm if isinstance(task, Task) else 1.0

    def reset(batch: int) -> None:
        for c in controllers:
            c.reset()

    def policy(k: int, vectors: np.ndarray, observations: np.ndarray, q: np.ndarray, q_dot: np.ndarray) -> Any:
        time_s = k * task.dt_s
        torques = np.empty(len(controllers))
        for i, c in enumerate(controllers):
            torque = float(c(Observation.from_array(observations[i]), q[i].copy(), q_dot[i].copy(), time_s))
            if not math.isfinite(torque):
                raise ValueError(f"controller {i} returned a non-finite torque at t = {time_s:.2f} s: {torque!r}")
            torques[i] = torque
        return (torques / limit)[:, None]

    return _run(policy, task, seeds, duration_s, n_torque_levels=None, rod_spread=rod_spread, rod_seed=rod_seed,
                substeps=substeps, initial_state=initial_state, name=name, reset_policy=reset)
