"""Fit a learned dynamics model (or an ensemble) to a babbling dataset.

One-step regression of the standardised core-state change (see :mod:`softpend.sysid.model`) with Adam
on minibatches, a validation split *by trial* (whole trials are held out, so validation transitions
are not neighbours of training ones), learning-rate halving on a validation plateau, early stopping
with the best validation weights restored, and a progress bar.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

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
    non_negative,
    one_of,
    positive_int,
)
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.layout import StateLayout, TransitionData
from softpend.sysid.model import ACTIVATIONS, DynamicsEnsemble, DynamicsModel

__all__ = ["TrainConfig", "FitResult", "fit_dynamics_model", "split_trials"]


@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of :func:`fit_dynamics_model`.

    Parameters
    ----------
    information : {"full", "limited"}
        Information level (:class:`softpend.sysid.StateLayout`).
    history : int
        Past position frames in the state (limited information only).
    velocity_source : {"observed", "true"}
        Differenced (rig-like, default) or the simulator's true velocities (full information only).
    hidden_widths : tuple of int
        Hidden layer widths (the report's ``(16, 16, 16)``).
    activation : str
        Hidden activation (``silu`` default: smooth, so linearisations are well defined, and cheap).
    integrate_positions : bool, optional
        Predict only the velocity change and integrate positions with ``x[t+1] = x[t] + dt v[t+1]``
        (exact for backward-difference velocities); ``None`` = yes for observed velocities, no for true.
    limit_tip_reach : bool
        Keep predicted tip positions within the rod's reach (the dataset's ``length_m``, or for a rig file
        without plant parameters the largest tip distance recorded, plus 1 % slack): see ``tip_reach_m``
        of :class:`softpend.sysid.DynamicsModel`.
    ensemble_size : int
        Number of members (1 = a single :class:`DynamicsModel`).
    bootstrap : bool
        Train each ensemble member on a bootstrap resample of the training transitions.
    max_epochs : int
        Upper limit on passes over the training set (one-step loss).
    rollout_steps, rollout_epochs : int
        After the one-step fit, fine-tune for ``rollout_epochs`` epochs on the multi-step loss: the
        model's own ``rollout_steps``-step open-loop predictions from every training state, compared
        with the data (0 = no fine-tuning, the report's plain one-step fit).
    batch_size : int
        Minibatch size.
    learning_rate : float
        Initial Adam step size.
    lr_schedule : {"cosine", "plateau"}
        Cosine annealing of the step size to 1 % over ``max_epochs``, or halving after ``patience // 3``
        epochs without a validation improvement.
    weight_decay : float
        Adam weight decay.
    patience : int
        Early stopping: epochs without a validation improvement before stopping.
    validation_fraction : float
        Fraction of trials held out for validation (at least one trial).
    seed : int
        Seed of the split, the initial weights, the bootstrap and the minibatch order.
    """

    information: str = "full"
    history: int = 0
    velocity_source: str = "observed"
    hidden_widths: tuple[int, ...] = (16, 16, 16)
    activation: str = "silu"
    integrate_positions: Optional[bool] = None
    limit_tip_reach: bool = True
    ensemble_size: int = 1
    bootstrap: bool = True
    max_epochs: int = 300
    rollout_steps: int = 0
    rollout_epochs: int = 0
    batch_size: int = 512
    learning_rate: float = 5e-3
    lr_schedule: str = "cosine"
    weight_decay: float = 0.0
    patience: int = 30
    validation_fraction: float = 0.2
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_widths", tuple(self.hidden_widths))
        self.layout()  # validates information, history, velocity_source
        if self.integrate_positions is None:
            object.__setattr__(self, "integrate_positions", self.velocity_source == "observed")
        if not isinstance(self.integrate_positions, bool):
            raise ValueError(f"integrate_positions must be a bool or None, got {self.integrate_positions!r}")
        boolean("limit_tip_reach", self.limit_tip_reach)
        if not self.hidden_widths or any(
            isinstance(w, bool) or not isinstance(w, int) or w < 1 for w in self.hidden_widths
        ):
            raise ValueError(f"hidden_widths must be positive integers, got {self.hidden_widths!r}")
        one_of("activation", self.activation, ACTIVATIONS)
        for name in ("rollout_steps", "rollout_epochs", "seed"):
            object.__setattr__(self, name, int_at_least(name, getattr(self, name), 0))
        for name in ("ensemble_size", "max_epochs", "batch_size", "patience"):
            object.__setattr__(self, name, positive_int(name, getattr(self, name)))
        in_range("learning_rate", self.learning_rate, 1e-12, 1e30)  # Adam's step, lr / (1 - beta1), stays a float32
        one_of("lr_schedule", self.lr_schedule, ("cosine", "plateau"))
        non_negative("weight_decay", self.weight_decay)
        in_unit_interval("validation_fraction", self.validation_fraction, include_zero=False, include_one=False)

    def layout(self) -> StateLayout:
        """The state layout these settings describe."""
        return StateLayout(self.information, self.history, self.velocity_source)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON metadata)."""
        out = dataclasses.asdict(self)
        out["hidden_widths"] = list(self.hidden_widths)
        return out

    def replace(self, **changes: Any) -> "TrainConfig":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


@dataclass
class FitResult:
    """What :func:`fit_dynamics_model` returns.

    Attributes
    ----------
    model : DynamicsModel or DynamicsEnsemble
        The trained model (eval mode), best validation weights.
    config : TrainConfig
        Settings used.
    train_trials, val_trials : ndarray of int
        Trial indices of the dataset used for training and for validation.
    train_loss, val_loss : list of ndarray
        Per member, the loss (mean squared standardised change) after each epoch.
    best_epochs : list of int
        Per member, the epoch whose weights were kept (1-based).
    multistep_train_loss, multistep_val_loss : list of ndarray
        Per member, the multi-step loss after each fine-tuning epoch (empty without fine-tuning).
    train_time_s : float
        Wall time of the fit [s].
    """

    model: DynamicsModel | DynamicsEnsemble
    config: TrainConfig
    train_trials: np.ndarray
    val_trials: np.ndarray
    train_loss: list[np.ndarray] = field(default_factory=list)
    val_loss: list[np.ndarray] = field(default_factory=list)
    best_epochs: list[int] = field(default_factory=list)
    multistep_train_loss: list[np.ndarray] = field(default_factory=list)
    multistep_val_loss: list[np.ndarray] = field(default_factory=list)
    train_time_s: float = 0.0

    def metadata(self) -> dict[str, Any]:
        """JSON-ready summary (config, split, losses) for :func:`softpend.sysid.save_model`."""
        return {
            "train_config": self.config.to_dict(),
            "train_trials": self.train_trials.tolist(),
            "val_trials": self.val_trials.tolist(),
            "best_epochs": list(self.best_epochs),
            "best_val_loss": [float(v[b - 1]) for v, b in zip(self.val_loss, self.best_epochs)],
            "train_time_s": self.train_time_s,
        }


def split_trials(n_trials: int, validation_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random split of trial indices into (train, validation), both sorted; at least one of each."""
    if n_trials < 2:
        raise ValueError(f"need at least 2 trials to split off validation trials, got n_trials={n_trials}")
    n_val = min(n_trials - 1, max(1, int(round(validation_fraction * n_trials))))
    order = np.random.default_rng(seed).permutation(n_trials)
    return np.sort(order[n_val:]), np.sort(order[:n_val])


