"""The PILCO loop on the simulated plant: random-torque trials, then alternate model learning, policy search and a trial."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
import scipy.optimize
import torch

from softpend.checks import (
    boolean,
    check_work_size,
    in_range,
    instance_of,
    optional_positive,
    positive,
    seed_tuple,
    set_ints,
)
from softpend.envs.randomised import RodUncertainty, optional_uncertainty, set_rod
from softpend.evaluation import TEST_EPISODE_S, EvaluationResult, evaluate_controller, run_episode
from softpend.io.overrides import dataclass_from_data
from softpend.io.reading import MAX_JSON_BYTES, read_json_checked
from softpend.io.torchfiles import load_state, refused, save_state
from softpend.pilco.controller import PilcoController, RandomTorqueController, in_balance_band
from softpend.pilco.gp import GPHyperparameters, MultiOutputGP, select_subset
from softpend.pilco.policy import LinearPolicy, RBFPolicy
from softpend.pilco.propagation import Propagator, StateSpec, state_spec
from softpend.plant import SimulationDiverged, wrap_angle_rad
from softpend.task import Task
from softpend.torch_threads import one_torch_thread

DTYPE = torch.float64

#: Prefix of the balancing policy's entries in ``policy.pt``.
BALANCE_PREFIX = "balance."


@dataclass(frozen=True)
class CostSettings:
    """The saturating cost: width [m] of tip distance (``width_after_swing_up_m`` once a policy trial swung up),
    tip-rate factor width ``rate_width_rad_s`` (None: none) once within ``rate_after_rad`` of upright (None: from
    the start), exploration weight in [-1, 0] of the cost's spread."""

    width_m: float = 0.15
    width_after_swing_up_m: Optional[float] = None
    rate_width_rad_s: Optional[float] = None
    rate_after_rad: Optional[float] = None
    exploration: float = 0.0

    def __post_init__(self) -> None:
        positive("cost.width_m", self.width_m)
        for name in ("rate_width_rad_s", "rate_after_rad", "width_after_swing_up_m"):
            optional_positive(f"cost.{name}", getattr(self, name))
        object.__setattr__(self, "exploration", in_range("cost.exploration", self.exploration, -1.0, 0.0))


@dataclass(frozen=True)
class GPSettings:
    """The GP dynamics: fitted on at most ``max_points`` points (``all_data``: then conditioned on all), with
    ``iterations`` optimiser steps."""

    max_points: int = 200
    all_data: bool = False
    iterations: int = 100

    def __post_init__(self) -> None:
        set_ints(self, "max_points", 10, "gp.")
        set_ints(self, "iterations", 1, "gp.")
        boolean("gp.all_data", self.all_data)


@dataclass(frozen=True)
class PolicySettings:
    """The RBF policy's ``n_basis`` functions; a linear balancing policy (None: none) acting within
    ``balance_within_rad`` and ``balance_within_rad_s`` of upright, searched over ``balance_prediction_s``."""

    n_basis: int = 50
    balance_within_rad: Optional[float] = None
    balance_within_rad_s: float = 2.0
    balance_prediction_s: float = 3.0

    def __post_init__(self) -> None:
        set_ints(self, "n_basis", 1, "policy.")
        if (optional_positive("policy.balance_within_rad", self.balance_within_rad) or 0.0) >= math.pi:
            raise ValueError(f"policy.balance_within_rad must be below pi, got {self.balance_within_rad!r}")
        for name in ("balance_prediction_s", "balance_within_rad_s"):
            positive(f"policy.{name}", getattr(self, name))


@dataclass(frozen=True)
class OptimiserSettings:
    """L-BFGS-B policy search: ``iterations`` per search, then ``restarts`` from fresh policies (pseudo-target
    spread ``restart_target_std``) when the predicted cost exceeds ``restart_above_cost_fraction`` of the steps."""

    iterations: int = 80
    restarts: int = 0
    restart_above_cost_fraction: float = 0.5
    restart_target_std: float = 1.0

    def __post_init__(self) -> None:
        set_ints(self, "iterations", 1, "optimiser.")
        set_ints(self, "restarts", 0, "optimiser.")
        positive("optimiser.restart_target_std", self.restart_target_std)
        fraction = in_range("optimiser.restart_above_cost_fraction", self.restart_above_cost_fraction, 0.0, 1 - 1e-16)
        object.__setattr__(self, "restart_above_cost_fraction", fraction)


