"""Model-predictive swing-up on learned dynamics (a black-box or PRB-residual Gaussian ensemble, MPPI, an LQR near
upright) with every plant second counted (:func:`run_planner`)."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from softpend.checks import in_range, one_of, positive, seed_tuple, set_ints
from softpend.control.identified import hanging_protocol
from softpend.control.learned import LearnedStateTracker
from softpend.control.lqr import LQRController
from softpend.control.swingup import pendulum_energy_j
from softpend.evaluation import HOLD_STD_RAD, TEST_EPISODE_S, BatchPolicy, EvaluationSummary, evaluate
from softpend.plant import Observation, RodParams
from softpend.plant.batched import BatchedPRBChain
from softpend.sysid.babble import PROGRAMS, babble
from softpend.sysid.greybox import GreyBoxConfig, identify, reconstruct_joint_states, wrap_diff
from softpend.sysid.layout import StateLayout
from softpend.sysid.model import DynamicsEnsemble, DynamicsModel
from softpend.sysid.variables import POSITION_NAMES, backward_difference, is_angle
from softpend.task import Task

#: The dynamics models of :class:`PlannerConfig` (``model``).
MODELS = ("ensemble", "residual")
#: Weight of the squared energy error (in units of the hanging energy gap) beside ``1 - cos(theta)``.
ENERGY_WEIGHT = 1.0
#: The LQR hands back to the planner beyond this multiple of the capture angle.
RELEASE_FACTOR = 2.0
#: Factors on the task rod's estimated fields that give the grey-box identification its starting guess.
IDENTIFY_GUESS_FACTORS = {
    "hub_inertia_kgm2": 1.5,
    "hub_friction_nms_per_rad": 0.5,
    "youngs_modulus_pa": 0.7,
    "joint_damping_nms_per_rad": 2.0,
    "tip_mass_kg": 0.7,
}
#: Knots planned at a time: a plan's work is spread over their control periods.
KNOTS_PER_PLAN = 2
#: Gauss-Newton steps of a tracked observation's joint angles from the previous observation's.
WARM_ITERATIONS = 10
#: Upright threshold of a held rod [rad] (as :func:`softpend.evaluation.metrics_from_trajectory`).
UPRIGHT_RAD = 0.2
#: The joint state the controllers are handed in place of the plant's (they read observations only).
_NO_STATE = np.empty(0)
_ANGLE_MASK = np.array([is_angle(n) for n in POSITION_NAMES])


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of :func:`run_planner` (SI units): ``excitation_s`` of babbling before the first trial; a trial lasts
    at most ``trial_s``, ending once held (``|theta| < 0.2`` rad, RMS <= ``HOLD_STD_RAD``) for ``hold_s``; the run
    ends after ``stop_after_balanced`` such trials in a row; ``identify_windows`` 0 keeps the task's rod."""

    task: Task = field(default_factory=Task)
    model: str = "ensemble"
    excitation_program: str = "multisine"
    excitation_s: float = 5.0
    trial_s: float = TEST_EPISODE_S
    hold_s: float = 3.0
    max_trials: int = 8
    stop_after_balanced: int = 1
    ensemble_size: int = 5
    hidden_width: int = 64
    train_steps: int = 600
    identify_windows: int = 40
    horizon_s: float = 1.2
    control_dt_s: float = 0.05
    n_samples: int = 200
    temperature: float = 0.3
    noise_fraction: float = 0.6
    capture_rad: float = 0.4
    selection_seeds: tuple[int, ...] = (1000, 1001, 1002)
    seed: int = 0

    def __post_init__(self) -> None:
        one_of("model", self.model, MODELS)
        one_of("excitation_program", self.excitation_program, PROGRAMS)
        for name in ("excitation_s", "trial_s", "hold_s", "horizon_s", "control_dt_s", "temperature"):
            positive(name, getattr(self, name))
        set_ints(self, "max_trials stop_after_balanced ensemble_size hidden_width train_steps", 1)
        set_ints(self, "identify_windows seed", 0)
        set_ints(self, "n_samples", 2)
        if self.n_samples % self.ensemble_size:
            raise ValueError(f"n_samples must be a multiple of ensemble_size, got {self.n_samples!r}")
        in_range("noise_fraction", self.noise_fraction, 1e-6, 10.0)
        in_range("capture_rad", self.capture_rad, 1e-6, math.pi / RELEASE_FACTOR)
        if self.hold_s > self.trial_s:
            raise ValueError(f"hold_s must be at most trial_s, got {self.hold_s!r}")
        if self.excitation_s < 2 * self.task.dt_s:
            raise ValueError(f"excitation_s must cover two steps of task.dt_s, got {self.excitation_s!r}")
        ratios = [getattr(self, name) / self.task.dt_s for name in ("control_dt_s", "horizon_s")]
        if self.n_knots <= KNOTS_PER_PLAN or any(round(r) < 1 or abs(r - round(r)) > 1e-9 for r in ratios):
            raise ValueError(
                "control_dt_s and horizon_s must be whole multiples of task.dt_s, "
                f"horizon_s > {KNOTS_PER_PLAN} control_dt_s"
            )
        seeds = seed_tuple("selection_seeds", self.selection_seeds, non_empty=True)
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"selection_seeds must be distinct, got {seeds!r}")
        object.__setattr__(self, "selection_seeds", seeds)

    @property
    def hold_steps(self) -> int:  # plant steps per planned torque
        return int(round(self.control_dt_s / self.task.dt_s))

    @property
    def n_knots(self) -> int:  # planned torques over the horizon
        return int(round(self.horizon_s / self.control_dt_s))

    def replace(self, **changes: Any) -> "PlannerConfig":
        return dataclasses.replace(self, **changes)