#: Slack of the tip-reach limit, as a fraction of the reach: a wall exactly at the rod length also clips
#: the small prediction errors of a nearly straight rod (measured: 1 % slack gives 12.0 mm at 0.5 s where
#: the exact length gives 14.3 mm and no limit 12.5 mm; every limit keeps 2 s rollouts on the rod's scale).
TIP_REACH_SLACK = 0.01


def _tip_reach_m(dataset: TrajectoryDataset) -> Optional[float]:
    """The rod length [m] of a simulated dataset, else the largest recorded tip distance, plus
    :data:`TIP_REACH_SLACK` (``None`` without a tip position)."""
    if dataset.params is not None:
        return float(dataset.params.length_m) * (1 + TIP_REACH_SLACK)
    if not all(n in dataset.position_names for n in ("ex_m", "ey_m")):
        return None
    radius = float(np.hypot(dataset.column("ex_m"), dataset.column("ey_m")).max())
    return radius * (1 + TIP_REACH_SLACK) if radius > 0 else None


def _statistics(model: DynamicsModel, data: TransitionData) -> tuple[torch.Tensor, ...]:
    """Feature and target standardisation statistics, computed in float64."""
    s = torch.as_tensor(data.states, dtype=torch.float64)
    s1 = torch.as_tensor(data.next_states, dtype=torch.float64)
    u = torch.as_tensor(data.torques_nm, dtype=torch.float64)
    probe = copy.deepcopy(model).double()
    feats = probe.features(s, u)
    deltas = probe.target_delta(s, s1)
    return feats.mean(0), feats.std(0), deltas.mean(0), deltas.std(0)


