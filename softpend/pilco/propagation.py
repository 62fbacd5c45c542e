"""State representation, one-step moment-matching propagation and the expected long-term cost."""

from __future__ import annotations

import functools
import logging
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from softpend.checks import one_of
from softpend.pilco.moments import saturating_cost_moments, trig_moments
from softpend.plant import OBSERVATION_NAMES

DTYPE = torch.float64


def _column(obs: np.ndarray, name: str) -> np.ndarray:
    return obs[:, OBSERVATION_NAMES.index(name)]


#: Variables computed from the observation: the rod's bending seen as hub angle minus tip angle.
DERIVED_VARIABLES = {
    "bend_rad": lambda obs: (_column(obs, "phi_rad") - _column(obs, "theta_rad") + np.pi) % (2 * np.pi) - np.pi,
    "bend_dot_rad_s": lambda obs: _column(obs, "phi_dot_rad_s") - _column(obs, "theta_dot_rad_s"),
}


@dataclass(frozen=True)
class StateSpec:
    """Which observed variables form PILCO's state; non-angle variables first, then the angles."""

    name: str
    variables: tuple[str, ...]
    n_angles: int
    tip_angle_index: int

    @property
    def dim(self) -> int:
        return len(self.variables)

    @property
    def tip_rate_index(self) -> int:
        """Index (in ``variables``) of the tip rate ``theta_dot`` [rad/s]."""
        return self.variables.index("theta_dot_rad_s")

    @property
    def angle_indices(self) -> list[int]:
        return list(range(self.dim - self.n_angles, self.dim))

    @property
    def n_model_inputs(self) -> int:
        """Policy input size: non-angle variables plus a (sin, cos) pair per angle."""
        return self.dim - self.n_angles + 2 * self.n_angles

    def from_observations(self, observations: np.ndarray) -> np.ndarray:
        """State rows from observation rows ``(T, 10)`` (:data:`OBSERVATION_NAMES` order), angles unwrapped in time."""
        obs = np.atleast_2d(np.asarray(observations, dtype=float))
        columns = [DERIVED_VARIABLES.get(name, lambda o, n=name: _column(o, n))(obs) for name in self.variables]
        states = np.stack(columns, axis=1)
        states[:, self.angle_indices] = np.unwrap(states[:, self.angle_indices], axis=0)
        return states

    def model_inputs(self, states: np.ndarray) -> np.ndarray:
        """``[non-angle variables, sin a_1, cos a_1, ...]`` for deterministic states ``(T, dim)``."""
        states = np.atleast_2d(np.asarray(states, dtype=float))
        k = self.dim - self.n_angles
        angles = states[:, k:]
        trig = np.stack([np.sin(angles), np.cos(angles)], axis=2).reshape(len(states), -1)
        return np.concatenate([states[:, :k], trig], axis=1)


STATE_SPECS: dict[str, StateSpec] = {
    "hub_tip": StateSpec("hub_tip", ("phi_dot_rad_s", "theta_dot_rad_s", "phi_rad", "theta_rad"), 2, 3),
    "tip": StateSpec("tip", ("theta_dot_rad_s", "theta_rad"), 1, 1),
    "tip_bend": StateSpec("tip_bend", ("theta_dot_rad_s", "bend_dot_rad_s", "bend_rad", "theta_rad"), 1, 3),
}


def state_spec(name: str) -> StateSpec:
    """The :class:`StateSpec` called ``name``; unknown names raise ``ValueError``."""
    return STATE_SPECS[one_of("state", name, STATE_SPECS)]