def _bound_log_var(log_var: Tensor, max_log_var: Tensor, min_log_var: Tensor) -> Tensor:  # as in PETS
    log_var = max_log_var - nn.functional.softplus(max_log_var - log_var)
    return min_log_var + nn.functional.softplus(log_var - min_log_var)


class _GaussianHead(nn.Module):
    """Mean and bounded log-variance from a network's ``2 m`` raw outputs (the bounds are learnt)."""

    def __init__(self, n_outputs: int) -> None:
        super().__init__()
        self.max_log_var = nn.Parameter(torch.full((n_outputs,), 0.5))
        self.min_log_var = nn.Parameter(torch.full((n_outputs,), -10.0))

    def forward(self, raw: Tensor) -> tuple[Tensor, Tensor]:
        mean, log_var = raw.chunk(2, dim=-1)
        return mean, _bound_log_var(log_var, self.max_log_var, self.min_log_var)


def _sample(mean: Tensor, log_var: Tensor, generator: Optional[torch.Generator]) -> Tensor:
    """``mean`` plus Gaussian noise of ``exp(log_var)`` drawn from ``generator`` (``None``: the mean)."""
    if generator is None:
        return mean
    return mean + torch.exp(0.5 * log_var) * torch.randn(mean.shape, generator=generator, dtype=mean.dtype)


def _mlp(n_in: int, n_out: int, width: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, width), nn.SiLU(), nn.Linear(width, width), nn.SiLU(), nn.Linear(width, n_out))


