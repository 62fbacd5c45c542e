"""Fit a learned dynamics model (or an ensemble) to a babbling dataset: one-step regression with Adam, a
validation split by trial, early stopping on the best validation weights."""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
import torch
from tqdm.auto import tqdm

from softpend.checks import (
    NonFiniteError,
    boolean,
    check_work_size,
    in_range,
    in_unit_interval,
    int_at_least,
    one_of,
    positive_int,
)
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.layout import StateLayout, TransitionData
from softpend.sysid.model import ACTIVATIONS, DynamicsEnsemble, DynamicsModel, check_widths


@dataclass(frozen=True)
class TrainConfig:
    """Settings of :func:`fit_dynamics_model` (ensemble members train on bootstraps of the transitions; the model
    integrates positions from observed velocities); ``limit_tip_reach`` keeps predicted tips within the rod's reach
    plus :data:`TIP_REACH_SLACK`."""

    information: str = "full"
    history: int = 0
    velocity_source: str = "observed"
    hidden_widths: tuple[int, ...] = (16, 16, 16)
    activation: str = "silu"
    limit_tip_reach: bool = True
    ensemble_size: int = 1
    max_epochs: int = 300
    batch_size: int = 512
    learning_rate: float = 5e-3
    patience: int = 30
    validation_fraction: float = 0.2
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_widths", check_widths(self.hidden_widths))
        self.layout()  # validates information, history, velocity_source
        boolean("limit_tip_reach", self.limit_tip_reach)
        one_of("activation", self.activation, ACTIVATIONS)
        object.__setattr__(self, "seed", int_at_least("seed", self.seed, 0))
        for name in ("ensemble_size", "max_epochs", "batch_size", "patience"):
            object.__setattr__(self, name, positive_int(name, getattr(self, name)))
        in_range("learning_rate", self.learning_rate, 1e-12, 1e30)  # Adam's step, lr / (1 - beta1), stays a float32
        in_unit_interval("validation_fraction", self.validation_fraction, include_zero=False, include_one=False)

    def layout(self) -> StateLayout:
        """The state layout these settings describe."""
        return StateLayout(self.information, self.history, self.velocity_source)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON metadata)."""
        return dataclasses.asdict(self) | {"hidden_widths": list(self.hidden_widths)}


@dataclass
class FitResult:
    """What :func:`fit_dynamics_model` returns: the model (best validation weights), settings, split, and per
    member the losses after each epoch and the epoch kept (1-based)."""

    model: DynamicsModel | DynamicsEnsemble
    config: TrainConfig
    train_trials: np.ndarray
    val_trials: np.ndarray
    train_loss: list[np.ndarray] = field(default_factory=list)
    val_loss: list[np.ndarray] = field(default_factory=list)
    best_epochs: list[int] = field(default_factory=list)
    train_time_s: float = 0.0

    def metadata(self) -> dict[str, Any]:
        """JSON-ready summary (config, split, losses) for :func:`softpend.sysid.save_model`."""
        out = {"train_config": self.config.to_dict(), "train_trials": self.train_trials.tolist()}
        out |= {"val_trials": self.val_trials.tolist(), "best_epochs": list(self.best_epochs)}
        best = [float(v[b - 1]) for v, b in zip(self.val_loss, self.best_epochs)]
        return out | {"best_val_loss": best, "train_time_s": self.train_time_s}


def split_trials(n_trials: int, validation_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random split of trial indices into (train, validation), both sorted; at least one of each."""
    if n_trials < 2:
        raise ValueError(f"need at least 2 trials to split off validation trials, got n_trials={n_trials}")
    n_val = min(n_trials - 1, max(1, int(round(validation_fraction * n_trials))))
    order = np.random.default_rng(seed).permutation(n_trials)
    return np.sort(order[n_val:]), np.sort(order[:n_val])


#: Slack of the tip-reach limit, as a fraction of the reach.
TIP_REACH_SLACK = 0.01


def _features_and_targets(
    model: DynamicsModel, data: TransitionData
) -> tuple[DynamicsModel, torch.Tensor, torch.Tensor]:
    """A float64 copy of the model, the raw features and the target changes."""
    probe = copy.deepcopy(model).double()
    s, s1, u = (torch.as_tensor(a, dtype=torch.float64) for a in (data.states, data.next_states, data.torques_nm))
    return probe, probe.features(s, u), probe.target_delta(s, s1)


def _tensors(model: DynamicsModel, data: TransitionData) -> tuple[torch.Tensor, torch.Tensor]:
    """Standardised (features, target changes) in the model's dtype."""
    probe, features, targets = _features_and_targets(model, data)
    x = probe.normalise_features(features)
    y = (targets - probe.delta_mean) / probe.delta_std
    dtype = model.feature_mean.dtype
    return x.to(dtype).contiguous(), y.to(dtype).contiguous()


