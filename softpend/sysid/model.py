"""Learned one-step dynamics ``x[t+1] = f(x[t], tau[t])`` in PyTorch: an MLP on standardised features of the
state (sin/cos of angles, lag differences, torque) predicting the standardised change of the core state, or an
ensemble of them; saved as a state dict plus JSON metadata and read back with ``weights_only=True``."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from softpend.checks import one_of, optional_positive, positive, positive_int
from softpend.io.reading import MAX_CONFIG_BYTES, read_json_checked
from softpend.io.torchfiles import load_state, refused, save_state
from softpend.sysid.layout import StateLayout

MODEL_SCHEMA_NAME = "softpend.sysid.model"
MODEL_SCHEMA_VERSION = 1
#: Largest network :func:`load_model` builds from a metadata file [weights over all members].
MAX_LOADED_WEIGHTS = 10**8
ACTIVATIONS: dict[str, type[nn.Module]] = dict(
    tanh=nn.Tanh, softsign=nn.Softsign, relu=nn.ReLU, silu=nn.SiLU, elu=nn.ELU
)


def wrap_tensor(x: Tensor) -> Tensor:
    """Angles wrapped to ``[-pi, pi)``."""
    return torch.remainder(x + math.pi, 2 * math.pi) - math.pi


def check_widths(hidden_widths: Sequence[int]) -> tuple[int, ...]:
    """The hidden layer widths as a non-empty tuple of positive ints, else ``ValueError``."""
    widths = tuple(positive_int("hidden_widths", w) for w in hidden_widths)
    if not widths:
        raise ValueError("hidden_widths must hold at least one width")
    return widths


class DynamicsModel(nn.Module):
    """One learned one-step dynamics model for states of ``layout`` at step ``dt_s``, torques clipped to
    ``torque_limit_nm``.  ``integrate_positions``: predict the velocity change and integrate positions (exact for
    backward-difference velocities); a predicted tip beyond ``tip_reach_m`` is pulled back radially onto it."""

    _angle_idx: Tensor
    _linear_idx: Tensor
    _core_angle_mask: Tensor
    _lag_angle_mask: Tensor
    _tip_idx: Tensor
    feature_mean: Tensor
    feature_std: Tensor
    feature_low: Tensor
    feature_high: Tensor
    delta_mean: Tensor
    delta_std: Tensor

    def __init__(
        self,
        layout: StateLayout,
        dt_s: float,
        torque_limit_nm: float,
        hidden_widths: Sequence[int] = (16, 16, 16),
        activation: str = "silu",
        integrate_positions: bool = True,
        tip_reach_m: Optional[float] = None,
    ) -> None:
        super().__init__()
        one_of("activation", activation, ACTIVATIONS)
        self.layout = layout
        self.dt_s = positive("dt_s", dt_s)
        self.torque_limit_nm = positive("torque_limit_nm", torque_limit_nm)
        self.hidden_widths = check_widths(hidden_widths)
        self.activation = activation
        self.integrate_positions = bool(integrate_positions)
        self.tip_reach_m = optional_positive("tip_reach_m", tip_reach_m)
        p, mask = layout.n_positions, layout.position_angle_mask
        self._p, self._h, self._core = p, layout.history, layout.core_dim
        self.n_outputs = p if self.integrate_positions else self._core
        names = layout.names  # every layout holds the tip
        indices = {
            "_angle_idx": torch.as_tensor(np.flatnonzero(mask), dtype=torch.long),
            "_linear_idx": torch.as_tensor(np.flatnonzero(~mask), dtype=torch.long),
            "_core_angle_mask": torch.as_tensor(np.concatenate([mask, np.zeros(p, bool)])),
            "_lag_angle_mask": torch.as_tensor(np.tile(mask, max(self._h, 1))[: p * self._h]),
            "_tip_idx": torch.tensor([names.index("ex_m"), names.index("ey_m")]),
        }
        for name, value in indices.items():
            self.register_buffer(name, value, persistent=False)
        # theta = atan2(-ex, ey) in the data: derived from the predicted tip, not predicted
        self._derive_theta = all(n in names for n in ("theta_rad", "ex_m", "ey_m"))
        if self._derive_theta:
            self._i_theta, self._i_ex, self._i_ey = (names.index(n) for n in ("theta_rad", "ex_m", "ey_m"))
        self.n_features = 2 * p + int(mask.sum()) + p * self._h + 1  # sin, cos of angles; the rest once; torque
        fills = {"feature_mean": 0.0, "feature_std": 1.0, "feature_low": -math.inf, "feature_high": math.inf}
        for name, fill in (fills | {"delta_mean": 0.0, "delta_std": 1.0}).items():
            size = self.n_outputs if name.startswith("delta") else self.n_features
            self.register_buffer(name, torch.full((size,), fill, dtype=torch.float32))
        widths = (self.n_features, *self.hidden_widths)
        hidden = [(nn.Linear(a, b, dtype=torch.float32), ACTIVATIONS[activation]()) for a, b in zip(widths, widths[1:])]
        self.net = nn.Sequential(*sum(hidden, ()), nn.Linear(widths[-1], self.n_outputs, dtype=torch.float32))

    def features(self, state: Tensor, torque_nm: Tensor) -> Tensor:
        """Raw (not standardised) network input features, shape ``(B, n_features)``."""
        p, h = self._p, self._h
        pos = state[:, :p]
        angles = pos.index_select(1, self._angle_idx)
        parts = [torch.sin(angles), torch.cos(angles), pos.index_select(1, self._linear_idx), state[:, p : 2 * p]]
        if h:
            rel = pos.repeat(1, h) - state[:, 2 * p :]  # the lagged frames relative to now
            parts.append(torch.where(self._lag_angle_mask, wrap_tensor(rel), rel))
        parts.append(torque_nm.reshape(-1, 1))
        return torch.cat(parts, dim=1)

    def target_delta(self, state: Tensor, next_state: Tensor) -> Tensor:
        """What the network learns (before standardisation): the velocity change, or the core-state change."""
        if self.integrate_positions:
            p = self._p
            return next_state[:, p : 2 * p] - state[:, p : 2 * p]
        delta = next_state[:, : self._core] - state[:, : self._core]
        return torch.where(self._core_angle_mask, wrap_tensor(delta), delta)

    def normalise_features(self, features: Tensor) -> Tensor:
        """Standardise features with the stored training statistics and clamp them to the training box."""
        return torch.clamp((features - self.feature_mean) / self.feature_std, self.feature_low, self.feature_high)

    def set_feature_box(self, low: Tensor, high: Tensor, margin: float = 0.1) -> None:
        """Clamp standardised features to ``[low, high]`` widened by ``margin`` of the range on each side."""
        low, high = (torch.as_tensor(v, dtype=self.feature_low.dtype) for v in (low, high))
        span = (high - low).clamp_min(1e-6)
        self.feature_low.copy_(low - margin * span)
        self.feature_high.copy_(high + margin * span)

    def set_normalisation(
        self, feature_mean: Tensor, feature_std: Tensor, delta_mean: Tensor, delta_std: Tensor
    ) -> None:
        """Store the training-set statistics (standard deviations below 1e-12 are replaced by 1)."""
        values = (feature_mean, feature_std, delta_mean, delta_std)
        for name, value in zip(("feature_mean", "feature_std", "delta_mean", "delta_std"), values):
            buffer = getattr(self, name)
            value = torch.as_tensor(value, dtype=buffer.dtype)
            if name.endswith("std"):
                value = torch.where(value > 1e-12, value, torch.ones_like(value))
            buffer.copy_(value)

    def _check(self, state: Tensor, torque_nm: Tensor) -> tuple[Tensor, Tensor]:
        if state.ndim != 2 or state.shape[1] != self.layout.dim:
            raise ValueError(f"state must have shape (B, {self.layout.dim}), got {tuple(state.shape)}")
        torque_nm = torque_nm.reshape(-1)
        if torque_nm.shape[0] != state.shape[0]:
            raise ValueError(f"torque_nm must have shape ({state.shape[0]},), got {tuple(torque_nm.shape)}")
        dtype = self.feature_mean.dtype  # float32 by default; follows model.double()
        return state.to(dtype), torque_nm.to(dtype)

    def predict_delta(self, state: Tensor, torque_nm: Tensor) -> Tensor:
        """Predicted core-state change over one step, in the report's units, shape ``(B, 2P)``."""
        state, torque_nm = self._check(state, torque_nm)
        torque_nm = torque_nm.clamp(-self.torque_limit_nm, self.torque_limit_nm)
        out = self.net(self.normalise_features(self.features(state, torque_nm))) * self.delta_std + self.delta_mean
        if not self.integrate_positions:
            return out
        p = self._p
        return torch.cat([self.dt_s * (state[:, p : 2 * p] + out), out], dim=1)

    def next_from_delta(self, state: Tensor, delta: Tensor) -> Tensor:
        """Apply a core-state change: add, wrap angles, shift the lagged frames."""
        core = state[:, : self._core] + delta
        core = torch.where(self._core_angle_mask, wrap_tensor(core), core)
        if self.tip_reach_m is not None:
            core = self._within_reach(state, core)
        if self._derive_theta:
            core = self._with_derived_theta(state, core)
        if not self._h:
            return core
        p = self._p
        previous = torch.where(self._core_angle_mask[:p], wrap_tensor(state[:, :p]), state[:, :p])
        return torch.cat([core, previous, state[:, 2 * p : 2 * p + p * (self._h - 1)]], dim=1)

    def _within_reach(self, state: Tensor, core: Tensor) -> Tensor:
        """Pull a tip predicted beyond ``tip_reach_m`` radially back onto the circle of that radius."""
        p, tip = self._p, self._tip_idx
        assert self.tip_reach_m is not None  # called only with a reach
        radius = torch.hypot(core[:, tip[0]], core[:, tip[1]])
        over = radius > self.tip_reach_m
        if not bool(over.any()):  # the usual case: nothing to do (and no copy)
            return core
        shrink = torch.where(over, self.tip_reach_m / radius.clamp_min(1e-12), torch.ones_like(radius))
        corrected = core[:, tip] * shrink[:, None]
        core = core.clone()
        core[:, tip] = corrected
        if self.integrate_positions:  # the backward-difference rate of the corrected position
            core[:, p + tip] = (corrected - state[:, tip]) / self.dt_s
        return core

    def _with_derived_theta(self, state: Tensor, core: Tensor) -> Tensor:
        p, i = self._p, self._i_theta
        ex, ey = core[:, self._i_ex], core[:, self._i_ey]
        theta = torch.atan2(-ex, ey)
        if self.integrate_positions:  # differenced velocities: the rate is the wrapped increment over dt
            rate = wrap_tensor(theta - state[:, i]) / self.dt_s
        else:  # true velocities: d/dt atan2(-ex, ey)
            ex_dot, ey_dot = core[:, p + self._i_ex], core[:, p + self._i_ey]
            rate = (ex * ey_dot - ey * ex_dot) / (ex * ex + ey * ey).clamp_min(1e-12)
        return torch.cat(
            [core[:, :i], theta[:, None], core[:, i + 1 : p + i], rate[:, None], core[:, p + i + 1 :]], dim=1
        )

    def predict_next(self, state: Tensor, torque_nm: Tensor, generator: Optional[torch.Generator] = None) -> Tensor:
        """Next state ``(B, d)`` from states ``(B, d)`` and torques ``(B,)`` [N m]; ``generator`` is ignored."""
        state, torque_nm = self._check(state, torque_nm)
        return self.next_from_delta(state, self.predict_delta(state, torque_nm))

    def config(self) -> dict[str, Any]:
        """Constructor arguments (for JSON metadata)."""
        names = ("dt_s", "torque_limit_nm", "activation", "integrate_positions", "tip_reach_m")
        return {"layout": dataclasses.asdict(self.layout), "hidden_widths": list(self.hidden_widths)} | {
            name: getattr(self, name) for name in names
        }