class GaussianDynamicsModel(DynamicsModel):
    """A :class:`~softpend.sysid.DynamicsModel` with a log-variance output; :meth:`predict_delta` adds a draw from
    ``self.noise_generator`` (``None``: the mean)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.net[-1] = nn.Linear(self.hidden_widths[-1], 2 * self.n_outputs)
        self.head = _GaussianHead(self.n_outputs)
        self.noise_generator: Optional[torch.Generator] = None

    def predict_delta(self, state: Tensor, torque_nm: Tensor) -> Tensor:
        state, torque_nm = self._check(state, torque_nm)
        torque_nm = torque_nm.clamp(-self.torque_limit_nm, self.torque_limit_nm)
        mean, log_var = self.head(self.net(self.normalise_features(self.features(state, torque_nm))))
        out = _sample(mean, log_var, self.noise_generator) * self.delta_std + self.delta_mean
        if not self.integrate_positions:
            return out
        p = self._p
        return torch.cat([self.dt_s * (state[:, p : 2 * p] + out), out], dim=1)


def _fit_gaussian(
    nets: Sequence[nn.Module], heads: Sequence[_GaussianHead], x: Tensor, y: Tensor, steps: int, seed: int
) -> None:
    """Fit each ``(net, head)``, its layers reset under ``torch.manual_seed(seed)``, to a bootstrap of ``(x, y)`` by
    Gaussian negative log-likelihood with Adam."""
    torch.manual_seed(seed)
    for net in nets:
        net.apply(lambda layer: layer.reset_parameters() if isinstance(layer, nn.Linear) else None)
    generator = torch.Generator().manual_seed(seed)
    n = x.shape[0]
    for net, head in zip(nets, heads):
        rows = torch.randint(n, (n,), generator=generator)
        optimiser = torch.optim.Adam(list(net.parameters()) + list(head.parameters()), lr=3e-3, weight_decay=1e-5)
        for _ in range(steps):
            batch = rows[torch.randint(n, (min(256, n),), generator=generator)]
            mean, log_var = head(net(x[batch]))
            loss = (((mean - y[batch]) ** 2) * torch.exp(-log_var) + log_var).mean()
            loss = loss + 0.01 * (head.max_log_var.sum() - head.min_log_var.sum())
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()


class _StackedNets:
    """An ensemble's Gaussian networks at once, each layer one batched matrix product: ``(E, R, F)`` inputs to means
    and bounded log-variances ``(E, R, n)``."""

    def __init__(self, nets: Sequence[Any], heads: Sequence[Any]) -> None:
        layers = [[net[i] for net in nets] for i in range(0, len(nets[0]), 2)]
        self.weights = [torch.stack([layer.weight.detach().T for layer in group]) for group in layers]
        self.biases = [torch.stack([layer.bias.detach()[None] for layer in group]) for group in layers]
        self.max_log_var = torch.stack([head.max_log_var.detach()[None] for head in heads])
        self.min_log_var = torch.stack([head.min_log_var.detach()[None] for head in heads])

    def __call__(self, h: Tensor) -> tuple[Tensor, Tensor]:
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = torch.baddbmm(b, h, w)
            if i < len(self.weights) - 1:
                h = nn.functional.silu(h)
        mean, log_var = h.chunk(2, dim=-1)
        return mean, _bound_log_var(log_var, self.max_log_var, self.min_log_var)


class StackedEnsemble:
    """Fast rollouts of a :func:`fit_ensemble` ensemble: row ``i`` of a batch is predicted by member ``i % E``."""

    def __init__(self, ensemble: DynamicsEnsemble) -> None:
        self.members: list[Any] = list(ensemble.members)
        self.first = self.members[0]
        self.nets = _StackedNets([m.net for m in self.members], [m.head for m in self.members])
        self.noise_generator: Optional[torch.Generator] = None

    def predict_next(self, state: Tensor, torque_nm: Tensor, generator: Optional[torch.Generator] = None) -> Tensor:
        first, n_members = self.first, len(self.members)
        state, torque_nm = first._check(state, torque_nm)
        batch = state.shape[0]
        torque_nm = torque_nm.clamp(-first.torque_limit_nm, first.torque_limit_nm)
        z = first.normalise_features(first.features(state, torque_nm))
        mean, log_var = self.nets(z.reshape(batch // n_members, n_members, -1).transpose(0, 1))
        out = _sample(mean, log_var, self.noise_generator).transpose(0, 1).reshape(batch, -1)
        out = out * first.delta_std + first.delta_mean
        p = first._p
        delta = torch.cat([first.dt_s * (state[:, p : 2 * p] + out), out], dim=1)
        return first.next_from_delta(state, delta)


def _standardise(values: Tensor) -> tuple[Tensor, Tensor]:
    mean, std = values.mean(0), values.std(0)
    return mean, torch.where(std > 1e-12, std, torch.ones_like(std))


def fit_ensemble(
    states: np.ndarray, torques_nm: np.ndarray, next_states: np.ndarray, task: Task, config: PlannerConfig
) -> DynamicsEnsemble:
    """The black-box ensemble on the full observed layout fitted to ``states (M, 10) -> next_states`` under
    ``torques_nm (M,)``."""
    args = (StateLayout.full(), task.dt_s, task.torque_limit_nm, (config.hidden_width,) * 2)
    members = [GaussianDynamicsModel(*args, tip_reach_m=1.01 * task.rod.length_m) for _ in range(config.ensemble_size)]
    first = members[0]
    s, u, s1 = (torch.as_tensor(a, dtype=torch.float32) for a in (states, torques_nm, next_states))
    features, targets = first.features(s, u), first.target_delta(s, s1)
    for m in members:  # unclamped until the box is set: the standardised features
        m.set_normalisation(features.mean(0), features.std(0), targets.mean(0), targets.std(0))
    z = first.normalise_features(features)
    for m in members:
        m.set_feature_box(z.min(0).values, z.max(0).values, margin=0.5)
    x, y = first.normalise_features(features), (targets - first.delta_mean) / first.delta_std
    _fit_gaussian([m.net for m in members], [m.head for m in members], x, y, config.train_steps, config.seed)
    return DynamicsEnsemble(members).eval()


def _tip(q: Tensor, qd: Tensor, link_length_m: float) -> tuple[Tensor, Tensor]:
    """Tip angle ``theta`` and rate of joint states ``(..., n + 1)``, as the plant observes them."""
    a, ad = torch.cumsum(q, -1)[..., 1:], torch.cumsum(qd, -1)[..., 1:]
    s, c = torch.sin(a), torch.cos(a)
    ex, ey = -link_length_m * s.sum(-1), link_length_m * c.sum(-1)
    ex_dot, ey_dot = -link_length_m * (c * ad).sum(-1), -link_length_m * (s * ad).sum(-1)
    return torch.atan2(-ex, ey), (ex * ey_dot - ey * ex_dot) / (ex * ex + ey * ey).clamp_min(1e-12)


class ResidualPRBEnsemble(nn.Module):
    """``x' = PRB(x, tau) + r_k(x, tau)`` on joint states ``x = [q, q_dot]`` over ``step_s``: the identified rod's
    Rosenbrock step plus the Gaussian residual of member ``k`` (drawn per row and step)."""

    def __init__(self, params: RodParams, step_s: float, n_members: int, width: int) -> None:
        super().__init__()
        self.params, self.dt_s, self.torque_limit_nm = params, float(step_s), params.torque_limit_nm
        self.n_q = params.n_links + 1
        n_features = 3 * params.n_links + self.n_q + 1
        self.nets = nn.ModuleList([_mlp(n_features, 4 * self.n_q, width) for _ in range(n_members)])
        self.heads = nn.ModuleList([_GaussianHead(2 * self.n_q) for _ in range(n_members)])
        for prefix, size in (("f", n_features), ("r", 2 * self.n_q)):
            self.register_buffer(f"{prefix}_mean", torch.zeros(size))
            self.register_buffer(f"{prefix}_std", torch.ones(size))
        self._chains: dict[int, BatchedPRBChain] = {}
        self._stacked: Optional[_StackedNets] = None
        self.noise_generator: Optional[torch.Generator] = None

    def physics(self, x: Tensor, torque_nm: Tensor) -> Tensor:
        """The identified PRB chain's Rosenbrock step of joint states ``x (B, 2 (n + 1))`` over ``step_s``."""
        batch = x.shape[0]
        if batch not in self._chains:
            self._chains[batch] = BatchedPRBChain(
                self.params, batch_size=batch, dt_s=self.dt_s, integrator="rosenbrock", substeps=1
            )
        q, qd = self._chains[batch].step(x[:, : self.n_q].double(), x[:, self.n_q :].double(), torque_nm.double())
        return torch.cat([q, qd], dim=1).to(x.dtype)

    def features(self, x: Tensor, torque_nm: Tensor) -> Tensor:
        q, qd = x[:, : self.n_q], x[:, self.n_q :]
        a = torch.cumsum(q, 1)[:, 1:]
        return torch.cat([torch.sin(a), torch.cos(a), q[:, 1:], qd, torque_nm.reshape(-1, 1) / self.torque_limit_nm], 1)

    def predict_next(self, x: Tensor, torque_nm: Tensor, generator: Optional[torch.Generator] = None) -> Tensor:
        x = x.float()
        torque_nm = torque_nm.reshape(-1).float().clamp(-self.torque_limit_nm, self.torque_limit_nm)
        z = (self.features(x, torque_nm) - self.f_mean) / self.f_std
        if self._stacked is None:
            self._stacked = _StackedNets(list(self.nets), list(self.heads))
        mean, log_var = self._stacked(z.expand(len(self.nets), -1, -1))
        pick = torch.randint(len(self.nets), (x.shape[0],), generator=generator)
        rows = torch.arange(x.shape[0])
        residual = _sample(mean[pick, rows], log_var[pick, rows], self.noise_generator) * self.r_std + self.r_mean
        return self.physics(x, torque_nm) + residual

    def fit(self, x: np.ndarray, torques_nm: np.ndarray, x_next: np.ndarray, steps: int, seed: int) -> None:
        """Fit the residual networks to joint-state transitions (members on bootstraps)."""
        x_t, u, x1 = (torch.as_tensor(a, dtype=torch.float32) for a in (x, torques_nm, x_next))
        with torch.no_grad():
            residual = x1 - self.physics(x_t, u)
            features = self.features(x_t, u)
        self.f_mean, self.f_std = _standardise(features)
        self.r_mean, self.r_std = _standardise(residual)
        z, y = (features - self.f_mean) / self.f_std, (residual - self.r_mean) / self.r_std
        _fit_gaussian(list(self.nets), list(self.heads), z, y, steps, seed)  # type: ignore[arg-type]
        self._stacked = None


