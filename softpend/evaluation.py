"""The one evaluation used by every controller in the project (RL, LQR, PID, PILCO, on any plant)."""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Protocol, Sequence

import numpy as np

from softpend.checks import (
    boolean,
    check_work_size,
    in_unit_interval,
    int_at_least,
    one_of,
    positive,
    positive_int,
    seed_tuple,
)
from softpend.plant import OBSERVATION_NAMES, Observation, SimulationDiverged
from softpend.stats import wilson_interval
from softpend.task import Task

#: Length [s] of the episodes from hanging that select agents, stop learning runs and measure the fresh starts.
TEST_EPISODE_S = 10.0

#: Largest upright std [rad] of an episode that counts as a success.
SUCCESS_STD_RAD = 0.2
#: Largest upright std [rad] of a start that *holds* the rod balanced (fresh-start figures, the rig's closed loop).
HOLD_STD_RAD = 0.1
#: The swing-up ends when ``|theta|`` stays below ``UPRIGHT_THRESHOLD_RAD`` [rad] for ``SWING_UP_HOLD_S`` [s].
UPRIGHT_THRESHOLD_RAD = 0.2
SWING_UP_HOLD_S = 1.0


class Controller(Protocol):
    """What :func:`evaluate` drives."""

    def reset(self) -> None:
        """Clear internal state (integrators, filters, bonus trackers) before an episode."""

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        """Base torque [N m] for the current step (the plant saturates it at its limit)."""


