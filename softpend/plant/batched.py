"""A batched, differentiable PRB chain in PyTorch: the equations of :class:`softpend.plant.PRBPlant` for many rods.

Internally the state is the absolute angles ``x = cumsum(q)``; the links' mass matrix is ``M_ij = G_ij cos(a_i - a_j)``
with constant ``G``, solved by a Cholesky factorisation written out over the batch.  Integrators: ``"rk4"``
(sub-steps from :func:`stable_substeps`) and ``"rosenbrock"`` (ROS2, linearly implicit in the springs and dampers).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np
import torch

from softpend.checks import boolean, int_at_least, one_of, positive
from softpend.plant.observation import energies
from softpend.plant.params import MAX_N_LINKS, POSITIVE_FIELDS, RodParams

#: The per-rod parameters of :class:`BatchedRodParams`: every float field of :class:`RodParams`.
PARAMETER_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(RodParams) if f.name != "n_links")

_POSITIVE = (*POSITIVE_FIELDS, "hub_inertia_kgm2")

#: ``|lambda| h`` allowed by :func:`stable_substeps` (inside RK4's stability region).
RK4_STABILITY_BOUND = 2.5

#: The integrators of :class:`BatchedPRBChain`.
INTEGRATORS = ("rk4", "rosenbrock")

#: Most sub-steps per control step.
MAX_SUBSTEPS = 1000

TensorLike = Union[torch.Tensor, np.ndarray, Sequence[float], float]


@dataclass(frozen=True)
class BatchedRodParams:
    """``B`` rods of one ``n_links``: every float field of :class:`~softpend.plant.RodParams` as a tensor ``(B,)``
    (may require gradients); checked as :class:`RodParams`, with ``hub_inertia_kgm2`` positive."""

    n_links: int
    length_m: torch.Tensor
    mass_kg: torch.Tensor
    width_m: torch.Tensor
    depth_m: torch.Tensor
    youngs_modulus_pa: torch.Tensor
    joint_damping_nms_per_rad: torch.Tensor
    tip_mass_kg: torch.Tensor
    hub_inertia_kgm2: torch.Tensor
    hub_friction_nms_per_rad: torch.Tensor
    torque_limit_nm: torch.Tensor
    gravity_mps2: torch.Tensor
    stiffness_scale: torch.Tensor

    def __post_init__(self) -> None:
        n_links = int_at_least("n_links", self.n_links, 1)
        if n_links > MAX_N_LINKS:
            raise ValueError(f"n_links must be at most {MAX_N_LINKS}, got {self.n_links!r}")
        object.__setattr__(self, "n_links", n_links)
        shape = getattr(self.length_m, "shape", None)
        for name in PARAMETER_FIELDS:
            value = getattr(self, name)
            if not (isinstance(value, torch.Tensor) and value.is_floating_point() and value.ndim == 1):
                raise ValueError(
                    f"{name} must be a floating-point torch tensor of shape (B,), got {type(value).__name__}"
                )
            if value.shape != shape or not value.shape[0]:
                raise ValueError(f"{name} has shape {tuple(value.shape)}, the other parameters {tuple(shape or ())}")
            detached = value.detach()
            low = float(detached.min())
            if not bool(torch.isfinite(detached).all()) or (low <= 0 if name in _POSITIVE else low < 0):
                sign = "positive" if name in _POSITIVE else "non-negative"
                raise ValueError(f"{name} must be finite and {sign} for every rod, got {detached.tolist()[:8]}")

    @property
    def batch_size(self) -> int:
        return int(self.length_m.shape[0])

    @classmethod
    def from_params(
        cls,
        params: Union[RodParams, Sequence[RodParams], None] = None,
        batch_size: Optional[int] = None,
        dtype: torch.dtype = torch.float64,
    ) -> "BatchedRodParams":
        """One rod repeated ``batch_size`` times, or a list of rods of one ``n_links``."""
        one = params is None or isinstance(params, RodParams)
        rods: list[RodParams] = [params or RodParams()] if one else list(params)  # type: ignore[list-item,arg-type]
        if not rods or not all(isinstance(r, RodParams) for r in rods):
            raise ValueError("params must be a RodParams or a non-empty sequence of RodParams")
        size = (1 if one else len(rods)) if batch_size is None else int_at_least("batch_size", batch_size, 1)
        if not one and size != len(rods):
            raise ValueError(f"batch_size is {batch_size} but params holds {len(rods)} rods")
        if len({r.n_links for r in rods}) != 1:
            raise ValueError(f"params must all have the same n_links, got {sorted({r.n_links for r in rods})}")
        columns = {name: torch.tensor([getattr(r, name) for r in rods], dtype=dtype) for name in PARAMETER_FIELDS}
        return cls(rods[0].n_links, **{n: c.expand(size).clone() if one else c for n, c in columns.items()})

    @property
    def dtype(self) -> torch.dtype:
        return self.length_m.dtype


class _Derived:
    """Per-rod constants of the equations, batch last: ``(B,)`` per rod, ``(n, B)`` per link, ``gram`` ``(n, n, B)``."""

    def __init__(self, p: BatchedRodParams) -> None:
        n = p.n_links
        self.link_length_m = length = p.length_m / n
        m_link = p.mass_kg / n
        last = torch.eye(n, dtype=p.dtype)[:, -1:]  # 1 for the last link, else 0
        masses = m_link + last * p.tip_mass_kg
        first = m_link * length / 2 + last * (p.tip_mass_kg * length)
        second = m_link * length**2 / 3 + last * (p.tip_mass_kg * length**2)
        beyond = torch.flip(torch.cumsum(torch.flip(masses, [0]), 0), [0]) - masses  # mass outboard of link i
        self.first_moment_kgm = h = first + length * beyond
        self.gram_diagonal = diagonal = second + length**2 * beyond
        index = torch.arange(n)
        gram = length * h[torch.maximum(index[:, None], index[None, :])]  # (n, n, B): L h_max(i, j)
        self.gram = torch.where(
            (index[:, None] == index[None, :])[:, :, None], diagonal[:, None, :].expand(n, n, -1), gram
        )
        self.length_times_h = length * h
        self.gram_diagonal_minus_lh = diagonal - length * h
        self.gravity_moment_nm = p.gravity_mps2 * h
        k = p.youngs_modulus_pa * p.width_m * p.depth_m**3 / 12.0 * p.stiffness_scale / length
        clamp = 1.0 + torch.eye(n, dtype=p.dtype)[:, :1]  # 2 at the clamp, else 1
        self.stiffness_nm_per_rad = clamp * k  # clamp first
        self.damping_nms_per_rad = clamp * p.joint_damping_nms_per_rad
        self.negative_stiffness = -(clamp * k)
        self.negative_damping = -(clamp * p.joint_damping_nms_per_rad)
        self.hub_inertia_kgm2 = p.hub_inertia_kgm2
        self.inverse_hub_inertia = 1.0 / p.hub_inertia_kgm2
        self.hub_friction_nms_per_rad = p.hub_friction_nms_per_rad
        self.torque_limit_nm = p.torque_limit_nm


#: Longest chain solved with the written-out Cholesky factorisation; longer ones use batched LAPACK.
UNROLLED_SOLVE_MAX_LINKS = 12


def _cholesky_factor(
    diagonal: torch.Tensor, below: list[torch.Tensor]
) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Cholesky factor of ``M`` given by its diagonal ``(n, B)`` and its columns below it (``below[j]``: rows
    ``j + 1..`` of column ``j``), as the reciprocals of the factor's diagonal and its columns below it."""
    n = diagonal.shape[0]
    inverse_diagonal: list[torch.Tensor] = []
    lower: list[torch.Tensor] = []
    for j in range(n):
        d, column = diagonal[j], below[j]
        for k in range(j):
            lk = lower[k]
            ljk = lk[j - k - 1]
            d = torch.addcmul(d, ljk, ljk, value=-1.0)
            if j < n - 1:
                column = torch.addcmul(column, lk[j - k :], ljk, value=-1.0)
        r = torch.rsqrt(d)
        inverse_diagonal.append(r)
        lower.append(column * r)
    return inverse_diagonal, lower