def joint_states(positions: np.ndarray, params: RodParams, dt_s: float) -> np.ndarray:
    """Joint states ``(N - 1, 2 (n + 1))`` of observed positions ``(N, 5)``: reconstructed angles (hub unwrapped)
    and their backward differences."""
    q = reconstruct_joint_states(positions[:, 0], positions[:, 2], positions[:, 3], positions[:, 4], params)
    q[:, 0] = np.unwrap(q[:, 0])
    return np.concatenate([q[1:], np.diff(q, axis=0) / dt_s], axis=1)


class JointStateTracker:
    """The residual model's states ``(B, 2 (n + 1))`` from successive observations ``(B, 10)``, as
    :func:`joint_states` builds them, each reconstruction warm-started from the previous one."""

    def __init__(self, params: RodParams, dt_s: float) -> None:
        self.params, self.dt_s = params, float(dt_s)
        self.reset()

    def reset(self) -> None:
        self._previous: Optional[np.ndarray] = None

    def _angles(self, p: np.ndarray, springs: Optional[np.ndarray]) -> np.ndarray:
        warm: dict[str, Any] = {} if springs is None else dict(iterations=WARM_ITERATIONS, initial_springs_rad=springs)
        return reconstruct_joint_states(p[:, 0], p[:, 2], p[:, 3], p[:, 4], self.params, **warm)

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        if self._previous is None or len(self._previous) != len(observations):
            self._previous = self._angles(observations[:, :5] - self.dt_s * observations[:, 5:], None)
        previous, now = self._previous, self._angles(observations[:, :5], self._previous[:, 1:])
        self._previous = now
        q = now.copy()
        q[:, 0] = previous[:, 0] + wrap_diff(now[:, 0], previous[:, 0])  # the hub unwrapped, as np.unwrap
        return np.concatenate([q, (q - previous) / self.dt_s], axis=1)