class DynamicsEnsemble(nn.Module):
    """:class:`DynamicsModel` members of one configuration; :meth:`predict_next` uses a random member per row (from
    ``generator``), member ``k``, or the mean of the members' predicted changes (``"mean"``)."""

    def __init__(self, members: Sequence[DynamicsModel]) -> None:
        super().__init__()
        members = list(members)
        if not all(isinstance(m, DynamicsModel) for m in members) or len({str(m.config()) for m in members}) != 1:
            raise ValueError("members must be a non-empty list of DynamicsModel of one configuration")
        # nn.ModuleList is not generic in torch's stubs: at run time it holds exactly these DynamicsModels
        self.members: Sequence[DynamicsModel] = nn.ModuleList(members)  # type: ignore[assignment]
        self.layout, self.dt_s, self.torque_limit_nm = members[0].layout, members[0].dt_s, members[0].torque_limit_nm

    def __len__(self) -> int:
        return len(self.members)

    def predict_next(
        self,
        state: Tensor,
        torque_nm: Tensor,
        generator: Optional[torch.Generator] = None,
        member: int | str | None = None,
    ) -> Tensor:
        if isinstance(member, int) and not isinstance(member, bool):
            if not 0 <= member < len(self.members):
                raise ValueError(f"member must be in [0, {len(self.members)}), got {member}")
            return self.members[member].predict_next(state, torque_nm)
        if member not in (None, "mean"):
            raise ValueError(f"member must be an int, 'mean' or None, got {member!r}")
        first = self.members[0]
        state, torque_nm = first._check(state, torque_nm)
        if member is None and len(self.members) == 1:
            return first.predict_next(state, torque_nm)
        deltas = torch.stack([m.predict_delta(state, torque_nm) for m in self.members])  # (K, B, 2P)
        if member == "mean":
            return first.next_from_delta(state, deltas.mean(0))
        pick = torch.randint(len(self.members), (state.shape[0],), generator=generator, device=state.device)
        return first.next_from_delta(state, deltas[pick, torch.arange(state.shape[0], device=state.device)])

    def config(self) -> dict[str, Any]:
        """Members' constructor arguments plus the ensemble size."""
        return dict(self.members[0].config(), ensemble_size=len(self.members))