@dataclass
class PilcoConfig:
    """Settings of a PILCO run (SI units); with ``rod_uncertainty`` each trial runs on a rod drawn around
    ``task.rod`` (:class:`~softpend.envs.randomised.RodUncertainty`)."""

    task: Task = field(default_factory=Task)
    state: str = "tip_bend"
    control_dt_s: float = 0.1
    horizon_s: float = 6.0
    prediction_s: Optional[float] = None
    n_policy_trials: int = 8
    n_random_trials: int = 1
    random_hold_min_s: float = 0.2
    random_hold_max_s: float = 0.6
    initial_std: float = 0.05
    eval_seeds: tuple[int, ...] = (1000, 1001, 1002)
    eval_duration_s: float = TEST_EPISODE_S
    target_std_rad: float = 0.1
    compiled: bool = False
    seed: int = 0
    cost: CostSettings = field(default_factory=CostSettings)
    gp: GPSettings = field(default_factory=GPSettings)
    policy: PolicySettings = field(default_factory=PolicySettings)
    optimiser: OptimiserSettings = field(default_factory=OptimiserSettings)
    rod_uncertainty: Optional[RodUncertainty] = None

    def __post_init__(self) -> None:
        self.rod_uncertainty = optional_uncertainty(self.rod_uncertainty)
        for f in dataclasses.fields(self):
            if isinstance(f.default_factory, type):  # the settings groups
                instance_of(f.name, getattr(self, f.name), f.default_factory)
        state_spec(self.state)
        positives = "control_dt_s horizon_s initial_std eval_duration_s target_std_rad random_hold_min_s"
        for name in f"{positives} random_hold_max_s".split():
            positive(name, getattr(self, name))
        if self.random_hold_max_s < self.random_hold_min_s:
            raise ValueError(f"random_hold_max_s must be >= random_hold_min_s, got {self.random_hold_max_s!r}")
        ratio = self.control_dt_s / self.task.dt_s
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(f"control_dt_s must be a whole multiple of task.dt_s, got {self.control_dt_s!r}")
        if self.n_horizon_steps < 2:
            raise ValueError(f"horizon_s must cover at least two control steps, got {self.horizon_s!r}")
        optional_positive("prediction_s", self.prediction_s)
        if self.prediction_s is not None and self.n_prediction_steps < self.n_horizon_steps:
            raise ValueError(f"prediction_s must be None or at least horizon_s, got {self.prediction_s!r}")
        set_ints(self, "n_policy_trials", 0)
        set_ints(self, "n_random_trials", 1)
        self.eval_seeds = seed_tuple("eval_seeds", self.eval_seeds)
        boolean("compiled", self.compiled)

    @property
    def hold_steps(self) -> int:  # plant steps per control step
        return int(round(self.control_dt_s / self.task.dt_s))

    @property
    def n_horizon_steps(self) -> int:  # control steps per trial
        return int(round(self.horizon_s / self.control_dt_s))

    @property
    def n_prediction_steps(self) -> int:  # control steps of each policy search's predicted rollout
        return int(round((self.prediction_s if self.prediction_s is not None else self.horizon_s) / self.control_dt_s))

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self) | {"task": self.task.to_dict(), "eval_seeds": list(self.eval_seeds)}
        uncertainty, data = self.rod_uncertainty, {k: v for k, v in data.items() if k != "rod_uncertainty"}
        return data if uncertainty is None else data | {"rod_uncertainty": uncertainty.to_dict()}

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: Any = "PILCO config") -> "PilcoConfig":
        """Inverse of :meth:`to_dict`; a missing or unknown field is a one-line ``ValueError`` naming ``source``."""
        if not isinstance(data, dict):
            raise ValueError(f"{source}: not a PILCO config (expected a JSON object, got {type(data).__name__})")
        data = {"rod_uncertainty": None, **data}
        return dataclass_from_data(cls, data, source, task=Task.from_dict, rod_uncertainty=optional_uncertainty)


