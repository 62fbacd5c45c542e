"""Gymnasium environments: swing the soft rod up from hanging and balance it upright."""

from __future__ import annotations

import math
from typing import Any, Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from softpend.checks import int_at_least, non_negative, one_of
from softpend.envs.reward import RewardParams
from softpend.plant import OBSERVATION_NAMES, Observation, RodParams, SimulationDiverged, make_plant
from softpend.task import START_KINDS as STARTS

#: Rates are divided by this in the observation vector [1/s].
VELOCITY_SCALE_PER_S = 10.0

OBSERVATION_VECTOR_NAMES: tuple[str, ...] = tuple(
    "cos_phi sin_phi cos_theta sin_theta ex_over_L ey_over_L phi_dot_over_10 theta_dot_over_10 ex_dot_over_10L "
    "ey_dot_over_10L bonus".split()
)

#: Bound of the observation vector's entries (velocity entries clipped at 5, i.e. 50 rad/s).
OBSERVATION_BOUND = np.array([1, 1, 1, 1, 2, 2, 5, 5, 5, 5, 1], dtype=np.float32)


#: Most torque levels of the discrete environments.
MAX_TORQUE_LEVELS = 1001


def reset_options(
    options: Optional[dict[str, Any]],
    start: str,
    n_coordinates: int,
    num_envs: Optional[int] = None,
    extra: tuple[str, ...] = (),
) -> tuple[str, Optional[tuple[np.ndarray, np.ndarray]]]:
    """The start kind (``options["start"]``, default ``start``) and the exact start state of ``options["q"]`` and
    ``options["q_dot"]`` (one, or one per rod of a vector environment) or ``None``; ``extra``: the caller's keys."""
    options = options or {}
    unknown = sorted(set(options) - {"start", "q", "q_dot", *extra})
    if unknown:
        raise ValueError(f"unknown reset option(s) {unknown}: the options are {['start', 'q', 'q_dot', *extra]}")
    start = one_of("options['start']", options.get("start", start), STARTS)
    if "q" not in options:
        if "q_dot" in options:
            raise ValueError("options['q_dot'] needs options['q'] (the exact start state)")
        return start, None
    shapes = [(n_coordinates,)] + ([(num_envs, n_coordinates)] if num_envs is not None else [])
    state = []
    for key in ("q", "q_dot"):
        value = np.asarray(options.get(key, np.zeros(n_coordinates)), dtype=np.float64)
        if value.shape not in shapes:
            raise ValueError(f"options['{key}'] must have shape {' or '.join(map(str, shapes))}, got {value.shape}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"options['{key}'] must be finite")
        state.append(value if num_envs is None else np.broadcast_to(value, (num_envs, n_coordinates)))
    return start, (state[0], state[1])


def draw_start(rng: np.random.Generator, start: str, noise_rad: float) -> tuple[float, float]:
    """Hub angle and rate of a start of kind ``start``, drawn from ``rng``."""
    hub = float(rng.uniform(-math.pi, math.pi)) if start == "random" else {"hanging": math.pi, "upright": 0.0}[start]
    return hub + float(rng.uniform(-noise_rad, noise_rad)), float(rng.uniform(-noise_rad, noise_rad))


class TaskSettings:
    """The (checked) rod, torque limit, reward and start distribution of the single and the vector environments."""

    params: RodParams
    torque_limit_nm: float
    reward_params: RewardParams
    start: str
    start_noise_rad: float

    def set_task(
        self, params: Optional[RodParams], reward_params: Optional[RewardParams], start: str, start_noise_rad: float
    ) -> None:
        self.params = params if params is not None else RodParams()
        if not isinstance(self.params, RodParams):
            raise ValueError(f"params must be a RodParams, got {type(params).__name__}")
        self.torque_limit_nm = self.params.torque_limit_nm
        self.reward_params = reward_params if reward_params is not None else RewardParams()
        self.start = one_of("start", start, STARTS)
        self.start_noise_rad = non_negative("start_noise_rad", start_noise_rad)


def check_torque_levels(n_torque_levels: int) -> int:
    n_torque_levels = int_at_least("n_torque_levels", n_torque_levels, 2)
    if n_torque_levels > MAX_TORQUE_LEVELS:
        raise ValueError(f"n_torque_levels must be at most {MAX_TORQUE_LEVELS}, got {n_torque_levels!r}")
    return n_torque_levels


class SoftPendulumEnv(TaskSettings, gym.Env):
    """Swing-up and balance of a soft rod driven by a torque-limited motor at its base: actions ``Box(-1, 1, (1,))``
    (fractions of ``torque_limit_nm``), observations :data:`OBSERVATION_VECTOR_NAMES` (the plant's in
    ``info["observation"]``), reward :mod:`softpend.envs.reward`, starts :data:`~softpend.task.START_KINDS` (uniform
    noise of ``start_noise_rad`` on hub angle and rate) or ``reset(options={"q": ..., "q_dot": ...})``; a diverged
    simulation truncates the episode with ``info["truncation_reason"]``."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        params: Optional[RodParams] = None,
        dt_s: float = 0.01,
        substeps: int = 2,
        reward_params: Optional[RewardParams] = None,
        start: str = "hanging",
        start_noise_rad: float = 0.05,
        plant: str = "prb",
        render_mode: Optional[str] = None,
    ) -> None:
        self.set_task(params, reward_params, start, start_noise_rad)
        if render_mode is not None:
            one_of("render_mode", render_mode, self.metadata["render_modes"])
        self.plant = make_plant(plant, params=self.params, dt_s=dt_s, substeps=substeps)
        self.dt_s = self.plant.dt_s
        self.render_mode = render_mode
        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        bound = OBSERVATION_BOUND.copy()
        self.observation_space = spaces.Box(-bound, bound, dtype=np.float32)
        self._bonus = 0.0
        self._bonus_decay = math.exp(-self.reward_params.bonus_decay_per_s * self.dt_s)
        self._observation: Optional[Observation] = None

    def observation_vector(self, o: Observation, bonus: float) -> np.ndarray:
        """The observation vector of plant observation ``o`` and the reward's bonus state ``bonus``."""
        inv_l, inv_v = 1.0 / self.params.length_m, 1.0 / VELOCITY_SCALE_PER_S
        angles = (math.cos(o.phi_rad), math.sin(o.phi_rad), math.cos(o.theta_rad), math.sin(o.theta_rad))
        tip_rates = (o.ex_dot_m_s * inv_l * inv_v, o.ey_dot_m_s * inv_l * inv_v)
        rates = (o.phi_dot_rad_s * inv_v, o.theta_dot_rad_s * inv_v, *tip_rates)
        clipped = [min(max(r, -5.0), 5.0) for r in rates]
        return np.array((*angles, o.ex_m * inv_l, o.ey_m * inv_l, *clipped, bonus), dtype=np.float32)

    def _reward(self, theta: float) -> float:  # step_reward's arithmetic on floats
        rp = self.reward_params
        self._bonus = 1.0 if abs(theta) < rp.epsilon_rad else self._bonus * self._bonus_decay
        s, c = abs(math.sin(theta)), math.cos(theta)
        ratio = c / s if s > 0 else math.copysign(math.inf, c)
        return min(max(ratio, -rp.clip_value), rp.clip_value) / rp.clip_value + rp.bonus_weight * self._bonus

    def torque_from_action(self, action: np.ndarray) -> float:
        """Base torque [N m] for an action of this environment."""
        try:
            try:
                a = float(action[0]) if len(action) == 1 else math.nan
            except TypeError:  # a scalar
                a = float(action)
        except (TypeError, ValueError, IndexError, KeyError):
            raise ValueError(f"action must be a number or a one-element array, got {action!r}") from None
        if not math.isfinite(a):
            raise ValueError(f"action must be finite, got {action!r}")
        return min(max(a, -1.0), 1.0) * self.torque_limit_nm

    @property
    def report_observation(self) -> Observation:
        """The report's raw observed variables at the current step."""
        if self._observation is None:
            raise RuntimeError("call reset() first")
        return self._observation

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None):
        """Start an episode; ``options`` as :func:`reset_options` reads them."""
        start, exact = reset_options(options, self.start, self.plant.n_coordinates)
        super().reset(seed=seed)
        q, qd = self.plant.hanging_state()
        q[0], qd[0] = draw_start(self.np_random, start, self.start_noise_rad)
        self._observation = self.plant.reset(*(exact if exact is not None else (q, qd)))
        self._bonus = 1.0 if abs(self._observation.theta_rad) < self.reward_params.epsilon_rad else 0.0
        return self.observation_vector(self._observation, self._bonus), {"observation": self._observation.as_array()}

    def step(self, action):
        if self._observation is None:
            raise RuntimeError("call reset() before step()")
        torque = self.torque_from_action(action)
        info: dict[str, Any] = {"torque_nm": torque}
        try:
            self._observation = self.plant.step(torque)
        except SimulationDiverged as exc:
            info["truncation_reason"] = f"simulation diverged: {exc.reason}"
            return self.observation_vector(self._observation, self._bonus), 0.0, False, True, info
        reward = self._reward(self._observation.theta_rad)
        return self.observation_vector(self._observation, self._bonus), reward, False, False, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from softpend.plotting import render_rod_rgb

        return render_rod_rgb(self.plant.link_points_m(), self.params.length_m)