class Propagator:
    """Moment-matching rollout of a Gaussian state through policy and GP dynamics, with the expected cost."""

    def __init__(
        self,
        spec: StateSpec,
        dynamics,
        policy,
        length_m: float,
        cost_width_m: float,
        cost_rate_width_rad_s: float | None = None,
        exploration: float = 0.0,
        compiled: bool = False,
    ) -> None:
        self.length_m, self.cost_width_m, self.cost_rate_width_rad_s = length_m, cost_width_m, cost_rate_width_rad_s
        self.spec, self.dynamics, self.policy, self.exploration = spec, dynamics, policy, exploration
        d, k, self.compiled = spec.dim, spec.dim - spec.n_angles, compiled
        # positions in the augmented vector [state (d), trig (2A), u]
        model_inputs = tuple(range(k)) + tuple(range(d, d + 2 * spec.n_angles))
        self._layout = _Layout(
            dim=d,
            angles=tuple(spec.angle_indices),
            model_inputs=model_inputs,
            dynamics_inputs=model_inputs + (d + 2 * spec.n_angles,),
            tip_angle=spec.tip_angle_index,
            tip_rate=spec.tip_rate_index if self.cost_rate_width_rad_s is not None else None,
        )
        # (ex, ey) = A @ (sin theta, cos theta) for the point at distance L in the tip's direction; the tip rate
        # is scaled by w / w_r, so that one width w applies to all three coordinates
        self._cost_terms = (
            torch.tensor([0.0, self.length_m], dtype=DTYPE),
            torch.tensor([[-self.length_m, 0.0], [0.0, self.length_m]], dtype=DTYPE),
            torch.tensor(self.cost_width_m, dtype=DTYPE),
            torch.tensor(self.cost_width_m / (self.cost_rate_width_rad_s or 1.0), dtype=DTYPE),
        )

    def rollout(
        self, m0: torch.Tensor, s0: torch.Tensor, n_steps: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Predicted state means (H+1, d), covariances (H+1, d, d), expected costs (H,) and the search
        objective: their total, plus ``exploration`` times the sum of the costs' standard deviations."""
        if n_steps < 1:
            raise ValueError(f"n_steps must be >= 1, got {n_steps!r}")
        means, covs, costs, stds = [m0], [s0], [], []
        policy, dynamics = self.policy.moment_function(), self.dynamics.moment_function()
        step_and_cost = _step_and_cost
        m, s = m0, s0
        if self.compiled and torch.is_grad_enabled():
            step_and_cost = _compiled_step_and_cost()
            # every step's inputs then record gradients, as the first step's must too (one compiled graph)
            m, s = m0.detach().requires_grad_(), s0.detach().requires_grad_()
        for _ in range(n_steps):
            m, s, expected, variance = step_and_cost(self._layout, policy, dynamics, self._cost_terms, m, s)
            means.append(m)
            covs.append(s)
            costs.append(expected)
            if self.exploration != 0.0:
                stds.append(torch.sqrt(torch.clamp(variance, min=1e-12)))
        cost_t = torch.stack(costs)
        objective = cost_t.sum()
        if stds:
            objective = objective + self.exploration * torch.stack(stds).sum()
        return torch.stack(means), torch.stack(covs), cost_t, objective


@dataclass(frozen=True)
class _Layout:
    """Indices of a propagation step: the state's size and angles, the policy's and the dynamics' inputs in the
    augmented vector ``[state (d), trig (2A), u]``, and the cost's tip angle and tip rate (None: no rate term)."""

    dim: int
    angles: tuple[int, ...]
    model_inputs: tuple[int, ...]
    dynamics_inputs: tuple[int, ...]
    tip_angle: int
    tip_rate: int | None


@functools.lru_cache(maxsize=None)
def _index(positions: tuple[int, ...]) -> torch.Tensor:
    """``positions`` as an index tensor (made once)."""
    return torch.tensor(positions)


def _augment(m: torch.Tensor, s: torch.Tensor, m_new: torch.Tensor, s_new: torch.Tensor, cross: torch.Tensor):
    """Append variables with mean ``m_new``, covariance ``s_new`` and ``cov(old, new) = cross``."""
    m_out = torch.cat([m, m_new])
    s_out = torch.cat([torch.cat([s, cross], dim=1), torch.cat([cross.T, s_new], dim=1)], dim=0)
    return m_out, s_out


def _step(
    layout: _Layout, policy: tuple, dynamics: tuple, m: torch.Tensor, s: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """One predicted step; ``policy`` and ``dynamics`` are ``(moment function, its parameters)``."""
    ang = _index(layout.angles)
    m_t, s_t, c_t = trig_moments(m[ang], s[ang][:, ang])
    m_a, s_a = _augment(m, s, m_t, s_t, s[:, ang] @ c_t)
    pi = _index(layout.model_inputs)
    m_u, s_u, c_u = policy[0](m_a[pi], s_a[pi][:, pi], *policy[1])
    cross_u = (s_a[:, pi] @ c_u).unsqueeze(1)
    m_f, s_f = _augment(m_a, s_a, m_u.reshape(1), s_u.reshape(1, 1), cross_u)
    di = _index(layout.dynamics_inputs)
    m_d, s_d, c_d = dynamics[0](m_f[di], s_f[di][:, di], *dynamics[1])
    cross_x = s_f[: layout.dim, di] @ c_d  # cov(x_t, delta)
    m_next = m + m_d
    s_next = s + s_d + cross_x + cross_x.T
    return m_next, 0.5 * (s_next + s_next.T)


def _cost(layout: _Layout, cost_terms: tuple, m: torch.Tensor, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Expected saturating cost and its variance (``cost_terms``: target, tip projection, width, rate scale)."""
    target, a, width, k = cost_terms
    i = layout.tip_angle
    m_t, s_t, c_t = trig_moments(m[i : i + 1], s[i : i + 1, i : i + 1])
    m_z, s_z = a @ m_t, a @ s_t @ a.T
    if layout.tip_rate is None:
        return saturating_cost_moments(m_z, s_z, target, width)
    # append the tip rate scaled by k = w / w_r
    j = layout.tip_rate
    cross = k * (a @ (s[j, i] * c_t[0]))  # cov(position, k theta_dot) = cov(theta_dot, theta) C_trig, projected
    m_z = torch.cat([m_z, k * m[j : j + 1]])
    s_z = torch.cat(
        [torch.cat([s_z, cross.unsqueeze(1)], dim=1), torch.cat([cross, (k * k) * s[j, j].reshape(1)]).unsqueeze(0)],
        dim=0,
    )
    return saturating_cost_moments(m_z, s_z, torch.cat([target, torch.zeros(1, dtype=DTYPE)]), width)


def _step_and_cost(
    layout: _Layout, policy: tuple, dynamics: tuple, cost_terms: tuple, m: torch.Tensor, s: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_step`, then :func:`_cost` of the new state: ``(m, s, expected cost, its variance)``."""
    m, s = _step(layout, policy, dynamics, m, s)
    expected, variance = _cost(layout, cost_terms, m, s)
    return m, s, expected, variance


_COMPILED: list = []


def _compiled_step_and_cost():
    """:func:`_step_and_cost` through ``torch.compile``, or eagerly (with a warning) where the compiler fails."""
    if not _COMPILED:
        logging.getLogger("torch._inductor.ir").addFilter(_quiet_c_shim_notes)
        silence_compiler_notes()
        compiled = torch.compile(
            _step_and_cost, dynamic=False, fullgraph=True, options={"cpp.threads": 1, "cpp_wrapper": True}
        )
        import torch._functorch.config as functorch_config

        cacheable = functorch_config.patch(autograd_cache_allow_custom_autograd_functions=True)
        usable = [True]

        def guarded(*args):
            if not usable[0]:
                return _step_and_cost(*args)
            try:
                with cacheable:
                    return compiled(*args)
            except Exception as exc:  # noqa: BLE001 (no C++ compiler, or an unsupported platform)
                if not _is_compiler_failure(exc):
                    raise
                warnings.warn(
                    f"torch.compile is unavailable ({type(exc).__name__}); PILCO's rollouts run eagerly",
                    RuntimeWarning,
                    stacklevel=2,
                )
                usable[0] = False
                return _step_and_cost(*args)

        _COMPILED.append(guarded)
    return _COMPILED[0]


def silence_compiler_notes() -> None:
    """Ignore the notes torch's compiler warns of while it compiles the rollout step."""
    warnings.filterwarnings("ignore", "Dynamo detected a call to a `functools.lru_cache`", UserWarning, "torch")
    warnings.filterwarnings("ignore", "`torch._prims_common.check` is deprecated", FutureWarning, "torch")


def _quiet_c_shim_notes(record: logging.LogRecord) -> bool:
    """Drop the compiler's note, at every compilation, that ``linalg_lu_solve`` has no C shim."""
    return "c-shim implementation" not in record.getMessage()


def _is_compiler_failure(exc: BaseException) -> bool:
    """Whether ``exc`` says that the compiler itself failed (rather than the computation, e.g. a singular matrix)."""
    from torch._dynamo.exc import BackendCompilerFailed
    from torch._inductor.exc import CppCompileError, InductorError

    return isinstance(exc, (BackendCompilerFailed, CppCompileError, InductorError))