def metrics_from_trajectory(
    time_s: np.ndarray,
    theta_rad: np.ndarray,
    torque_nm: np.ndarray,
    phi_dot_rad_s: np.ndarray,
    success_std_rad: float = SUCCESS_STD_RAD,
) -> dict[str, float]:
    """Metrics of one sampled trajectory: swing-up time (first time ``|theta|`` stays below
    :data:`UPRIGHT_THRESHOLD_RAD` for :data:`SWING_UP_HOLD_S`), upright std and mean after it (or over the second
    half), peak torque, energy, and success (swung up, std at most ``success_std_rad``)."""
    names = ("time_s", "theta_rad", "torque_nm", "phi_dot_rad_s")
    t, theta, torque, phi_dot = arrays = [
        np.asarray(a, dtype=float) for a in (time_s, theta_rad, torque_nm, phi_dot_rad_s)
    ]
    if any(a.ndim != 1 for a in arrays):
        raise ValueError(f"{', '.join(names)} must be 1-D arrays")
    if len({len(a) for a in arrays}) > 1 or len(t) < 2:
        raise ValueError(f"{', '.join(names)} must have the same length >= 2, got {[len(a) for a in arrays]}")
    for name, values in zip(names, arrays):
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{name} contains non-finite values")
    dt = float(np.median(np.diff(t)))
    if dt <= 0:
        raise ValueError("time_s must be increasing")
    window = int(round(SWING_UP_HOLD_S / dt)) + 1
    inside = (np.abs(theta) < UPRIGHT_THRESHOLD_RAD).astype(int)
    held = np.flatnonzero(np.convolve(inside, np.ones(window, dtype=int), "valid") == window)
    start_index = int(held[0]) if held.size else None
    after = theta[start_index if start_index is not None else len(theta) // 2 :]
    swing_up_time = float(t[start_index] - t[0]) if start_index is not None else math.inf
    upright_std = float(np.sqrt(np.mean(after**2)))
    return {
        "swing_up_time_s": swing_up_time,
        "upright_std_rad": upright_std,
        "upright_mean_abs_rad": float(np.mean(np.abs(after))),
        "peak_torque_nm": float(np.max(np.abs(torque))),
        "energy_used_j": float(np.sum(np.abs(torque[:-1] * phi_dot[:-1])) * dt),
        "success": bool(start_index is not None and upright_std <= success_std_rad),
    }


#: The metrics of an episode (the keys of :func:`metrics_from_trajectory`).
_METRICS = ("swing_up_time_s", "upright_std_rad", "upright_mean_abs_rad", "peak_torque_nm", "energy_used_j", "success")


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
        return {"seed": self.seed, **{name: getattr(self, name) for name in _METRICS}}


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
        return int(sum(r.success for r in self.results))

    def median(self, metric: str) -> float:
        return float(np.median([getattr(r, metric) for r in self.results]))

    def row(self) -> dict[str, Any]:
        """One table row: medians over seeds plus the success rate and its Wilson 95 % interval."""
        low, high = wilson_interval(self.successes, len(self.results))
        return {
            "controller": self.name,
            "seeds": len(self.results),
            "success_rate": self.success_rate,
            "success_low": low,
            "success_high": high,
            **{name: self.median(name) for name in _METRICS[:-1]},
        }


#: Metrics of an episode that ends before its second sample (a plant that diverged on the first step).
_NO_EPISODE = dict(zip(_METRICS, (math.inf, math.pi, math.pi, 0.0, 0.0, False)))
_THETA = OBSERVATION_NAMES.index("theta_rad")
_PHI_DOT = OBSERVATION_NAMES.index("phi_dot_rad_s")


class _OneRod:
    """The Exudyn engine: one :class:`~softpend.envs.SoftPendulumEnv` rod; controllers' torques go to its plant."""

    def __init__(self, env: Any) -> None:
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.dt_s, self.n_coordinates = self.env.plant.dt_s, self.env.plant.n_coordinates

    def reset(self, seeds: list[int], options: Optional[dict[str, Any]]) -> tuple[Any, ...]:
        self.env.reset(seed=seeds[0], options=options)
        q, q_dot = self.env.plant.joint_state()
        self.last = (None, self.env.report_observation.as_array()[None], q[None], q_dot[None])
        return self.last

    def step(self, torques: np.ndarray) -> tuple[Any, ...]:
        plant = self.env.plant
        try:
            observation = plant.step(float(torques[0]))
        except SimulationDiverged as exc:
            return (*self.last, np.zeros(1), np.ones(1, dtype=bool), [exc.reason])
        q, q_dot = plant.joint_state()
        self.last = (None, observation.as_array()[None], q[None], q_dot[None])
        return (*self.last, np.array([plant.last_torque_nm]), np.zeros(1, dtype=bool), [None])


class _ManyRods:
    """The batched engine: a :class:`~softpend.envs.vector.SoftPendulumVectorEnv` (or its discrete twin)."""

    def __init__(self, env: Any) -> None:
        self.env, self.dt_s, self.n_coordinates = env, env.dt_s, env.chain.n_coordinates
        self.limits = env.chain.params.torque_limit_nm.numpy()

    def reset(self, seeds: list[int], options: Optional[dict[str, Any]]) -> tuple[Any, ...]:
        vectors, info = self.env.reset(seed=seeds, options=options)
        return (vectors, info["observation"], *(x.numpy() for x in self.env.joint_state()))

    def step(self, actions: Any) -> tuple[Any, ...]:
        torques = np.clip(self.env.torques_from_actions(actions), -self.limits, self.limits)
        vectors, _, _, _, info = self.env.step(actions)
        failed = info.get("_truncation_reason", np.zeros(self.env.num_envs, dtype=bool))
        reasons = [str(r) if f else None for f, r in zip(failed, info.get("truncation_reason", failed))]
        return (vectors, info["observation"], *(x.numpy() for x in self.env.joint_state()), torques, failed, reasons)


class _Controllers:
    """One :class:`Controller` per rod, called with its rod's observation, joint state and time."""

    def __init__(self, controllers: list[Any], to_actions: Callable[[np.ndarray], Any]) -> None:
        for c in controllers:
            if not callable(c) or not hasattr(c, "reset"):
                raise ValueError(f"controller must have reset() and be callable, got {type(c).__name__}")
        self.controllers, self.to_actions = controllers, to_actions

    def reset(self) -> None:
        for c in self.controllers:
            c.reset()

    def __call__(
        self, k: int, time_s: float, vectors: Any, observations: np.ndarray, q: np.ndarray, q_dot: np.ndarray
    ) -> Any:
        torques = np.empty(len(self.controllers))
        for i, c in enumerate(self.controllers):
            torques[i] = float(c(Observation.from_array(observations[i]), q[i].copy(), q_dot[i].copy(), time_s))
            if not math.isfinite(torques[i]):
                raise ValueError(f"controller {i} returned a non-finite torque at t = {time_s:.2f} s: {torques[i]!r}")
        return self.to_actions(torques)


@dataclass
class BatchPolicy:
    """A batched-engine policy: ``predict_batch(vectors) -> actions`` on ``(B, 11)`` observation vectors (the plant's
    ``(B, 10)`` observations if ``observed``) every ``action_repeat`` plant steps, held in between; actions are levels
    ``(B,)`` with ``n_torque_levels``, else fractions of the torque limit; ``on_reset`` is called before an episode."""

    predict_batch: Callable[[np.ndarray], Any]
    action_repeat: int = 1
    n_torque_levels: Optional[int] = None
    observed: bool = False
    on_reset: Optional[Callable[[], None]] = None
    _held: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if not callable(self.predict_batch):
            raise ValueError(f"predict_batch must be callable, got {type(self.predict_batch).__name__}")
        positive_int("action_repeat", self.action_repeat)

    def reset(self) -> None:
        self._held = None
        if self.on_reset is not None:
            self.on_reset()

    def __call__(self, k: int, time_s: float, vectors: np.ndarray, *state: Any) -> Any:
        if k % self.action_repeat == 0:
            self._held = np.asarray(self.predict_batch(state[0] if self.observed else vectors))
            if self._held.shape == (len(vectors), 1) and self.n_torque_levels is not None:
                self._held = self._held[:, 0]
        return self._held


def _steps(duration_s: float, dt_s: float, batch: int, n_coordinates: int) -> int:
    """Plant steps of an episode, refusing fewer than two or trajectories that do not fit in memory."""
    n_steps = int(round(duration_s / dt_s))
    if n_steps < 2:
        raise ValueError(f"duration_s must cover at least two steps of {dt_s} s, got {duration_s!r}")
    per_step = 8 * (len(OBSERVATION_NAMES) + 2 + n_coordinates)
    detail = f"{n_steps + 1} steps of {dt_s:g} s per episode, {per_step} bytes of trajectory a step"
    check_work_size(f"evaluating {batch} episode(s) of {duration_s:g} s", batch * (n_steps + 1) * per_step, detail)
    return n_steps


def _roll(
    rods: Any, policy: Any, seeds: list[int], duration_s: float, initial_state: Optional[tuple[Any, Any]]
) -> list[EvaluationResult]:
    """The one evaluation loop: ``len(seeds)`` episodes at once on ``rods`` (an engine), one per seed."""
    n_steps, batch = _steps(duration_s, rods.dt_s, len(seeds), rods.n_coordinates), len(seeds)
    try:  # reset's options for an exact start (q, q_dot); None: the start distribution
        options = None if initial_state is None else dict(zip(("q", "q_dot"), initial_state, strict=True))
    except (TypeError, ValueError):
        raise ValueError("initial_state must be a pair (q, q_dot)") from None
    vectors, observations, q, q_dot = rods.reset(seeds, options)
    policy.reset()
    recorded_obs = np.empty((n_steps + 1, batch, len(OBSERVATION_NAMES)))
    recorded_torque = np.zeros((n_steps + 1, batch))
    recorded_q = np.empty((n_steps + 1, batch, rods.n_coordinates))
    recorded_obs[0], recorded_q[0] = observations, q
    last, reasons, active = np.full(batch, n_steps), [None] * batch, np.ones(batch, dtype=bool)
    for k in range(n_steps):
        actions = policy(k, k * rods.dt_s, vectors, observations, q, q_dot)
        vectors, observations, q, q_dot, torques, failed, why = rods.step(actions)
        for j in np.flatnonzero(failed & active):
            last[j], reasons[j] = k, why[j]
        active &= ~failed
        recorded_torque[k, active] = torques[active]
        recorded_obs[k + 1], recorded_q[k + 1] = observations, q
        if not active.any():
            break
    times = np.arange(n_steps + 1) * rods.dt_s
    results = []
    for i, seed in enumerate(seeds):
        end = int(last[i]) + 1
        obs, torque = recorded_obs[:end, i].copy(), recorded_torque[:end, i].copy()
        metrics: dict[str, Any] = dict(_NO_EPISODE)
        if end >= 2:
            metrics = metrics_from_trajectory(times[:end], obs[:, _THETA], torque, obs[:, _PHI_DOT])
        metrics["success"] = metrics["success"] and reasons[i] is None
        trajectory = dict(time_s=times[:end].copy(), observations=obs, torque_nm=torque, diverged=reasons[i])
        results.append(EvaluationResult(seed, **metrics, **trajectory, joint_angles_rad=recorded_q[:end, i].copy()))
    return results


def run_episode(
    controller: Controller,
    env: Any,
    seed: int,
    duration_s: float,
    initial_state: Optional[tuple[np.ndarray, np.ndarray]] = None,
) -> EvaluationResult:
    """One closed-loop episode of ``controller`` on ``env``, a :class:`~softpend.envs.SoftPendulumEnv` (see
    :func:`evaluate`)."""
    (result,) = _roll(_OneRod(env), _Controllers([controller], lambda u: u), [seed], duration_s, initial_state)
    return result


def _one_by_one(controller: Any, task: Task, seeds: list[int], duration_s: float, o: dict) -> list[EvaluationResult]:
    """The Exudyn engine's episodes of :func:`evaluate`, one after the other (none after a failure if asked)."""
    from softpend.envs import SoftPendulumEnv

    results: list[EvaluationResult] = []
    env = SoftPendulumEnv(**task.env_kwargs())
    for i, seed in enumerate(seeds):
        if o["rods"] is not None:
            env = SoftPendulumEnv(**task.replace(rod=o["rods"][i]).env_kwargs())
        results.append(run_episode(controller, env, seed, duration_s, initial_state=o["initial_state"]))
        if o["stop_at_first_failure"] and not results[-1].success:
            break
    return results


def _batched(controller: Any, task: Task, seeds: list[int], duration_s: float, o: dict) -> list[EvaluationResult]:
    """The batched engine's episodes of :func:`evaluate`, all at once (rod ``i`` drawn for ``seeds[i]``)."""
    from softpend.envs.vector import SoftPendulumDiscreteVectorEnv, SoftPendulumVectorEnv
    from softpend.plant.batched import BatchedRodParams, stable_substeps

    policy = controller if isinstance(controller, BatchPolicy) else _copies(controller, len(seeds))
    rods = None if o["rods"] is None else BatchedRodParams.from_params(o["rods"])
    substeps = o["substeps"]
    if rods is not None:
        stable = stable_substeps(rods, task.dt_s)
        if substeps is None:
            substeps = max(stable, stable_substeps(task.rod, task.dt_s))
        elif int_at_least("substeps", substeps, 1) < stable:
            raise ValueError(
                f"substeps must be at least {stable} for the rods drawn with rod_spread = {o['rod_spread']:g} "
                f"(softpend.plant.batched.stable_substeps), got {substeps!r}"
            )
    kwargs = {k: v for k, v in task.env_kwargs().items() if k != "plant"}
    kwargs.update(substeps=substeps, num_envs=len(seeds), max_episode_steps=int(round(duration_s / task.dt_s)) + 1)
    levels = getattr(policy, "n_torque_levels", None)
    env = SoftPendulumDiscreteVectorEnv(n_torque_levels=levels, **kwargs) if levels else SoftPendulumVectorEnv(**kwargs)
    if rods is not None:
        env.chain.set_params(rods)  # actions still map to torques by the task's limit; each rod saturates at its own
    to_actions = lambda torques: (torques / env.torque_limit_nm)[:, None]  # noqa: E731
    batch_policy = policy if isinstance(policy, BatchPolicy) else _Controllers(policy, to_actions)
    return _roll(_ManyRods(env), batch_policy, seeds, duration_s, o["initial_state"])


def evaluate(
    controller: Controller | Sequence[Controller] | BatchPolicy,
    task: Optional[Task] = None,
    *,
    engine: str = "exudyn",
    name: str = "controller",
    seeds: Sequence[int] = (0, 1, 2),
    duration_s: float = TEST_EPISODE_S,
    initial_state: Optional[tuple[Any, Any]] = None,
    stop_at_first_failure: bool = False,
    rod_spread: float = 0.0,
    rod_seed: int = 0,
    substeps: Optional[int] = None,
) -> EvaluationSummary:
    """Evaluate a controller on the true plant of ``task`` from one start per seed, on the Exudyn engine (one episode
    after the other) or the batched one (all at once); ``rod_spread > 0``: the rod of seed ``s``
    :func:`softpend.plant.params.randomised_rod` from ``default_rng(rod_seed + s)``."""
    from softpend.plant.params import randomised_rod

    task = task if task is not None else Task()
    if not isinstance(task, Task):
        raise ValueError(f"task must be a Task, got {type(task).__name__}")
    one_of("engine", engine, ("exudyn", "batched"))
    seeds = list(seed_tuple("seeds", seeds, non_empty=True))
    positive("duration_s", duration_s)
    stop_at_first_failure = boolean("stop_at_first_failure", stop_at_first_failure)
    rod_spread = in_unit_interval("rod_spread", rod_spread, include_one=False)
    rod_seed = int_at_least("rod_seed", rod_seed, 0)
    if engine == "exudyn" and (isinstance(controller, BatchPolicy) or substeps is not None):
        raise ValueError("a BatchPolicy and substeps are the batched engine's: pass engine='batched'")
    if engine == "batched" and task.plant != "prb":
        raise ValueError(f"task.plant must be 'prb' (the batched chain simulates the PRB rod), got {task.plant!r}")
    _steps(duration_s, task.dt_s, len(seeds), task.rod.n_links + 1)  # all the episodes' trajectories are kept
    draw = lambda s: randomised_rod(task.rod, np.random.default_rng(rod_seed + s), rod_spread)  # noqa: E731
    rods = None if rod_spread == 0 else [draw(s) for s in seeds]
    options: dict[str, Any] = dict(initial_state=initial_state, stop_at_first_failure=stop_at_first_failure)
    options.update(rods=rods, rod_spread=rod_spread, substeps=substeps)
    results = (_batched if engine == "batched" else _one_by_one)(controller, task, seeds, duration_s, options)
    failed = [i for i, r in enumerate(results) if not r.success]
    if stop_at_first_failure and failed:
        results = results[: failed[0] + 1]
    return EvaluationSummary(name=name, results=results)


#: The name most call sites use.
evaluate_controller = evaluate


def _copies(controller: Any, batch: int) -> list[Any]:
    """One controller per rod: the ``batch`` of a sequence, or copies of one controller."""
    if isinstance(controller, (list, tuple)):
        if len(controller) != batch:
            raise ValueError(f"controller holds {len(controller)} controllers for {batch} seeds")
        return list(controller)
    try:
        return [copy.deepcopy(controller) for _ in range(batch)]
    except Exception as exc:  # objects holding a simulator or a file handle cannot be copied
        raise ValueError(f"controller cannot be copied for every rod ({exc}); pass one controller per seed") from exc