@dataclass
class TrialRecord:
    """One real trial and what PILCO predicted for it."""

    index: int
    kind: str
    duration_s: float
    plant_seconds_total: float
    predicted_cost: float
    real_cost: float
    swing_up_time_s: float
    upright_std_rad: float
    n_gp_points: int
    wall_s_total: float
    eval_success_rate: float = float("nan")
    eval_upright_std_rad: float = float("nan")
    balanced: bool = False
    cpu_s_total: float = float("nan")
    cost_rate_width_rad_s: Optional[float] = None
    policy_restarts: int = 0
    cost_width_m: Optional[float] = None
    balance_predicted_cost: float = float("nan")


@dataclass
class PilcoResult:
    """Outcome of :func:`run_pilco`."""

    config: PilcoConfig
    records: list[TrialRecord]
    policy: RBFPolicy
    gp_hyperparameters: Optional[GPHyperparameters]
    balance_policy: Optional[LinearPolicy] = None
    predicted_means: list[np.ndarray] = field(default_factory=list, repr=False)  # per policy trial (H+1, d)
    real_states: list[np.ndarray] = field(default_factory=list, repr=False)  # per trial (H+1, d)

    @property
    def real_seconds_to_balance(self) -> float:
        """Plant seconds of interaction up to the first policy that balances (``inf`` if none did)."""
        for record in self.records:
            if record.balanced:
                return record.plant_seconds_total
        return math.inf

    @property
    def train_wall_s(self) -> float:
        return self.records[-1].wall_s_total if self.records else 0.0

    @property
    def train_cpu_s(self) -> float:
        return self.records[-1].cpu_s_total if self.records else 0.0

    @property
    def plant_seconds_total(self) -> float:
        return self.records[-1].plant_seconds_total if self.records else 0.0

    def controller(self) -> PilcoController:
        """The final policy (with its balancing policy, if any) as a :class:`~softpend.evaluation.Controller`."""
        return _controller(self.config, self.policy, self.balance_policy)

    def save(self, directory: str | Path) -> Path:
        """Write ``policy.pt`` (state dict) and ``pilco.json`` (config, trial records, GP hyperparameters)."""
        state = self.policy.state_dict()
        if self.balance_policy is not None:
            state.update({BALANCE_PREFIX + k: v for k, v in self.balance_policy.state_dict().items()})
        meta = {
            "config": self.config.to_dict(),
            "records": [dataclasses.asdict(r) for r in self.records],
            "gp_hyperparameters": self.gp_hyperparameters.to_dict() if self.gp_hyperparameters else None,
            "real_seconds_to_balance": self.real_seconds_to_balance,
            "train_wall_s": self.train_wall_s,
        }
        directory = Path(directory)
        save_state(directory / "policy.pt", state, directory / "pilco.json", json.dumps(meta, indent=2, default=float))
        return directory

    @classmethod
    def load(cls, directory: str | Path) -> "PilcoResult":
        """Inverse of :meth:`save` (without the predicted and real trajectories)."""
        directory = Path(directory)
        meta_path, weights_path = directory / "pilco.json", directory / "policy.pt"
        for path in (meta_path, weights_path):
            if not path.exists():
                raise FileNotFoundError(f"no PILCO result file {path}")
        try:
            meta = read_json_checked(meta_path, "PILCO result file", MAX_JSON_BYTES)  # a regular file, bounded
            config = PilcoConfig.from_dict(meta["config"], meta_path)
            records = [TrialRecord(**r) for r in meta["records"]]
            hyper = GPHyperparameters.from_dict(meta["gp_hyperparameters"]) if meta["gp_hyperparameters"] else None
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError, KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"{meta_path}: not a PILCO result ({type(exc).__name__}: {exc})") from None
        spec = state_spec(config.state)
        with refused(f"{weights_path}: not a PILCO policy written by softpend"):
            bound = 2**20 + 16 * (config.policy.n_basis + 2) * (spec.n_model_inputs + 2)
            state = load_state(weights_path, "PILCO policy file", bound)
            balance_state = {k[len(BALANCE_PREFIX) :]: v for k, v in state.items() if k.startswith(BALANCE_PREFIX)}
            state = {k: v for k, v in state.items() if not k.startswith(BALANCE_PREFIX)}
            n_inputs, limit_nm = spec.n_model_inputs, config.task.torque_limit_nm
            policy = RBFPolicy(np.zeros((state["centers"].shape[0], n_inputs)), np.ones(n_inputs), limit_nm)
            policy.load_state_dict(state)
            balance = LinearPolicy(n_inputs, limit_nm) if balance_state else None
            if balance is not None:
                balance.load_state_dict(balance_state)
        return cls(config=config, records=records, policy=policy, gp_hyperparameters=hyper, balance_policy=balance)