def _tensors(model: DynamicsModel, data: TransitionData) -> tuple[torch.Tensor, torch.Tensor]:
    """Standardised (features, target changes) in the model's dtype."""
    probe = copy.deepcopy(model).double()
    s = torch.as_tensor(data.states, dtype=torch.float64)
    s1 = torch.as_tensor(data.next_states, dtype=torch.float64)
    u = torch.as_tensor(data.torques_nm, dtype=torch.float64)
    x = probe.normalise_features(probe.features(s, u))
    y = (probe.target_delta(s, s1) - probe.delta_mean) / probe.delta_std
    dtype = model.feature_mean.dtype
    return x.to(dtype).contiguous(), y.to(dtype).contiguous()


def _train_member(
    model: DynamicsModel,
    x_train: torch.Tensor,
    y_train: torch.Tensor,
    x_val: torch.Tensor,
    y_val: torch.Tensor,
    config: TrainConfig,
    generator: torch.Generator,
    progress: bool,
    desc: str,
) -> tuple[np.ndarray, np.ndarray, int]:
    net = model.net
    optimiser = torch.optim.Adam(net.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    scheduler: torch.optim.lr_scheduler.LRScheduler
    if config.lr_schedule == "cosine":
        scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
            optimiser, T_max=config.max_epochs, eta_min=config.learning_rate / 100
        )
    else:
        scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(
            optimiser, factor=0.5, patience=max(1, config.patience // 3)
        )
    n = x_train.shape[0]
    best = (math.inf, 0, copy.deepcopy(net.state_dict()))
    train_losses: list[float] = []
    val_losses: list[float] = []
    bar = tqdm(range(1, config.max_epochs + 1), desc=desc, unit="epoch", disable=not progress, leave=False)
    for epoch in bar:
        net.train()
        order = torch.randperm(n, generator=generator)
        total = 0.0
        for start in range(0, n, config.batch_size):
            batch = order[start : start + config.batch_size]
            loss = torch.mean((net(x_train[batch]) - y_train[batch]) ** 2)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            total += float(loss.detach()) * batch.shape[0]
        net.eval()
        with torch.no_grad():
            val = float(torch.mean((net(x_val) - y_val) ** 2))
        _check_finite_loss(desc, epoch, total / n, val, config)
        train_losses.append(total / n)
        val_losses.append(val)
        scheduler.step(val) if isinstance(scheduler, torch.optim.lr_scheduler.ReduceLROnPlateau) else scheduler.step()
        if val < best[0] * (1 - 1e-4):
            best = (val, epoch, copy.deepcopy(net.state_dict()))
        bar.set_postfix(train=f"{total / n:.2e}", val=f"{val:.2e}", best=best[1])
        if epoch - best[1] >= config.patience:
            break
    bar.close()
    net.load_state_dict(best[2])
    net.eval()
    return np.array(train_losses), np.array(val_losses), best[1]


def _check_fit_size(layout: StateLayout, dataset: TrajectoryDataset, config: TrainConfig) -> None:
    """``ValueError`` before any work if the fit's arrays would exceed :data:`softpend.checks.MAX_WORK_BYTES`:
    the transitions (states, next states and features, a few copies) and every member's weights (with Adam's
    moments and the best-epoch copy)."""
    dim = layout.dim
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


def _check_finite_loss(desc: str, epoch: int, train_loss: float, val_loss: float, config: TrainConfig) -> None:
    """``NonFiniteError`` if an epoch's training or validation loss is NaN or infinite (the fit diverged; the
    weights kept would be the untrained ones or garbage)."""
    if not (math.isfinite(train_loss) and math.isfinite(val_loss)):
        raise NonFiniteError(
            f"dynamics model fit diverged ({desc}, epoch {epoch}): training loss {train_loss!r}, validation loss "
            f"{val_loss!r} (lower learning_rate, now {config.learning_rate!r})"
        )


def _windows(
    layout: StateLayout, dataset: TrajectoryDataset, trials: np.ndarray, steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """All windows of ``steps + 1`` consecutive states (and their ``steps`` torques) of the trials."""
    states = layout.states(dataset)[trials]
    torques = layout.torques(dataset)[trials]
    n = states.shape[1] - steps
    if n < 1:
        raise ValueError(f"rollout_steps={steps} is longer than the trials ({states.shape[1]} states)")
    idx = np.arange(n)[:, None] + np.arange(steps + 1)[None, :]
    return states[:, idx].reshape(-1, steps + 1, layout.dim), torques[:, idx[:, :-1]].reshape(-1, steps)


def _multistep_loss(
    model: DynamicsModel, states: torch.Tensor, torques: torch.Tensor, scale: torch.Tensor
) -> torch.Tensor:
    """Mean squared scaled core-state error of the model's open-loop predictions over a window."""
    x = states[:, 0]
    core = model.layout.core_dim
    mask = torch.as_tensor(model.layout.angle_mask[:core])
    total = states.new_zeros(())
    for j in range(torques.shape[1]):
        x = model.predict_next(x, torques[:, j])
        err = x[:, :core] - states[:, j + 1, :core]
        err = torch.where(mask, torch.remainder(err + math.pi, 2 * math.pi) - math.pi, err)
        total = total + torch.mean((err / scale) ** 2)
    return total / torques.shape[1]


def _finetune_multistep(
    model: DynamicsModel,
    train: tuple[np.ndarray, np.ndarray],
    val: tuple[np.ndarray, np.ndarray],
    scale: torch.Tensor,
    config: TrainConfig,
    generator: torch.Generator,
    progress: bool,
    desc: str,
) -> tuple[np.ndarray, np.ndarray]:
    dtype = model.feature_mean.dtype
    xs, us = (torch.as_tensor(a, dtype=dtype) for a in train)
    vs, vu = (torch.as_tensor(a, dtype=dtype) for a in val)
    optimiser = torch.optim.Adam(model.net.parameters(), lr=config.learning_rate / 10)
    best = (math.inf, copy.deepcopy(model.net.state_dict()))
    train_losses: list[float] = []
    val_losses: list[float] = []
    with torch.no_grad():
        best = (float(_multistep_loss(model, vs, vu, scale)), best[1])
    bar = tqdm(range(1, config.rollout_epochs + 1), desc=desc, unit="epoch", disable=not progress, leave=False)
    for _ in bar:
        order = torch.randperm(xs.shape[0], generator=generator)
        total = 0.0
        for start in range(0, xs.shape[0], config.batch_size):
            batch = order[start : start + config.batch_size]
            loss = _multistep_loss(model, xs[batch], us[batch], scale)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            total += float(loss.detach()) * batch.shape[0]
        with torch.no_grad():
            val_loss = float(_multistep_loss(model, vs, vu, scale))
        _check_finite_loss(desc, len(train_losses) + 1, total / xs.shape[0], val_loss, config)
        train_losses.append(total / xs.shape[0])
        val_losses.append(val_loss)
        if val_loss < best[0]:
            best = (val_loss, copy.deepcopy(model.net.state_dict()))
        bar.set_postfix(train=f"{total / xs.shape[0]:.2e}", val=f"{val_loss:.2e}")
    bar.close()
    model.net.load_state_dict(best[1])
    return np.array(train_losses), np.array(val_losses)


def fit_dynamics_model(
    dataset: TrajectoryDataset,
    config: Optional[TrainConfig] = None,
    progress: bool = True,
    **overrides: Any,
) -> FitResult:
    """Train a dynamics model on a dataset.

    Parameters
    ----------
    dataset : TrajectoryDataset
        Babbling (or rig) data, at least 2 trials.
    config : TrainConfig, optional
        Settings (default ``TrainConfig()``: full information, 3 x 16, one model).
    progress : bool
        Show progress bars (one per member, over epochs).
    **overrides
        Fields of :class:`TrainConfig` to change, e.g. ``hidden_widths=(64, 64)``, ``ensemble_size=5``.

    Returns
    -------
    FitResult
        The model and the training record.

    Raises
    ------
    ValueError
        On invalid settings, or a dataset that lacks the layout's variables.
    NonFiniteError
        If a training or validation loss becomes NaN or infinite (the fit diverged).
    """
    if not isinstance(dataset, TrajectoryDataset):
        raise ValueError(f"dataset must be a TrajectoryDataset, got {type(dataset).__name__}")
    config = config if config is not None else TrainConfig()
    if not isinstance(config, TrainConfig):
        raise ValueError(f"config must be a TrainConfig, got {type(config).__name__}")
    if overrides:
        config = config.replace(**overrides)
    started = time.perf_counter()
    layout = config.layout()
    _check_fit_size(layout, dataset, config)
    train_trials, val_trials = split_trials(dataset.n_trials, config.validation_fraction, config.seed)
    train = layout.transitions(dataset, train_trials)
    val = layout.transitions(dataset, val_trials)
    params = dataset.params
    # without plant parameters (a rig file), the largest recorded torque stands in for the limit
    limit = params.torque_limit_nm if params is not None else float(np.abs(dataset.torques_nm).max())
    if limit <= 0:
        raise ValueError(
            "dataset torques_nm are all zero and it has no plant_params: nothing to learn the torque's effect from"
        )

    reach = _tip_reach_m(dataset) if config.limit_tip_reach else None

    def new_member(index: int) -> DynamicsModel:
        assert config.integrate_positions is not None  # set in TrainConfig.__post_init__
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed * 1000 + index)
            return DynamicsModel(
                layout,
                dataset.dt_s,
                limit,
                config.hidden_widths,
                config.activation,
                config.integrate_positions,
                tip_reach_m=reach,
            )

    members = [new_member(k) for k in range(config.ensemble_size)]
    stats = _statistics(members[0], train)
    for m in members:
        m.set_normalisation(*stats)
    x_train, y_train = _tensors(members[0], train)
    x_val, y_val = _tensors(members[0], val)
    for m in members:
        m.set_feature_box(x_train.min(0).values, x_train.max(0).values)
    result = FitResult(model=members[0], config=config, train_trials=train_trials, val_trials=val_trials)
    if config.rollout_steps and config.rollout_epochs:
        windows_train = _windows(layout, dataset, train_trials, config.rollout_steps)
        windows_val = _windows(layout, dataset, val_trials, config.rollout_steps)
        change = train.next_states[:, : layout.core_dim] - train.states[:, : layout.core_dim]
        mask = layout.angle_mask[: layout.core_dim]
        change[:, mask] = (change[:, mask] + np.pi) % (2 * np.pi) - np.pi
        core_scale = torch.as_tensor(np.maximum(change.std(0), 1e-12), dtype=members[0].feature_mean.dtype)
    for k, member in enumerate(members):
        generator = torch.Generator().manual_seed(config.seed * 1000 + k)
        if config.ensemble_size > 1 and config.bootstrap:
            pick = torch.randint(x_train.shape[0], (x_train.shape[0],), generator=generator)
            xk, yk = x_train[pick], y_train[pick]
        else:
            xk, yk = x_train, y_train
        desc = "training" if config.ensemble_size == 1 else f"training member {k + 1}/{config.ensemble_size}"
        tl, vl, best = _train_member(member, xk, yk, x_val, y_val, config, generator, progress, desc)
        result.train_loss.append(tl)
        result.val_loss.append(vl)
        result.best_epochs.append(best)
        if config.rollout_steps and config.rollout_epochs:
            mtl, mvl = _finetune_multistep(
                member, windows_train, windows_val, core_scale, config, generator, progress, desc + " (multi-step)"
            )
            result.multistep_train_loss.append(mtl)
            result.multistep_val_loss.append(mvl)
    result.model = members[0] if config.ensemble_size == 1 else DynamicsEnsemble(members).eval()
    result.train_time_s = time.perf_counter() - started
    return result


def parse_widths(widths: Sequence[int] | str) -> tuple[int, ...]:
    """Parse ``"16,16,16"`` or a sequence into a tuple of ints (for the command line)."""
    if isinstance(widths, str):
        try:
            return tuple(int(w) for w in widths.split(",") if w.strip())
        except ValueError as exc:
            raise ValueError(f"hidden_widths must be comma-separated integers, got {widths!r}") from exc
    return tuple(int(w) for w in widths)