def _train(
    net: torch.nn.Module,
    x: torch.Tensor,
    y: torch.Tensor,
    x_val: torch.Tensor,
    y_val: torch.Tensor,
    config: TrainConfig,
    generator: torch.Generator,
    progress: bool,
    desc: str,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Adam on minibatches with cosine annealing, early stopping on the validation loss; the losses and best epoch."""
    optimiser = torch.optim.Adam(net.parameters(), lr=config.learning_rate)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
        optimiser, T_max=config.max_epochs, eta_min=config.learning_rate / 100
    )
    best = (math.inf, 0, copy.deepcopy(net.state_dict()))
    losses: list[tuple[float, float]] = []  # training and validation, per epoch
    n = len(x)
    bar = tqdm(range(1, config.max_epochs + 1), desc=desc, unit="epoch", disable=not progress, leave=False)
    for epoch in bar:
        net.train()
        order = torch.randperm(n, generator=generator)
        train = 0.0
        for start in range(0, n, config.batch_size):
            batch = order[start : start + config.batch_size]
            loss = torch.mean((net(x[batch]) - y[batch]) ** 2)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            train += float(loss.detach()) * batch.shape[0]
        train /= n
        net.eval()
        with torch.no_grad():
            val = float(torch.mean((net(x_val) - y_val) ** 2))
        if not (math.isfinite(train) and math.isfinite(val)):
            raise NonFiniteError(
                f"dynamics model fit diverged ({desc}, epoch {epoch}): training loss {train!r}, validation loss "
                f"{val!r} (lower learning_rate, now {config.learning_rate!r})"
            )
        losses.append((train, val))
        scheduler.step()
        if val < best[0] * (1 - 1e-4):
            best = (val, epoch, copy.deepcopy(net.state_dict()))
        bar.set_postfix(train=f"{train:.2e}", val=f"{val:.2e}", best=best[1])
        if epoch - best[1] >= config.patience:
            break
    bar.close()
    net.load_state_dict(best[2])
    net.eval()
    return np.array(losses)[:, 0], np.array(losses)[:, 1], best[1]


def fit_dynamics_model(
    dataset: TrajectoryDataset, config: Optional[TrainConfig] = None, progress: bool = True, **overrides: Any
) -> FitResult:
    """Train a dynamics model (``config`` with ``overrides`` of its fields) on a dataset of at least 2 trials;
    raises ``ValueError`` on invalid settings or data, ``NonFiniteError`` if a loss becomes NaN or infinite."""
    config = dataclasses.replace(config if config is not None else TrainConfig(), **overrides)
    started = time.perf_counter()
    layout = config.layout()
    dim = layout.dim  # the work size checked before any work
    transitions = dataset.n_trials * max(dataset.n_samples - 1, 1)
    data = 8.0 * 8 * transitions * (dim + 1)
    widths = [2 * dim + 1, *config.hidden_widths, dim]
    weights = sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:]))
    networks = 8.0 * 5 * config.ensemble_size * weights + 8.0 * 4 * min(config.batch_size, transitions) * sum(widths)
    check_work_size(
        "this dynamics model fit",
        data + networks,
        f"{transitions} transitions of a {dim}-dimensional state, {config.ensemble_size} member(s) of {weights} weights",
    )
    train_trials, val_trials = split_trials(dataset.n_trials, config.validation_fraction, config.seed)
    train, val = (layout.transitions(dataset, trials) for trials in (train_trials, val_trials))
    params = dataset.params
    # without plant parameters (a rig file), the largest recorded torque stands in for the limit
    limit = params.torque_limit_nm if params is not None else float(np.abs(dataset.torques_nm).max())
    if limit <= 0:
        raise ValueError("dataset torques_nm are all zero and it has no plant_params (nothing to learn from)")
    # the rod length of a simulated dataset, else the largest recorded tip distance, plus the slack
    radius = float(params.length_m if params else np.hypot(dataset.column("ex_m"), dataset.column("ey_m")).max())
    reach = radius * (1 + TIP_REACH_SLACK) if config.limit_tip_reach and radius > 0 else None
    positions = config.velocity_source == "observed"  # integrated from differenced velocities
    members = []
    for index in range(config.ensemble_size):
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed * 1000 + index)
            members.append(
                DynamicsModel(layout, dataset.dt_s, limit, config.hidden_widths, config.activation, positions, reach)
            )
    _, features, targets = _features_and_targets(members[0], train)
    stats = features.mean(0), features.std(0), targets.mean(0), targets.std(0)
    for m in members:
        m.set_normalisation(*stats)
    (x_train, y_train), (x_val, y_val) = (_tensors(members[0], data) for data in (train, val))
    for m in members:
        m.set_feature_box(x_train.min(0).values, x_train.max(0).values)
    result = FitResult(model=members[0], config=config, train_trials=train_trials, val_trials=val_trials)
    for k, member in enumerate(members):
        generator = torch.Generator().manual_seed(config.seed * 1000 + k)
        n = x_train.shape[0]  # a bootstrap of the transitions for each member of an ensemble
        pick = torch.randint(n, (n,), generator=generator) if config.ensemble_size > 1 else slice(None)
        desc = "training" if config.ensemble_size == 1 else f"training member {k + 1}/{config.ensemble_size}"
        tl, vl, best = _train(member.net, x_train[pick], y_train[pick], x_val, y_val, config, generator, progress, desc)
        result.train_loss.append(tl)
        result.val_loss.append(vl)
        result.best_epochs.append(best)
    result.model = members[0] if config.ensemble_size == 1 else DynamicsEnsemble(members).eval()
    result.train_time_s = time.perf_counter() - started
    return result