def _cholesky_substitute(factor: tuple[list[torch.Tensor], list[torch.Tensor]], rhs: torch.Tensor) -> torch.Tensor:
    """Solve ``L L' x = rhs`` (``rhs`` of shape ``(n, B)``) with a factor from :func:`_cholesky_factor`."""
    inverse_diagonal, lower = factor
    n = rhs.shape[0]
    y: list[torch.Tensor] = []
    rest = rhs
    for j in range(n):
        yj = rest[0] * inverse_diagonal[j]
        y.append(yj)
        if j < n - 1:
            rest = torch.addcmul(rest[1:], lower[j], yj, value=-1.0)
    x: list[Optional[torch.Tensor]] = [None] * n
    for i in range(n - 1, -1, -1):
        xi = y[i] * inverse_diagonal[i]
        x[i] = xi
        for k in range(i):
            y[k] = torch.addcmul(y[k], lower[k][i - k - 1], xi, value=-1.0)
    return torch.stack(x)  # type: ignore[arg-type]


def _gram_times(d: _Derived, w: torch.Tensor) -> torch.Tensor:
    """``G w`` along dimension ``-2`` of ``w`` in O(n), from ``G_ij = L h_max(i, j)`` off the diagonal."""
    hw = d.first_moment_kgm * w
    tail = hw.sum(-2, keepdim=True) - torch.cumsum(hw, -2)
    return torch.addcmul(
        torch.addcmul(d.gram_diagonal_minus_lh * w, d.length_times_h, torch.cumsum(w, -2)), d.link_length_m, tail
    )


