"""Linear models of the PRB chain about upright, joint state ``x = [q, q_dot]``, from Exudyn's linearised matrices
(:func:`linearise_exudyn`), and condensed onto the observed angles (:func:`reduce_to_observation_coordinates`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import scipy.linalg

from softpend.plant import PRBPlant, RodParams

#: Observed angles the observation-feedback controllers use.
OBSERVATION_COORDINATE_NAMES: tuple[str, ...] = ("phi_rad", "theta_rad", "er_rad")


def _joint_names(n: int) -> tuple[str, ...]:
    return tuple(f"q{i}" for i in range(n)) + tuple(f"q{i}_dot" for i in range(n))


@dataclass(frozen=True)
class SecondOrderModel:
    """``M q_dd + D q_d + K q = b tau`` about an equilibrium (``K`` includes gravity)."""

    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    input_vector: np.ndarray

    def state_space(self) -> "LinearModel":
        """First-order continuous model with state ``[q, q_dot]``."""
        n = self.mass.shape[0]
        m_inv = np.linalg.inv(self.mass)
        a = np.block([[np.zeros((n, n)), np.eye(n)], [-m_inv @ self.stiffness, -m_inv @ self.damping]])
        b = np.concatenate([np.zeros(n), m_inv @ self.input_vector]).reshape(-1, 1)
        return LinearModel(a=a, b=b, dt_s=None, state_names=_joint_names(n))


@dataclass(frozen=True)
class LinearModel:
    """``x_dot = A x + B u`` (``dt_s is None``) or ``x+ = A x + B u``; ``B`` per newton metre of torque."""

    a: np.ndarray
    b: np.ndarray
    dt_s: Optional[float] = None
    state_names: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        a = np.asarray(self.a, dtype=float)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", np.asarray(self.b, dtype=float).reshape(a.shape[0], -1))

    def eigenvalues(self) -> np.ndarray:
        return np.linalg.eigvals(self.a)


def discretise(model: LinearModel, dt_s: float) -> LinearModel:
    """Zero-order-hold discretisation (``control.c2d``)."""
    import control

    n = model.a.shape[0]
    sys_d = control.c2d(control.ss(model.a, model.b, np.eye(n), np.zeros((n, 1)), 0), dt_s, method="zoh")
    return LinearModel(a=np.asarray(sys_d.A), b=np.asarray(sys_d.B), dt_s=float(dt_s), state_names=model.state_names)


def linearise_exudyn(params: Optional[RodParams] = None) -> SecondOrderModel:
    """Mechanics about upright from Exudyn's ``ComputeLinearizedSystem``; the torque enters the hub (``e_0``)."""
    plant = PRBPlant(params if params is not None else RodParams())
    mass, stiffness, damping = (np.asarray(m) for m in plant.linearized_matrices())
    return SecondOrderModel(mass, stiffness, damping, np.eye(plant.n_coordinates)[0])


def observation_coordinates_matrix(
    params: RodParams, names: Sequence[str] = OBSERVATION_COORDINATE_NAMES
) -> np.ndarray:
    """``C`` of ``y = C q``, the observed angles ``names`` (of :data:`OBSERVATION_COORDINATE_NAMES`) about upright
    (``theta`` the mean link angle, ``e_r`` the last), shape ``(len(names), n_links + 1)``."""
    n = params.n_links
    absolute = np.hstack([np.ones((n, 1)), np.tril(np.ones((n, n)))])  # a_i = phi + sum_{j<=i} q_j
    rows = {"phi_rad": np.eye(1, n + 1, 0)[0], "theta_rad": absolute.mean(axis=0), "er_rad": absolute[-1]}
    return np.array([rows[name] for name in names])


def reduce_to_observation_coordinates(
    model: SecondOrderModel, params: RodParams
) -> tuple[SecondOrderModel, np.ndarray, tuple[str, ...]]:
    """Guyan reduction onto observed angles: ``q = T y`` with ``T`` the shape of least spring energy with
    ``C q = y``; returns ``(T' M T, ...)``, ``T`` and the kept names (linearly dependent ones dropped)."""
    kept: list[str] = []
    for name in OBSERVATION_COORDINATE_NAMES:
        trial = observation_coordinates_matrix(params, kept + [name])
        if np.linalg.matrix_rank(trial, tol=1e-9) == len(kept) + 1:
            kept.append(name)
    c = observation_coordinates_matrix(params, kept)
    n = c.shape[1]
    k_elastic = np.zeros((n, n))
    k_elastic[1:, 1:] = np.diag(params.spring_stiffnesses_nm_per_rad())
    kkt = np.block([[k_elastic, c.T], [c, np.zeros((len(kept), len(kept)))]])
    rhs = np.vstack([np.zeros((n, len(kept))), np.eye(len(kept))])
    shape = scipy.linalg.lstsq(kkt, rhs)[0][:n]
    mass, stiffness, damping = (shape.T @ m @ shape for m in (model.mass, model.stiffness, model.damping))
    reduced = SecondOrderModel(mass, stiffness, damping, shape.T @ model.input_vector)
    return reduced, shape, tuple(kept)