class ObservedStateTracker:
    """The black-box model's states ``(B, d)`` from observations ``(B, 10)``, one ``LearnedStateTracker`` per rod."""

    def __init__(self, model: Any) -> None:
        self.model = model
        self.reset()

    def reset(self) -> None:
        self._trackers: list[LearnedStateTracker] = []

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        if len(self._trackers) != len(observations):
            self._trackers = [LearnedStateTracker(self.model) for _ in observations]
        return np.stack(
            [t(Observation.from_array(o), _NO_STATE, _NO_STATE) for t, o in zip(self._trackers, observations)]
        )


@dataclass
class MPPIPlan:
    """One MPPI iteration under way: knots ``(B, K, n_knots)``, rollout torques ``(B K, T)``, states, summed costs."""

    knots: Tensor
    torques: Tensor
    states: Tensor
    cost: Tensor
    steps_taken: int = 0

    @property
    def steps(self) -> int:
        return int(self.torques.shape[1])


class MPPI:
    """Model-predictive path integral control of torques held ``hold_steps`` model steps per knot, from
    ``step_fn(x (R, d), torque (R,)) -> x_next`` and ``cost_fn(x, torque, x_next) -> (R,)``: ``n_samples`` perturbed
    copies of each mean (the first unperturbed, kept alone where every rollout diverged) weighted by
    ``exp(-cost / temperature)``."""

    def __init__(
        self,
        step_fn: Callable[[Tensor, Tensor], Tensor],
        cost_fn: Callable[[Tensor, Tensor, Tensor], Tensor],
        torque_limit_nm: float,
        n_knots: int,
        hold_steps: int,
        n_samples: int,
        noise_std_nm: float,
        temperature: float,
        seed: int = 0,
    ) -> None:
        self.step_fn, self.cost_fn, self.limit = step_fn, cost_fn, float(torque_limit_nm)
        self.n_knots, self.hold_steps, self.n_samples = int(n_knots), int(hold_steps), int(n_samples)
        self.noise_std, self.temperature = float(noise_std_nm), float(temperature)
        self.generator = torch.Generator().manual_seed(int(seed))

    @torch.inference_mode()
    def begin(self, states: np.ndarray | Tensor, mean: Tensor, held_nm: Optional[np.ndarray] = None) -> MPPIPlan:
        """An iteration from ``states (B, d)`` around ``mean (B, n_knots)`` [N m], first holding ``held_nm (B, c)``."""
        x = torch.as_tensor(states, dtype=torch.float32)
        batch, k = x.shape[0], self.n_samples
        noise = self.noise_std * torch.randn(batch, k, self.n_knots, generator=self.generator, dtype=torch.float64)
        noise[:, 0] = 0.0
        knots = (mean[:, None] + noise).clamp(-self.limit, self.limit)
        rolled = knots
        if held_nm is not None:
            held = torch.as_tensor(held_nm, dtype=torch.float64).reshape(batch, 1, -1).expand(-1, k, -1)
            rolled = torch.cat([held, knots], 2)
        torques = rolled.reshape(batch * k, -1).repeat_interleave(self.hold_steps, 1)
        cost = torch.zeros(batch * k, dtype=torch.float64)
        return MPPIPlan(knots, torques, x.repeat_interleave(k, dim=0), cost)

    @torch.inference_mode()
    def advance(self, plan: MPPIPlan, steps: int) -> None:
        """Up to ``steps`` more model steps of ``plan``'s rollouts."""
        for t in range(plan.steps_taken, min(plan.steps_taken + steps, plan.steps)):
            u = plan.torques[:, t]
            x_next = self.step_fn(plan.states, u.float())
            plan.cost += self.cost_fn(plan.states, u, x_next).double()
            plan.states = x_next
            plan.steps_taken = t + 1

    @torch.inference_mode()
    def finish(self, plan: MPPIPlan) -> Tensor:
        """The refined means ``(B, n_knots)`` of a ``plan`` (its remaining steps taken first)."""
        self.advance(plan, plan.steps)
        batch, k = plan.knots.shape[:2]
        cost = plan.cost.reshape(batch, k)
        cost = torch.where(torch.isfinite(cost), cost, torch.full_like(cost, math.inf))
        best = cost.min(1, keepdim=True).values
        weights = torch.softmax(-(cost - torch.where(torch.isfinite(best), best, 0.0)) / self.temperature, 1)
        lost = ~torch.isfinite(best[:, 0])  # every rollout diverged: keep the unperturbed (first) sequence
        weights[lost] = nn.functional.one_hot(torch.zeros(int(lost.sum()), dtype=torch.long), k).to(weights.dtype)
        return (weights[..., None] * plan.knots).sum(1)