class SoftPendulumDiscreteEnv(SoftPendulumEnv):
    """:class:`SoftPendulumEnv` with ``Discrete(n_torque_levels)`` actions: evenly spaced torques from
    ``-torque_limit_nm`` to ``+torque_limit_nm``."""

    def __init__(self, n_torque_levels: int = 5, **kwargs: Any) -> None:
        n_torque_levels = check_torque_levels(n_torque_levels)
        super().__init__(**kwargs)
        self.n_torque_levels = n_torque_levels
        self.torque_levels_nm = np.linspace(-1.0, 1.0, self.n_torque_levels) * self.torque_limit_nm
        self.action_space = spaces.Discrete(self.n_torque_levels)

    def torque_from_action(self, action) -> float:
        """Torque [N m] of an integer action (or a one-element integer array) in ``[0, n_torque_levels)``."""
        try:
            value = np.asarray(action)
        except ValueError:  # a ragged list
            value = np.asarray(None)
        if value.size != 1 or value.dtype.kind not in "iu" or not 0 <= value.reshape(-1)[0] < self.n_torque_levels:
            raise ValueError(f"action must be an integer in [0, {self.n_torque_levels}), got {action!r}")
        return float(self.torque_levels_nm[value.reshape(-1)[0]])


def observation_vector(observations: np.ndarray, bonus: np.ndarray, env: Any) -> np.ndarray:
    """Rows ``env.observation_vector(observation, bonus)`` (float32, ``(B, 11)``) for plant observations
    ``(B, 10)`` and the reward's bonus state after each; ``env`` (single or vector) is not stepped."""
    observations = np.asarray(observations, dtype=np.float64)
    if observations.ndim != 2 or observations.shape[1] != len(OBSERVATION_NAMES):
        raise ValueError(f"observations must have shape (B, {len(OBSERVATION_NAMES)}), got {observations.shape}")
    bonus = np.broadcast_to(np.asarray(bonus, dtype=np.float64), (observations.shape[0],))
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    inv_l, v = 1.0 / env.params.length_m, VELOCITY_SCALE_PER_S
    phi, theta, ex, ey, _, phi_dot, theta_dot, ex_dot, ey_dot, _ = observations.T
    angles = [np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)]  # the order of OBSERVATION_VECTOR_NAMES
    rates = [phi_dot / v, theta_dot / v, ex_dot * inv_l / v, ey_dot * inv_l / v]
    vec = np.stack([*angles, ex * inv_l, ey * inv_l, *rates, bonus], axis=1).astype(np.float32)
    bound = env.observation_space.high
    return np.clip(vec, -bound, bound)