def model_paths(path: str | Path) -> tuple[Path, Path]:
    """``(<path>.pt, <path>.json)``, the two files of :func:`save_model` (``path`` may end in either suffix)."""
    path = Path(path)
    stem = path.with_suffix("") if path.suffix in (".pt", ".json") else path
    return stem.with_name(stem.name + ".pt"), stem.with_name(stem.name + ".json")


def save_model(
    path: str | Path, model: DynamicsModel | DynamicsEnsemble, metadata: Optional[dict[str, Any]] = None
) -> tuple[Path, Path]:
    """Write ``<path>.pt`` (state dict) and ``<path>.json`` (architecture and ``metadata``); returns both paths."""
    from softpend import __version__

    weights, meta_path = model_paths(path)
    kind = "ensemble" if isinstance(model, DynamicsEnsemble) else "single"
    meta = dict(schema=MODEL_SCHEMA_NAME, schema_version=MODEL_SCHEMA_VERSION, softpend_version=__version__, kind=kind)
    meta |= {"config": model.config(), "metadata": metadata or {}}
    text = json.dumps(meta, indent=2, sort_keys=True, allow_nan=False)
    save_state(weights, model.state_dict(), meta_path, text + "\n")
    return weights, meta_path


def load_model(path: str | Path) -> tuple[DynamicsModel | DynamicsEnsemble, dict[str, Any]]:
    """``(model in eval mode, metadata)`` of :func:`save_model`'s files; ``ValueError`` if they are missing, of
    another schema, or do not match each other."""
    weights, meta_path = model_paths(path)
    for p in (weights, meta_path):
        if not p.exists():
            raise ValueError(f"model file not found: {p}")
    meta = read_json_checked(meta_path, "model metadata file", MAX_CONFIG_BYTES)  # a regular file, bounded
    schema = (MODEL_SCHEMA_NAME, MODEL_SCHEMA_VERSION)
    if not isinstance(meta, dict) or (meta.get("schema"), meta.get("schema_version")) != schema:
        raise ValueError(f"{meta_path}: not a {MODEL_SCHEMA_NAME} v{MODEL_SCHEMA_VERSION} file")
    try:
        config = dict(meta["config"])
        size = positive_int("ensemble_size", config.pop("ensemble_size", 1))
        widths = [positive_int("hidden_widths", w) for w in config.get("hidden_widths", ())]
        edges = [64] + widths + [64]  # generous input and output widths
        n_weights = size * sum((a + 1) * b for a, b in zip(edges[:-1], edges[1:]))
        if n_weights > MAX_LOADED_WEIGHTS:
            raise ValueError(f"the network would have about {n_weights:.3g} weights, above {MAX_LOADED_WEIGHTS:.0e}")
        config["layout"] = StateLayout(**config["layout"])
        members = [DynamicsModel(**config) for _ in range(size)]
        model: DynamicsModel | DynamicsEnsemble = (
            DynamicsEnsemble(members) if meta["kind"] == "ensemble" else members[0]
        )
        if not isinstance(meta["metadata"], dict):
            raise TypeError(f"metadata must be an object, got {type(meta['metadata']).__name__}")
    except (KeyError, TypeError, ValueError, AttributeError, RuntimeError) as exc:
        raise ValueError(f"{meta_path}: not a model of this version ({type(exc).__name__}: {exc})") from None
    failure = f"{weights}: weights do not match {meta_path} or are not weights written by softpend"
    with refused(failure):  # a regular file no larger than the weights the metadata allows (float32, and the format)
        model.load_state_dict(load_state(weights, "model weights file", MAX_CONFIG_BYTES + 8 * n_weights), strict=True)
    model.eval()
    return model, meta["metadata"]


def rollout(model: Any, x0: Tensor, torques_nm: Tensor, generator: Optional[torch.Generator] = None) -> Tensor:
    """``x0 (B, d)`` followed by the ``T`` states a model (anything with ``predict_next``; an ensemble draws its
    members from ``generator``) predicts under torques ``(B, T)``: shape ``(B, T + 1, d)``."""
    if x0.ndim != 2:
        raise ValueError(f"x0 must have shape (B, d), got {tuple(x0.shape)}")
    if torques_nm.ndim != 2 or torques_nm.shape[0] != x0.shape[0]:
        raise ValueError(f"torques_nm must have shape ({x0.shape[0]}, T), got {tuple(torques_nm.shape)}")
    steps = [x0]
    for t in range(torques_nm.shape[1]):
        steps.append(model.predict_next(steps[-1], torques_nm[:, t], generator=generator))
    return torch.stack(steps, dim=1)