def _forces(d: _Derived, x: torch.Tensor, v: torch.Tensor, torque: torch.Tensor):
    """Right-hand sides ``J phi_dd`` and ``M(a) a_dd``, and the links' cosines and sines."""
    a, ad = x[1:], v[1:]
    s, c = torch.sin(a), torch.cos(a)
    tau = torch.addcmul(d.negative_stiffness * (a - x[:-1]), d.negative_damping, ad - v[:-1])
    force = torch.cat([tau[:-1] - tau[1:], tau[-1:]]) if tau.shape[0] > 1 else tau
    ad2 = ad * ad
    sums = _gram_times(d, torch.stack([c, s]) * ad2)
    rhs = torch.addcmul(torch.addcmul(torch.addcmul(force, d.gravity_moment_nm, s), s, sums[0], value=-1.0), c, sums[1])
    hub = torch.addcmul(torque - tau[0], d.hub_friction_nms_per_rad, v[0], value=-1.0)
    return hub, rhs, c, s


def _mass_below(d: _Derived, c: torch.Tensor, s: torch.Tensor) -> list[torch.Tensor]:
    """The links' mass matrix below its diagonal, column by column."""
    n = c.shape[0]
    return [d.length_times_h[j + 1 :] * torch.addcmul(c[j + 1 :] * c[j], s[j + 1 :], s[j]) for j in range(n)]