def swing_up_cost(params: RodParams, theta_rad: Tensor, theta_dot_rad_s: Tensor) -> Tensor:
    """``1 - cos(theta)`` plus :data:`ENERGY_WEIGHT` times the squared rigid-pendulum energy error (zero upright)
    in units of the hanging energy gap."""
    energy = pendulum_energy_j(params, theta_rad, theta_dot_rad_s, torch.cos)
    return 1.0 - torch.cos(theta_rad) + ENERGY_WEIGHT * (energy / (2 * params.gravity_torque_horizontal_nm)) ** 2


class PlannerController:
    """MPPI on a learned model away from upright, the LQR inside ``capture_rad`` (until ``RELEASE_FACTOR`` times it),
    for one rod (a ``Controller``) or a batch (:meth:`batch_policy`): torques held ``hold_steps`` calls and planned
    ``knots_per_plan`` knots at a time, each plan's work spread over the calls of the knots already committed."""

    def __init__(
        self, mppi: MPPI, tracker: Any, lqr: LQRController, capture_rad: float, hold_steps: int, knots_per_plan: int = 1
    ) -> None:
        self.mppi, self.tracker, self.lqr = mppi, tracker, lqr
        self.capture_rad, self.hold_steps = float(capture_rad), int(hold_steps)
        self.knots_per_plan = int(knots_per_plan)
        self.torque_limit_nm = lqr.torque_limit_nm
        calls = self.hold_steps * self.knots_per_plan
        steps = (self.mppi.n_knots + self.knots_per_plan) * self.mppi.hold_steps
        self._done_by = [(i + 1) * steps // calls for i in range(calls)]
        self.reset()

    def reset(self) -> None:
        self.tracker.reset()
        self._mean: Optional[Tensor] = None
        self._plan: Optional[MPPIPlan] = None

    def torques(self, observations: np.ndarray, time_s: float) -> np.ndarray:
        """Torques ``(B,)`` [N m] for observations ``(B, 10)`` of ``B`` rods (the same ``B`` since :meth:`reset`)."""
        batch, c = len(observations), self.knots_per_plan
        if self._mean is None or len(self._mean) != batch:
            self._mean = torch.zeros(batch, self.mppi.n_knots, dtype=torch.float64)
            self.balancing, self._held, self._next = np.zeros(batch, bool), np.zeros((batch, c)), np.zeros((batch, c))
            self._k, self._plan = 0, None
        states = self.tracker(observations)
        angle = np.abs(observations[:, 1])
        release = self.balancing & (angle > RELEASE_FACTOR * self.capture_rad)
        self._mean[torch.as_tensor(release)] = 0.0
        self._held[release] = 0.0
        self.balancing = (self.balancing & ~release) | (angle < self.capture_rad)
        out = np.empty(batch)
        for i in np.flatnonzero(self.balancing):
            out[i] = self.lqr(Observation.from_array(observations[i]), _NO_STATE, _NO_STATE, time_s)
        phase = self._k % len(self._done_by)
        if phase == 0:
            self._held, self._next = self._next, np.zeros((batch, c))
            self._rows = np.flatnonzero(~self.balancing)
            if self._rows.size:
                rows = self._rows
                self._plan = self.mppi.begin(states[rows], self._mean[torch.as_tensor(rows)], self._held[rows])
        if self._plan is not None:
            self.mppi.advance(self._plan, self._done_by[phase] - self._plan.steps_taken)
            if phase == len(self._done_by) - 1:
                mean = self.mppi.finish(self._plan)
                padded = torch.cat([mean, mean[:, -1:].expand(-1, c)], dim=1)  # the last knot held on
                self._next[self._rows] = padded[:, :c].numpy()
                self._mean[torch.as_tensor(self._rows)] = padded[:, c : c + mean.shape[1]]
                self._plan = None
        planning = ~self.balancing
        out[planning] = self._held[planning, phase // self.hold_steps]
        self._k += 1
        return np.clip(out, -self.torque_limit_nm, self.torque_limit_nm)

    def __call__(self, observation: Observation, q: Any, q_dot: Any, time_s: float) -> float:
        return float(self.torques(observation.as_array()[None], time_s)[0])

    def batch_policy(self) -> BatchPolicy:
        """This controller as a policy of the batched engine: observations in, torque fractions out (the time its
        LQR is handed is 0: it does not read it)."""
        fractions = lambda observations: (self.torques(observations, 0.0) / self.torque_limit_nm)[:, None]  # noqa: E731
        return BatchPolicy(fractions, observed=True, on_reset=self.reset)


@dataclass
class TrialRecord:
    """One stretch of plant time: the excitation or a planner trial (``start_seed`` None)."""

    kind: str
    start_seed: Optional[int]
    plant_s: float
    plant_s_total: float
    balanced: bool
    upright_std_rad: float
    wall_s_total: float


@dataclass
class PlannerResult:
    """Outcome of :func:`run_planner`: the records, the final controller and model, the identified rod."""

    config: PlannerConfig
    records: list[TrialRecord]
    controller: PlannerController
    rod: RodParams
    model: Any

    @property
    def plant_seconds(self) -> float:
        return self.records[-1].plant_s_total

    @property
    def balanced(self) -> bool:
        """Whether the stopping rule fired."""
        n = self.config.stop_after_balanced
        trials = [r for r in self.records if r.kind == "trial"]
        return len(trials) >= n and all(r.balanced for r in trials[-n:])

    @property
    def plant_seconds_to_balance(self) -> float:
        return self.plant_seconds if self.balanced else math.inf


def _run_trial(env: Any, controller: PlannerController, seed: int, config: PlannerConfig) -> tuple[Any, ...]:
    """One trial until held for ``hold_s``, ``trial_s`` or divergence: positions, torques, balanced, RMS angle."""
    env.reset(seed=seed)
    controller.reset()
    dt, limit = env.dt_s, env.torque_limit_nm
    window = int(round(config.hold_s / dt))
    observations, torques, balanced = [env.report_observation.as_array()], [], False
    for k in range(int(round(config.trial_s / dt))):
        torque = min(max(controller(env.report_observation, None, None, k * dt), -limit), limit)
        *_, truncated, _info = env.step(np.array([torque / limit]))
        torques.append(torque)
        observations.append(env.report_observation.as_array())
        if truncated:
            break
        theta = np.array(observations[-window:])[:, 1]
        held = len(theta) == window and np.all(np.abs(theta) < UPRIGHT_RAD)
        if balanced := bool(held and math.sqrt(float(np.mean(theta**2))) <= HOLD_STD_RAD):
            break
    obs = np.array(observations)
    return obs[:, :5], np.array(torques), balanced, float(np.sqrt(np.mean(obs[-window:, 1] ** 2)))


def _fit(config: PlannerConfig, rod: RodParams, trajectories: list[tuple[np.ndarray, np.ndarray]], refit: int) -> Any:
    """The dynamics model of ``config.model`` fitted to the trajectories (positions, torques) so far."""
    task, seed = config.task, config.seed * 1000 + refit
    if config.model == "ensemble":  # states [x, backward difference] from the second sample on
        xv = [np.concatenate([p[1:], backward_difference(p, task.dt_s, _ANGLE_MASK)], 1) for p, _ in trajectories]
        s, s1 = np.concatenate([x[:-1] for x in xv]), np.concatenate([x[1:] for x in xv])
        u = np.concatenate([t[1:] for _, t in trajectories])
        return fit_ensemble(s, u, s1, task, config.replace(seed=seed))
    xs, us, x1s = [], [], []
    h = config.hold_steps  # one model step per control step, under the mean torque over it
    for positions, torques in trajectories:
        x = joint_states(positions, rod, task.dt_s)  # row j is sample j + 1
        rows = np.arange(0, len(x) - h, h)
        xs.append(x[rows])
        us.append(np.array([torques[j + 1 : j + 1 + h].mean() for j in rows]))
        x1s.append(x[rows + h])
    model = ResidualPRBEnsemble(rod, config.control_dt_s, config.ensemble_size, config.hidden_width)
    model.fit(np.concatenate(xs), np.concatenate(us), np.concatenate(x1s), config.train_steps, seed)
    return model


def _controller(
    config: PlannerConfig, rod: RodParams, model: Any, lqr: LQRController, generator: torch.Generator
) -> PlannerController:
    """MPPI on ``model`` (its noise drawn from ``generator``) with the LQR near upright."""
    task, n_q = config.task, rod.n_links + 1
    tracker: Any
    if config.model == "ensemble":
        tracker, fast = ObservedStateTracker(model), StackedEnsemble(model)
        i_theta, i_rate = model.layout.index("theta_rad"), model.layout.index("theta_dot_rad_s")
        tip = lambda x: (x[:, i_theta], x[:, i_rate])  # noqa: E731
    else:
        tracker, fast = JointStateTracker(rod, task.dt_s), model
        tip = lambda x: _tip(x[:, :n_q], x[:, n_q:], rod.link_length_m)  # noqa: E731
    fast.noise_generator = generator
    step = lambda x, torque: fast.predict_next(x, torque, generator=generator)  # noqa: E731
    cost = lambda x, torque, x_next: swing_up_cost(rod, *tip(x_next))  # noqa: E731
    n_knots = config.n_knots - KNOTS_PER_PLAN  # after the knots under way: the rollouts cover horizon_s from now
    hold, limit = (config.hold_steps if config.model == "ensemble" else 1), task.torque_limit_nm
    settings = (config.n_samples, config.noise_fraction * limit, config.temperature)
    mppi = MPPI(step, cost, limit, n_knots, hold, *settings, seed=config.seed)
    return PlannerController(mppi, tracker, lqr, config.capture_rad, config.hold_steps, KNOTS_PER_PLAN)


def run_planner(config: Optional[PlannerConfig] = None, progress: bool = False) -> PlannerResult:
    """Excitation, identification, then planner trials from the selection starts until the stopping rule fires (or
    ``max_trials``), every plant second counted."""
    from softpend.envs import SoftPendulumEnv
    from softpend.torch_threads import one_torch_thread

    config = config if config is not None else PlannerConfig()
    task = config.task
    started = time.perf_counter()
    with one_torch_thread():
        protocol = hanging_protocol(task, config.excitation_s, config.excitation_program)
        data = babble(protocol, params=task.rod, seed=config.seed, plant=task.plant, progress=False)
        plant_s = protocol.n_trials * (protocol.n_samples + protocol.camera_delay_steps) * task.dt_s
        rod = task.rod
        if config.identify_windows:
            guess = rod.replace(**{k: f * getattr(rod, k) for k, f in IDENTIFY_GUESS_FACTORS.items()})
            rod = identify(data, GreyBoxConfig(max_windows=config.identify_windows, seed=config.seed), guess).params
        lqr = LQRController.from_params(rod, dt_s=task.dt_s, state="observation", torque_limit_nm=task.torque_limit_nm)
        generator = torch.Generator().manual_seed(config.seed)
        trajectories = [(p, u) for p, u in zip(data.positions, data.torques_nm) if len(u) >= 3]
        model = _fit(config, rod, trajectories, 0)
        records = [TrialRecord("excitation", None, plant_s, plant_s, False, math.nan, time.perf_counter() - started)]
        env = SoftPendulumEnv(**task.env_kwargs())
        in_a_row = 0
        for index in range(config.max_trials):
            seed = config.selection_seeds[index % len(config.selection_seeds)]
            controller = _controller(config, rod, model, lqr, generator)
            positions, torques, balanced, std = _run_trial(env, controller, seed, config)
            if len(torques) >= 3:
                trajectories.append((positions, torques))
            in_a_row = in_a_row + 1 if balanced else 0
            if in_a_row < config.stop_after_balanced:
                model = _fit(config, rod, trajectories, index + 1)
            plant_s = len(torques) * task.dt_s
            total = records[-1].plant_s_total + plant_s
            r = TrialRecord("trial", seed, plant_s, total, balanced, std, time.perf_counter() - started)
            records.append(r)
            if progress:
                print(
                    f"trial {index}: seed {seed} {r.plant_s:.2f} s (total {r.plant_s_total:.2f} s) balanced "
                    f"{r.balanced} std {r.upright_std_rad:.3f} wall {r.wall_s_total:.0f} s",
                    flush=True,
                )
            if in_a_row >= config.stop_after_balanced:
                break
    return PlannerResult(config, records, _controller(config, rod, model, lqr, generator), rod, model)


def fresh_start_evaluation(
    result: PlannerResult, seeds: Sequence[int], duration_s: float = TEST_EPISODE_S
) -> EvaluationSummary:
    """The final controller from fresh starts (disjoint from the selection starts) on the batched engine."""
    from softpend.torch_threads import one_torch_thread

    shared = sorted(set(int(s) for s in seeds) & set(result.config.selection_seeds))
    if shared:
        raise ValueError(f"seeds must be fresh starts, disjoint from selection_seeds; shared: {shared}")
    with torch.no_grad(), one_torch_thread():
        policy = result.controller.batch_policy()
        return evaluate(
            policy, result.config.task, engine="batched", name="planner", seeds=seeds, duration_s=duration_s
        )