def _trial_cost(
    config: PilcoConfig,
    spec: StateSpec,
    states: np.ndarray,
    rate_width: Optional[float],
    width_m: Optional[float] = None,
) -> float:
    """The propagator's saturating cost (width ``width_m``, default ``config.cost.width_m``; with ``rate_width`` a
    tip-rate term) summed over a real trial's states after the start."""
    width_m = config.cost.width_m if width_m is None else width_m
    theta, theta_dot = states[1:, spec.tip_angle_index], states[1:, spec.tip_rate_index]
    exponent = 0.5 * (2.0 * config.task.rod.length_m**2 * (1.0 - np.cos(theta))) / width_m**2
    if rate_width is not None:
        exponent = exponent + 0.5 * (theta_dot / rate_width) ** 2
    return float((1.0 - np.exp(-exponent)).sum())


def _came_near_upright(spec: StateSpec, states: np.ndarray, within_rad: float) -> bool:
    theta = states[:, spec.tip_angle_index]
    return bool(np.min(np.abs((theta + np.pi) % (2 * np.pi) - np.pi)) < within_rad)


def _initial_distribution(spec: StateSpec, std: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Hanging at rest: rates 0, angles pi; ``S0 = std^2 I``."""
    m0 = torch.zeros(spec.dim, dtype=DTYPE)
    m0[spec.angle_indices] = math.pi
    return m0, (std**2) * torch.eye(spec.dim, dtype=DTYPE)


def _run_trial(config: PilcoConfig, controller, seed: int, env) -> tuple[EvaluationResult, np.ndarray, np.ndarray]:
    """One real trial: the episode, the control steps' states (H+1, d) and torques (H,)."""
    episode = run_episode(controller, env, seed=seed, duration_s=config.horizon_s)
    if episode.diverged:
        raise SimulationDiverged(f"the plant diverged during a PILCO trial: {episode.diverged}")
    k = config.hold_steps
    spec = state_spec(config.state)
    states = spec.from_observations(episode.observations[::k])
    torques = episode.torque_nm[::k][: len(states) - 1]
    return episode, states, torques


def _optimise_policy(
    propagator: Propagator,
    policy: RBFPolicy | LinearPolicy,
    m0: torch.Tensor,
    s0: torch.Tensor,
    n_steps: int,
    iterations: int,
) -> float:
    """L-BFGS-B on the policy's parameters from its current ones; it keeps the better, whose cost is returned."""

    def objective(vector: np.ndarray) -> tuple[float, np.ndarray]:
        leaf = torch.tensor(vector, dtype=DTYPE, requires_grad=True)
        policy.set_vector(leaf, requires_grad=True)
        try:
            _, _, _, total = propagator.rollout(m0, s0, n_steps)
        except torch.linalg.LinAlgError:
            return 1e6, np.zeros_like(vector)
        (grad,) = torch.autograd.grad(total, leaf)
        if not torch.all(torch.isfinite(grad)) or not math.isfinite(float(total.detach())):
            return 1e6, np.zeros_like(vector)
        return float(total.detach()), grad.numpy().copy()

    start = policy.get_vector()
    start_value = objective(start)[0]
    options = {"maxiter": int(iterations), "maxfun": int(2 * iterations)}
    result = scipy.optimize.minimize(objective, start, jac=True, method="L-BFGS-B", options=options)
    if result.fun <= start_value:
        policy.set_vector(result.x)
        return float(result.fun)
    policy.set_vector(start)
    return float(start_value)


#: The purposes of a run's random draws, each with its own child stream of ``SeedSequence(seed)`` (in this order).
RANDOM_STREAMS = tuple(
    "random_starts random_torques policy_starts policy_init gp_subsets policy_restarts rod_draws".split()
)


def _random_streams(seed: int) -> dict[str, np.random.Generator]:
    """One generator per purpose of :data:`RANDOM_STREAMS`, spawned from ``SeedSequence(seed)``."""
    children = np.random.SeedSequence(int(seed)).spawn(len(RANDOM_STREAMS))
    return {name: np.random.default_rng(child) for name, child in zip(RANDOM_STREAMS, children)}


def _draw_seed(rng: np.random.Generator) -> int:
    return int(rng.integers(0, 2**31 - 1))


def _controller(config: PilcoConfig, policy: RBFPolicy, balance: Optional[LinearPolicy]) -> PilcoController:
    within_rad = config.policy.balance_within_rad
    band = None if balance is None or within_rad is None else (within_rad, config.policy.balance_within_rad_s)
    return PilcoController(policy, state_spec(config.state), config.control_dt_s, balance if band else None, band)


def _upright_distribution(
    config: PilcoConfig, spec: StateSpec, states: np.ndarray
) -> Optional[tuple[torch.Tensor, torch.Tensor]]:
    """Mean and covariance (plus ``initial_std**2 I``) of the states in the balancing band, angles wrapped; None
    with fewer than ``2 * dim`` of them."""
    band = (config.policy.balance_within_rad, config.policy.balance_within_rad_s)
    assert band[0] is not None
    near = states[in_balance_band(spec, states, band[0], band[1])].copy()
    if len(near) < 2 * spec.dim:
        return None
    near[:, spec.angle_indices] = wrap_angle_rad(near[:, spec.angle_indices])
    cov = np.cov(near, rowvar=False) + config.initial_std**2 * np.eye(spec.dim)
    return torch.tensor(near.mean(axis=0), dtype=DTYPE), torch.tensor(0.5 * (cov + cov.T), dtype=DTYPE)


def check_pilco_size(config: PilcoConfig) -> None:
    """``ValueError`` if a run of ``config`` (rollout covariances, policy gradient, evaluation trajectories) would
    exceed :data:`softpend.checks.MAX_WORK_BYTES`."""
    dim = state_spec(config.state).dim
    rollout = 8.0 * config.n_prediction_steps * dim * dim * config.gp.max_points**2
    policy = 8.0 * config.n_prediction_steps * config.policy.n_basis * (config.gp.max_points + dim) * dim
    evaluation = 8.0 * 20 * len(config.eval_seeds) * (config.eval_duration_s / config.task.dt_s + 1)
    steps = f"{config.n_prediction_steps} prediction steps x {dim}**2 outputs x {config.gp.max_points}**2 GP points"
    policy_size = f"{config.policy.n_basis} basis functions"
    episodes = f"{len(config.eval_seeds)} evaluation episodes of {config.eval_duration_s:g} s"
    check_work_size("this PILCO run", rollout + policy + evaluation, f"{steps}, {policy_size}, {episodes}")


def run_pilco(
    config: Optional[PilcoConfig] = None,
    progress: bool = True,
    callback: Optional[Callable[[TrialRecord], None]] = None,
) -> PilcoResult:
    """Run PILCO on the plant (see the module docstring)."""
    from tqdm.auto import tqdm

    callback = callback or (lambda record: None)
    with one_torch_thread():
        pilco = Pilco(config if config is not None else PilcoConfig())
        for _ in range(pilco.config.n_random_trials):
            callback(pilco.random_trial())
        pilco.start_policy()
        bar = tqdm(range(pilco.config.n_policy_trials), desc="PILCO trials", disable=not progress)
        for _ in bar:
            pilco.optimize_models()
            search = pilco.optimize_policy()
            record = pilco.policy_trial(search)
            callback(record)
            real_s, std = f"{record.plant_seconds_total:.0f}", f"{record.eval_upright_std_rad:.2f}"
            bar.set_postfix(real_s=real_s, cost=f"{record.real_cost:.1f}/{search.predicted_cost:.1f}", std=std)
            if record.balanced:
                break
        bar.close()
        return pilco.result()


@dataclass
class PolicySearch:
    """What :meth:`Pilco.optimize_policy` searched with and predicted (:class:`TrialRecord`'s fields)."""

    predicted_cost: float
    cost_width_m: Optional[float]
    cost_rate_width_rad_s: Optional[float]
    policy_restarts: int
    balance_predicted_cost: float = float("nan")


class Pilco:
    """PILCO on the plant as an object: real trials feed the data, :meth:`optimize_models` fits the GP dynamics,
    :meth:`optimize_policy` searches the policies on the model, :meth:`controller` gives them as a controller."""

    def __init__(self, config: PilcoConfig) -> None:
        from softpend.envs import SoftPendulumEnv

        check_pilco_size(config)
        self.config = config
        self.spec = state_spec(config.state)
        self.env = SoftPendulumEnv(**config.task.env_kwargs())
        self.streams = _random_streams(config.seed)
        self.m0, self.s0 = _initial_distribution(self.spec, config.initial_std)
        self.inputs: list[np.ndarray] = []  # per trial: GP inputs (model inputs and torque)
        self.targets: list[np.ndarray] = []  # per trial: state differences
        self.records: list[TrialRecord] = []
        self.real_states: list[np.ndarray] = []  # per trial (H+1, d)
        self.predicted_means: list[np.ndarray] = []  # per policy trial (H+1, d)
        self.policy: Optional[RBFPolicy] = None
        self.balance_policy: Optional[LinearPolicy] = None
        self.gp: Optional[MultiOutputGP] = None
        self.gp_hyperparameters: Optional[GPHyperparameters] = None
        self.n_gp_points, self.n_searches, self.plant_seconds = 0, 0, 0.0
        self.rate_on = config.cost.rate_width_rad_s is not None and config.cost.rate_after_rad is None
        self._start_wall, self._start_cpu = time.perf_counter(), time.process_time()

    def random_trial(self) -> TrialRecord:
        """One trial of held random torques (start and torques each from their own stream)."""
        config = self.config
        limit_nm, hold_s = config.task.rod.torque_limit_nm, (config.random_hold_min_s, config.random_hold_max_s)
        seed = _draw_seed(self.streams["random_torques"])
        controller = RandomTorqueController(limit_nm, config.control_dt_s, seed, hold_s)
        search = PolicySearch(float("nan"), None, config.cost.rate_width_rad_s if self.rate_on else None, 0)
        return self._trial("random", controller, _draw_seed(self.streams["random_starts"]), search, n_gp_points=0)

    def start_policy(self) -> RBFPolicy:
        """The first policy: random, its centres on the states visited so far."""
        self.policy = self._random_policy(self.streams["policy_init"])
        return self.policy

    def _random_policy(self, rng: np.random.Generator, target_std: float = 0.1) -> RBFPolicy:
        """A fresh policy: centres drawn from the visited states, pseudo-targets of spread ``target_std``,
        length-scales the rates' spread in the model inputs and 0.7 for every sin/cos input (as in PILCO)."""
        spec, states, n_basis = self.spec, np.vstack(self.real_states), self.config.policy.n_basis
        chosen = states[rng.choice(len(states), size=n_basis, replace=n_basis > len(states))]
        spread = np.maximum(np.vstack(self.inputs)[:, :-1].std(axis=0), 1e-3)
        lengthscales = np.where(np.arange(spec.n_model_inputs) < spec.dim - spec.n_angles, spread, 0.7)
        limit_nm = self.config.task.rod.torque_limit_nm
        return RBFPolicy(spec.model_inputs(chosen), lengthscales, limit_nm, seed=_draw_seed(rng), target_std=target_std)

    def optimize_models(self) -> MultiOutputGP:
        """Fit the GP dynamics on at most ``gp.max_points`` points (the latest trial kept) from the last fit's
        hyperparameters; with ``gp.all_data`` condition it on all the data."""
        x_all, y_all = np.vstack(self.inputs), np.vstack(self.targets)
        seed = _draw_seed(self.streams["gp_subsets"])
        subset = select_subset(len(x_all), self.config.gp.max_points, recent=len(self.inputs[-1]), seed=seed)
        gp = MultiOutputGP(x_all[subset], y_all[subset], hyperparameters=self.gp_hyperparameters)
        gp.fit(self.config.gp.iterations)
        self.gp_hyperparameters = gp.hyperparameters
        if self.config.gp.all_data and len(subset) < len(x_all):
            gp.condition_on(x_all, y_all)
        self.gp, self.n_gp_points = gp, len(subset)
        return gp

    def optimize_policy(self) -> PolicySearch:
        """Search the RBF policy on the model from the current one (with restarts after the first search), predict
        its trial, and search the balancing policy when it is on."""
        config, spec = self.config, self.spec
        assert self.policy is not None and self.gp is not None, "start_policy and optimize_models come first"
        if not self.rate_on and config.cost.rate_width_rad_s is not None:
            assert config.cost.rate_after_rad is not None  # without it the rate term is on from the start
            self.rate_on = any(_came_near_upright(spec, st, config.cost.rate_after_rad) for st in self.real_states)
        rate_width = config.cost.rate_width_rad_s if self.rate_on else None
        swung_up = any(r.kind == "policy" and math.isfinite(r.swing_up_time_s) for r in self.records)
        width_after = config.cost.width_after_swing_up_m
        width_m = width_after if swung_up and width_after is not None else config.cost.width_m
        n_search, n_steps = config.n_prediction_steps if swung_up else config.n_horizon_steps, config.n_horizon_steps
        length_m, exploration = config.task.rod.length_m, config.cost.exploration
        propagator = Propagator(spec, self.gp, self.policy, length_m, width_m, rate_width, exploration, config.compiled)
        restart_rng = np.random.default_rng(_draw_seed(self.streams["policy_restarts"]))  # one draw per search
        objective, n_restarts = self._search(propagator, n_search, restart_rng, self.n_searches > 0)
        self.n_searches += 1
        with torch.no_grad():  # the predicted trial (the objective itself when it neither explores nor looks past it)
            means, _, costs, _ = propagator.rollout(self.m0, self.s0, n_search)
        self.predicted_means.append(means[: n_steps + 1].numpy())
        same = exploration == 0.0 and n_search == n_steps
        predicted = objective if same else float(costs[:n_steps].sum())
        return PolicySearch(predicted, width_m, rate_width, n_restarts, self._optimize_balance(width_m, rate_width))

    def _search(self, prop: Propagator, n_steps: int, rng: np.random.Generator, restart: bool) -> tuple[float, int]:
        """Search from the policy, then (when due) from fresh random ones; it keeps the lowest predicted cost's."""
        o, policy = self.config.optimiser, self.policy
        assert policy is not None
        search = lambda: _optimise_policy(prop, policy, self.m0, self.s0, n_steps, o.iterations)  # noqa: E731
        best = search()
        if not restart or o.restarts == 0 or best <= o.restart_above_cost_fraction * n_steps:
            return best, 0
        best_vector = policy.get_vector()
        for _ in range(o.restarts):
            policy.set_vector(self._random_policy(rng, o.restart_target_std).get_vector())
            if (value := search()) < best:
                best, best_vector = value, policy.get_vector()
        policy.set_vector(best_vector)
        return best, o.restarts

    def _optimize_balance(self, width_m: float, rate_width: Optional[float]) -> float:
        """Search the balancing policy from the trials' upright band; its predicted cost (NaN: none searched)."""
        config, spec = self.config, self.spec
        on = config.policy.balance_within_rad is not None
        upright = _upright_distribution(config, spec, np.vstack(self.real_states)) if on else None
        if upright is None:
            return float("nan")
        if self.balance_policy is None:
            self.balance_policy = LinearPolicy(spec.n_model_inputs, config.task.rod.torque_limit_nm)
        propagator = Propagator(spec, self.gp, self.balance_policy, config.task.rod.length_m, width_m, rate_width)
        n_balance = int(round(config.policy.balance_prediction_s / config.control_dt_s))
        return _optimise_policy(propagator, self.balance_policy, *upright, n_balance, config.optimiser.iterations)

    def controller(self) -> PilcoController:
        """The current policy (with its balancing policy, if any) as a controller."""
        assert self.policy is not None, "no policy before the first optimize_policy"
        return _controller(self.config, self.policy, self.balance_policy)

    def policy_trial(self, search: PolicySearch) -> TrialRecord:
        """Run the current policy on the plant (learnt from), then test it from ``eval_seeds`` (not learnt from,
        not counted); ``search`` is what :meth:`optimize_policy` returned for it."""
        config = self.config
        seed = _draw_seed(self.streams["policy_starts"])
        record = self._trial("policy", self.controller(), seed, search, self.n_gp_points)
        if config.eval_seeds:
            summary = evaluate_controller(
                self.controller(), config.task, name="pilco", seeds=config.eval_seeds, duration_s=config.eval_duration_s
            )
            stds = [r.upright_std_rad for r in summary.results]
            record.eval_success_rate = summary.success_rate
            record.eval_upright_std_rad = float(np.max(stds))
            record.balanced = bool(
                all(math.isfinite(r.swing_up_time_s) for r in summary.results) and max(stds) <= config.target_std_rad
            )
        vars(record).update(self._clocks())
        return record

    def _trial(self, kind: str, controller, seed: int, search: PolicySearch, n_gp_points: int) -> TrialRecord:
        """One real trial (on a rod drawn from ``rod_uncertainty`` when set), added to the data; its
        :class:`TrialRecord`, appended to the records."""
        config = self.config
        if config.rod_uncertainty is not None:
            set_rod(self.env, config.task, config.rod_uncertainty.draw(config.task.rod, self.streams["rod_draws"]))
        episode, states, torques = _run_trial(config, controller, seed, self.env)
        self.inputs.append(np.hstack([self.spec.model_inputs(states[:-1]), torques[:, None]]))
        self.targets.append(states[1:] - states[:-1])
        self.real_states.append(states)
        self.plant_seconds += config.horizon_s
        cost = _trial_cost(config, self.spec, states, search.cost_rate_width_rad_s, search.cost_width_m)
        record = TrialRecord(
            index=len(self.records),
            kind=kind,
            duration_s=config.horizon_s,
            plant_seconds_total=self.plant_seconds,
            real_cost=cost,
            swing_up_time_s=episode.swing_up_time_s,
            upright_std_rad=episode.upright_std_rad,
            n_gp_points=n_gp_points,
            **self._clocks(),
            **dataclasses.asdict(search),
        )
        self.records.append(record)
        return record

    def _clocks(self) -> dict[str, Any]:
        """Wall and CPU seconds since the run started."""
        wall, cpu = time.perf_counter() - self._start_wall, time.process_time() - self._start_cpu
        return dict(wall_s_total=wall, cpu_s_total=cpu)

    def result(self) -> PilcoResult:
        assert self.policy is not None  # set before the first trial
        return PilcoResult(
            config=self.config,
            records=self.records,
            policy=self.policy,
            gp_hyperparameters=self.gp_hyperparameters,
            balance_policy=self.balance_policy,
            predicted_means=self.predicted_means,
            real_states=self.real_states,
        )