def _dense_mass(d: _Derived, c: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """The links' mass matrix ``(B, n, n)``."""
    return (d.gram * (c[:, None] * c[None] + s[:, None] * s[None])).permute(2, 0, 1)


def _accelerations(d: _Derived, x: torch.Tensor, v: torch.Tensor, torque: torch.Tensor) -> torch.Tensor:
    """``x_dd`` for absolute angles ``x``, rates ``v`` and the hub torque."""
    hub, rhs, c, s = _forces(d, x, v, torque)
    n = c.shape[0]
    if n <= UNROLLED_SOLVE_MAX_LINKS:
        a_dd = _cholesky_substitute(_cholesky_factor(d.gram_diagonal, _mass_below(d, c, s)), rhs)
    else:
        a_dd = torch.linalg.solve(_dense_mass(d, c, s), rhs.T).T
    return torch.cat([(hub * d.inverse_hub_inertia)[None], a_dd])


def _mass_times(d: _Derived, c: torch.Tensor, s: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """``M(a) w`` in O(n) (``M_ij = G_ij (c_i c_j + s_i s_j)``)."""
    g = _gram_times(d, torch.stack([c * w, s * w]))
    return torch.addcmul(c * g[0], s, g[1])


def _spring_times(k: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """The spring chain's stiffness (or damping) matrix, coefficients ``k`` clamp first, times ``w``."""
    e = k * (w[1:] - w[:-1])
    if e.shape[0] == 1:
        return torch.cat([-e, e])
    return torch.cat([-e[:1], e[:-1] - e[1:], e[-1:]])


#: The diagonal coefficient of ROS2.
ROS2_GAMMA = 1.0 - 1.0 / math.sqrt(2.0)

#: Default sub-steps per control step of the Rosenbrock integrator.
ROSENBROCK_SUBSTEPS = 2


class _RosenbrockMatrix:
    """The factorised ``S = M + gamma h D + (gamma h)**2 K``, the hub eliminated onto the first link first."""

    def __init__(self, d: _Derived, c: torch.Tensor, s: torch.Tensor, gamma_h: float) -> None:
        e = torch.add(gamma_h * d.damping_nms_per_rad, d.stiffness_nm_per_rad, alpha=gamma_h * gamma_h)
        self.clamp = e[0]
        self.hub = torch.add(d.hub_inertia_kgm2 + self.clamp, d.hub_friction_nms_per_rad, alpha=gamma_h)
        self.inverse_hub = 1.0 / self.hub
        n = c.shape[0]
        diagonal = d.gram_diagonal + e
        if n > 1:
            diagonal = torch.cat([diagonal[:-1] + e[1:], diagonal[-1:]])
        diagonal = torch.cat([(diagonal[0] - self.clamp * self.clamp * self.inverse_hub)[None], diagonal[1:]])
        self.dense = n > UNROLLED_SOLVE_MAX_LINKS
        if self.dense:
            matrix = _dense_mass(d, c, s)
            index = torch.arange(n)
            matrix[:, index, index] = diagonal.T
            if n > 1:
                matrix[:, index[1:], index[:-1]] -= e[1:].T
                matrix[:, index[:-1], index[1:]] -= e[1:].T
            self.factor = torch.linalg.cholesky(matrix)
        else:
            below = _mass_below(d, c, s)
            below = [
                torch.cat([(column[0] - e[j + 1])[None], column[1:]]) if j < n - 1 else column
                for j, column in enumerate(below)
            ]
            self.factor = _cholesky_factor(diagonal, below)

    def solve(self, hub_rhs: torch.Tensor, link_rhs: torch.Tensor) -> torch.Tensor:
        """``S^{-1} r`` for ``r = (hub_rhs, link_rhs)``, as one ``(n + 1, B)`` tensor (hub first)."""
        first = torch.addcmul(link_rhs[0], self.clamp * self.inverse_hub, hub_rhs)
        rhs = torch.cat([first[None], link_rhs[1:]])
        if self.dense:
            links = torch.cholesky_solve(rhs.T[:, :, None], self.factor)[:, :, 0].T
        else:
            links = _cholesky_substitute(self.factor, rhs)
        hub = torch.addcmul(hub_rhs, self.clamp, links[0]) * self.inverse_hub
        return torch.cat([hub[None], links])


def _rosenbrock_step(
    d: _Derived, x: torch.Tensor, v: torch.Tensor, torque: torch.Tensor, h: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """One step of ``h`` of ROS2 (Verwer et al. 1999), ``W = I - gamma h J`` for the springs and dampers:
    ``k1 = W^-1 f(y)``, ``k2 = W^-1 (f(y + h k1) - 2 k1)``, ``y+ = y + h (3/2 k1 + 1/2 k2)``."""
    gamma_h = ROS2_GAMMA * h
    hub, rhs, c, s = _forces(d, x, v, torque)
    matrix = _RosenbrockMatrix(d, c, s, gamma_h)
    k = d.stiffness_nm_per_rad
    spring_v = _spring_times(k, v)
    kv1 = matrix.solve(torch.add(hub, spring_v[0], alpha=-gamma_h), torch.add(rhs, spring_v[1:], alpha=-gamma_h))
    kx1 = torch.add(v, kv1, alpha=gamma_h)
    x2, v2 = torch.add(x, kx1, alpha=h), torch.add(v, kv1, alpha=h)
    rv2 = torch.add(_accelerations(d, x2, v2, torque), kv1, alpha=-2.0)
    rx2 = torch.add(v2, kx1, alpha=-2.0)
    spring_x = _spring_times(k, rx2)
    kv2 = matrix.solve(
        torch.addcmul(-gamma_h * spring_x[0], d.hub_inertia_kgm2, rv2[0]),
        torch.add(_mass_times(d, c, s, rv2[1:]), spring_x[1:], alpha=-gamma_h),
    )
    kx2 = torch.add(rx2, kv2, alpha=gamma_h)
    return (
        torch.add(x, torch.add(kx2, kx1, alpha=3.0), alpha=h / 2),
        torch.add(v, torch.add(kv2, kv1, alpha=3.0), alpha=h / 2),
    )


def stable_substeps(params: Union[RodParams, BatchedRodParams], dt_s: float = 0.01) -> int:
    """RK4 sub-steps per ``dt_s`` keeping ``|lambda| h <=`` :data:`RK4_STABILITY_BOUND` for every rod, ``lambda``
    the eigenvalues of the chain linearised about the straight rod hanging at rest."""
    positive("dt_s", dt_s)
    p = params if isinstance(params, BatchedRodParams) else BatchedRodParams.from_params(params)
    d = _Derived(
        BatchedRodParams(n_links=p.n_links, **{f: getattr(p, f).detach().to(torch.float64) for f in PARAMETER_FIELDS})
    )
    n, size = p.n_links, p.batch_size
    mass = torch.zeros(size, n + 1, n + 1, dtype=torch.float64)
    mass[:, 0, 0] = d.hub_inertia_kgm2
    mass[:, 1:, 1:] = d.gram.permute(2, 0, 1)
    difference = torch.diff(torch.eye(n + 1, dtype=torch.float64), dim=0)  # spring angles from the coordinates
    stiffness, damping = (
        torch.einsum("ki,bk,kj->bij", difference, k.T, difference)
        for k in (d.stiffness_nm_per_rad, d.damping_nms_per_rad)
    )
    stiffness[:, 1:, 1:] += torch.diag_embed(d.gravity_moment_nm.T)
    damping[:, 0, 0] += d.hub_friction_nms_per_rad
    inv_mass = torch.linalg.inv(mass)
    top = torch.cat([torch.zeros_like(mass), torch.eye(n + 1, dtype=torch.float64).expand(size, -1, -1)], dim=2)
    bottom = torch.cat([-inv_mass @ stiffness, -inv_mass @ damping], dim=2)
    largest = float(torch.linalg.eigvals(torch.cat([top, bottom], dim=1)).abs().max())
    return max(1, math.ceil(largest * dt_s / RK4_STABILITY_BOUND))


def _integrate(
    integrator: str, substeps: int, h: float, d: _Derived, x: torch.Tensor, v: torch.Tensor, torque: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    acc = _accelerations
    for _ in range(substeps):
        if integrator == "rosenbrock":
            x, v = _rosenbrock_step(d, x, v, torque, h)
            continue
        a1 = acc(d, x, v, torque)
        x2, v2 = torch.add(x, v, alpha=h / 2), torch.add(v, a1, alpha=h / 2)
        a2 = acc(d, x2, v2, torque)
        x3, v3 = torch.add(x, v2, alpha=h / 2), torch.add(v, a2, alpha=h / 2)
        a3 = acc(d, x3, v3, torque)
        x4, v4 = torch.add(x, v3, alpha=h), torch.add(v, a3, alpha=h)
        a4 = acc(d, x4, v4, torque)
        x = torch.add(x, torch.add(torch.add(v + v4, v2, alpha=2.0), v3, alpha=2.0), alpha=h / 6)
        v = torch.add(v, torch.add(torch.add(a1 + a4, a2, alpha=2.0), a3, alpha=2.0), alpha=h / 6)
    return x, v


class BatchedPRBChain:
    """``B`` PRB rods of one ``n_links`` stepped together, statelessly; ``substeps`` defaults to
    :func:`stable_substeps` (RK4) or :data:`ROSENBROCK_SUBSTEPS`; ``compiled``: the steps that need no gradient
    through ``torch.compile``.  Torques are saturated per rod; a non-finite state stays so, without an exception."""

    def __init__(
        self,
        params: Union[BatchedRodParams, RodParams, None] = None,
        batch_size: Optional[int] = None,
        dt_s: float = 0.01,
        substeps: Optional[int] = None,
        dtype: torch.dtype = torch.float64,
        integrator: str = "rk4",
        compiled: bool = False,
    ) -> None:
        self.integrator = one_of("integrator", integrator, INTEGRATORS)
        self.compiled = boolean("compiled", compiled)
        self._compiled_integrate: Optional[Callable[..., Any]] = None
        if not isinstance(params, (BatchedRodParams, RodParams, type(None))):
            raise ValueError(f"params must be a BatchedRodParams or a RodParams, got {type(params).__name__}")
        if not isinstance(params, BatchedRodParams):
            params = BatchedRodParams.from_params(params, batch_size, dtype)
        elif batch_size is not None and int_at_least("batch_size", batch_size, 1) != params.batch_size:
            raise ValueError(f"batch_size is {batch_size} but params holds {params.batch_size} rods")
        self.dt_s = positive("dt_s", dt_s)
        if substeps is None:
            substeps = stable_substeps(params, self.dt_s) if self.integrator == "rk4" else ROSENBROCK_SUBSTEPS
        self.substeps = int_at_least("substeps", substeps, 1)
        if self.substeps > MAX_SUBSTEPS:
            raise ValueError(f"substeps must be at most {MAX_SUBSTEPS}, got {substeps!r}")
        self.set_params(params)

    def set_params(self, params: BatchedRodParams) -> None:
        """Use new per-rod parameters (same ``n_links`` and batch size; the sub-step count is kept)."""
        if hasattr(self, "params") and (params.n_links, params.batch_size) != (self.n_links, self.batch_size):
            raise ValueError(
                f"params must keep n_links = {self.n_links} and batch size {self.batch_size}, "
                f"got {params.n_links} and {params.batch_size}"
            )
        self.params = params
        self._params_require_grad = any(getattr(params, name).requires_grad for name in PARAMETER_FIELDS)
        self.n_links: int = params.n_links
        self.n_coordinates = params.n_links + 1
        self.batch_size: int = params.batch_size
        self.dtype = params.dtype
        self._d = _Derived(params)

    def hanging_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The straight rods hanging down at rest, as ``(q, q_dot)`` of shape ``(B, n + 1)``."""
        q = torch.zeros(self.batch_size, self.n_coordinates, dtype=self.dtype)
        q[:, 0] = math.pi
        return q, torch.zeros_like(q)

    def _check_torque(self, torque_nm: TensorLike) -> torch.Tensor:
        torque = torch.as_tensor(torque_nm, dtype=self.dtype)
        if torque.ndim == 0:
            torque = torque.expand(self.batch_size)
        if tuple(torque.shape) != (self.batch_size,):
            raise ValueError(
                f"torque_nm must be a number or have shape ({self.batch_size},), got {tuple(torque.shape)}"
            )
        if not bool(torch.isfinite(torque.detach()).all()):
            raise ValueError("torque_nm must be finite")
        return torch.minimum(torch.maximum(torque, -self._d.torque_limit_nm), self._d.torque_limit_nm)

    def _absolute_state(self, q: TensorLike, qd: TensorLike) -> tuple[torch.Tensor, torch.Tensor]:
        """Checked ``(q, q_dot)`` as absolute angles and rates ``(n + 1, B)``."""
        out = []
        for value, name in ((q, "joint_angles_rad"), (qd, "joint_velocities_rad_s")):
            tensor = torch.as_tensor(value, dtype=self.dtype)
            if tuple(tensor.shape) != (self.batch_size, self.n_coordinates):
                raise ValueError(
                    f"{name} must have shape ({self.batch_size}, {self.n_coordinates}), got {tuple(tensor.shape)}"
                )
            out.append(torch.cumsum(tensor, dim=1).T.contiguous())
        return out[0], out[1]

    @staticmethod
    def _relative(x: torch.Tensor) -> torch.Tensor:
        return torch.cat([x[:1], x[1:] - x[:-1]]).T

    def step(
        self, joint_angles_rad: TensorLike, joint_velocities_rad_s: TensorLike, torque_nm: TensorLike
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(q, q_dot)`` of shape ``(B, n + 1)`` after holding ``torque_nm`` (per rod or one number) for ``dt_s``."""
        x, v = self._absolute_state(joint_angles_rad, joint_velocities_rad_s)
        x, v = self._integrate(x, v, self._check_torque(torque_nm))
        return self._relative(x), self._relative(v)

    def _integrate(self, x: torch.Tensor, v: torch.Tensor, torque: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.dt_s / self.substeps
        needs_grad = torch.is_grad_enabled() and (
            self._params_require_grad or x.requires_grad or v.requires_grad or torque.requires_grad
        )
        if self.compiled and not needs_grad:
            if self._compiled_integrate is None:
                self._compiled_integrate = torch.compile(_integrate, dynamic=False)
            return self._compiled_integrate(self.integrator, self.substeps, h, self._d, x, v, torque)
        return _integrate(self.integrator, self.substeps, h, self._d, x, v, torque)

    def rollout(
        self, joint_angles_rad: TensorLike, joint_velocities_rad_s: TensorLike, torques_nm: TensorLike
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """States ``(T, B, n + 1)`` after each of ``T`` control steps, for torques ``(T, B)``."""
        x, v = self._absolute_state(joint_angles_rad, joint_velocities_rad_s)
        torques = torch.as_tensor(torques_nm, dtype=self.dtype)
        if torques.ndim != 2 or torques.shape[1] != self.batch_size:
            raise ValueError(f"torques_nm must have shape (T, {self.batch_size}), got {tuple(torques.shape)}")
        qs, qds = [], []
        for torque in torques:
            x, v = self._integrate(x, v, self._check_torque(torque))
            qs.append(self._relative(x))
            qds.append(self._relative(v))
        return torch.stack(qs), torch.stack(qds)

    def observations(self, joint_angles_rad: TensorLike, joint_velocities_rad_s: TensorLike) -> torch.Tensor:
        """Plant observations ``(B, 10)`` in :data:`softpend.plant.OBSERVATION_NAMES` order."""
        x, v = self._absolute_state(joint_angles_rad, joint_velocities_rad_s)
        length, a, ad = self._d.link_length_m, x[1:], v[1:]
        s, c = torch.sin(a), torch.cos(a)
        ex, ey = -(length * s).sum(0), (length * c).sum(0)
        ex_dot, ey_dot = -(length * c * ad).sum(0), -(length * s * ad).sum(0)
        r2 = ex * ex + ey * ey
        theta = torch.atan2(-ex, ey)
        theta_dot = torch.where(
            r2 > 0, (ex * ey_dot - ey * ex_dot) / torch.where(r2 > 0, r2, torch.ones_like(r2)), torch.zeros_like(r2)
        )
        phi, theta, er = torch.remainder(torch.stack([x[0], theta, a[-1]]) + math.pi, 2 * math.pi) - math.pi
        return torch.stack([phi, theta, ex, ey, er, v[0], theta_dot, ex_dot, ey_dot, ad[-1]], dim=1)

    def energy_j(self, joint_angles_rad: TensorLike, joint_velocities_rad_s: TensorLike) -> dict[str, torch.Tensor]:
        """Energies of each rod [J] (tensors ``(B,)``), as :meth:`softpend.plant.PRBPlant.energy_j`."""
        x, v = self._absolute_state(joint_angles_rad, joint_velocities_rad_s)
        d, a, ad = self._d, x[1:], v[1:]
        s, c = torch.sin(a), torch.cos(a)
        kinetic = 0.5 * d.hub_inertia_kgm2 * v[0] ** 2 + 0.5 * (ad * _mass_times(d, c, s, ad)).sum(0)
        gravity = (d.gravity_moment_nm * c).sum(0)
        return energies(kinetic, gravity, 0.5 * (d.stiffness_nm_per_rad * (a - x[:-1]) ** 2).sum(0))
