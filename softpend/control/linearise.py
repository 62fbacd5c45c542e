"""Linearisation of the soft pendulum about the upright equilibrium.

Three independent routes give the linear model ``x_dot = A x + B tau`` (or ``x[k+1] = A x[k] + B tau[k]``)
of the PRB chain with joint state ``x = [q, q_dot]``, ``q = [phi, q_1, ..., q_n]`` (hub angle, then the
spring angles, all zero at upright):

* :func:`linearise_exudyn` -- Exudyn's own linearised mass, stiffness and damping matrices
  (``MainSystem.ComputeLinearizedSystem`` on the plant's multibody system), ``M q_dd + D q_d + K q = e_0 tau``;
* :func:`linearise_step_map` -- central finite differences of the simulator's one-step map (the discrete
  model the controller actually sees, including the implicit integrator);
* :func:`analytic_linearisation_one_link` -- the hand derivation for ``n = 1`` (hub inertia plus one rigid
  link on a torsional spring), used by the tests to check the other two.

The learned model is linearised in :mod:`softpend.control.learned`.  :func:`observation_coordinates_matrix`
gives the linear map from the joint state to the observed angles ``[phi, theta, e_r]`` and their rates, and
:func:`reduce_to_observation_coordinates` projects the joint-space model onto those coordinates, so that a
controller can run on observations alone (any plant, e.g. the continuum beam).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import scipy.linalg

from softpend.checks import optional_positive, positive
from softpend.plant import PRBPlant, RodParams

__all__ = [
    "LinearModel",
    "SecondOrderModel",
    "analytic_linearisation_one_link",
    "discretise",
    "linearise_exudyn",
    "linearise_step_map",
    "observation_coordinates_matrix",
    "reduce_to_observation_coordinates",
    "OBSERVATION_COORDINATE_NAMES",
]

#: Observation-derived coordinates used by the observation-feedback controllers (angles from upright).
OBSERVATION_COORDINATE_NAMES: tuple[str, ...] = ("phi_rad", "theta_rad", "er_rad")


@dataclass(frozen=True)
class SecondOrderModel:
    """Linearised mechanics ``M q_dd + D q_d + K q = b tau`` about an equilibrium.

    Attributes
    ----------
    mass : (N, N) array
        Mass matrix [kg m^2].
    stiffness : (N, N) array
        Tangent stiffness including the (destabilising) gravity term [N m/rad].
    damping : (N, N) array
        Damping matrix [N m s/rad].
    input_vector : (N,) array
        Generalised force per unit base torque (``e_0``: the torque acts on the hub coordinate).
    """

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
        names = tuple(f"q{i}" for i in range(n)) + tuple(f"q{i}_dot" for i in range(n))
        return LinearModel(a=a, b=b, dt_s=None, state_names=names)


@dataclass(frozen=True)
class LinearModel:
    """A linear state-space model ``x_dot = A x + B u`` (``dt_s is None``) or ``x+ = A x + B u``.

    Attributes
    ----------
    a : (nx, nx) array
    b : (nx, 1) array
        Input matrix per newton metre of base torque.
    dt_s : float or None
        Sample time [s] of a discrete model; ``None`` for continuous time.
    state_names : tuple of str
        Names of the state entries (for tables and for mapping observations).
    """

    a: np.ndarray
    b: np.ndarray
    dt_s: Optional[float] = None
    state_names: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        a = np.asarray(self.a, dtype=float)
        b = np.asarray(self.b, dtype=float).reshape(a.shape[0], -1)
        if a.ndim != 2 or a.shape[0] != a.shape[1]:
            raise ValueError(f"a must be square, got shape {a.shape}")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise ValueError("a and b must be finite")
        optional_positive("dt_s", self.dt_s)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        if self.state_names and len(self.state_names) != a.shape[0]:
            raise ValueError(f"state_names must have {a.shape[0]} entries, got {len(self.state_names)}")

    @property
    def n_states(self) -> int:
        return self.a.shape[0]

    @property
    def is_discrete(self) -> bool:
        return self.dt_s is not None

    def eigenvalues(self) -> np.ndarray:
        """Open-loop eigenvalues (continuous: rad/s; discrete: multipliers per step)."""
        return np.linalg.eigvals(self.a)

    def closed_loop(self, gain: np.ndarray) -> np.ndarray:
        """Closed-loop matrix ``A - B K`` for ``u = -K x``."""
        return self.a - self.b @ np.asarray(gain, dtype=float).reshape(1, -1)

    def is_stable_closed_loop(self, gain: np.ndarray, margin: float = 0.0) -> bool:
        """All closed-loop eigenvalues inside the unit circle (discrete) or the left half-plane."""
        eig = np.linalg.eigvals(self.closed_loop(gain))
        if self.is_discrete:
            return bool(np.all(np.abs(eig) < 1.0 - margin))
        return bool(np.all(eig.real < -margin))

    def to_control(self):
        """The model as a ``control.StateSpace`` (all states as outputs)."""
        import control

        return control.ss(self.a, self.b, np.eye(self.n_states), np.zeros((self.n_states, 1)), self.dt_s or 0)


def discretise(model: LinearModel, dt_s: float) -> LinearModel:
    """Zero-order-hold discretisation (the torque is held over each control step), via ``control.c2d``."""
    import control

    if model.is_discrete:
        raise ValueError("model is already discrete")
    positive("dt_s", dt_s)
    sys_d = control.c2d(model.to_control(), dt_s, method="zoh")
    return LinearModel(a=np.asarray(sys_d.A), b=np.asarray(sys_d.B), dt_s=float(dt_s), state_names=model.state_names)


def _upright_plant(params: RodParams, dt_s: float = 0.01, substeps: int = 2) -> PRBPlant:
    plant = PRBPlant(params, dt_s=dt_s, substeps=substeps)
    if plant.hub_locked:  # pragma: no cover - PRBPlant(params) always has a free hub
        raise ValueError("the hub must be free to linearise the actuated system")
    plant.reset()
    return plant


def linearise_exudyn(params: Optional[RodParams] = None) -> SecondOrderModel:
    """Linearised mechanics about upright from Exudyn (``ComputeLinearizedSystem`` on the PRB chain).

    Exudyn differentiates the chain's generalised forces (gravity, springs, dampers) at the current state;
    the plant is reset to the straight upright rod first.  The base torque enters the hub coordinate, so
    the input vector is ``e_0``.

    Parameters
    ----------
    params : RodParams, optional
        Rod and hub parameters (default rod if omitted).
    """
    params = params if params is not None else RodParams()
    plant = _upright_plant(params)
    mass, stiffness, damping = plant.linearized_matrices()
    n = plant.n_coordinates
    input_vector = np.zeros(n)
    input_vector[0] = 1.0
    return SecondOrderModel(np.asarray(mass), np.asarray(stiffness), np.asarray(damping), input_vector)


def analytic_linearisation_one_link(params: RodParams) -> SecondOrderModel:
    """Hand-derived linearisation for ``n_links = 1``.

    Coordinates ``phi`` (hub) and ``q_1`` (clamp spring); the link's absolute angle is ``a = phi + q_1``.
    With hub inertia ``J``, hub friction ``b``, link mass ``m`` (rod plus tip mass) with centre of mass at
    ``c`` from the hub axis and inertia ``I_O`` about the axis, clamp spring ``k`` and damper ``d``:

    ``T = J phi_d^2/2 + I_O (phi_d + q1_d)^2/2``, ``V = m g c cos(a) + k q_1^2/2``, so about upright

    ``M = [[J + I_O, I_O], [I_O, I_O]]``, ``K = [[-m g c, -m g c], [-m g c, k - m g c]]``,
    ``D = diag(b, d)``, ``B = [1, 0]``.
    """
    if params.n_links != 1:
        raise ValueError(f"params.n_links must be 1 for the analytic linearisation, got {params.n_links}")
    length = params.length_m
    m_rod, m_tip = params.mass_kg, params.tip_mass_kg
    m = m_rod + m_tip
    c = (m_rod * length / 2 + m_tip * length) / m
    inertia_axis = m_rod * length**2 / 3 + m_tip * length**2
    g = params.gravity_mps2
    j_hub = params.hub_inertia_kgm2
    k = params.spring_stiffnesses_nm_per_rad()[0]
    d = params.spring_dampings_nms_per_rad()[0]
    mgc = m * g * c
    mass = np.array([[j_hub + inertia_axis, inertia_axis], [inertia_axis, inertia_axis]])
    stiffness = np.array([[-mgc, -mgc], [-mgc, k - mgc]])
    damping = np.diag([params.hub_friction_nms_per_rad, d])
    return SecondOrderModel(mass, stiffness, damping, np.array([1.0, 0.0]))


def linearise_step_map(
    params: Optional[RodParams] = None,
    dt_s: float = 0.01,
    substeps: int = 2,
    state_step: float = 1e-6,
    torque_step_nm: float = 1e-5,
) -> LinearModel:
    """Discrete linear model from central finite differences of the simulator's one-step map.

    Each column of ``A`` is ``(F(x0 + h e_i, 0) - F(x0 - h e_i, 0)) / 2h`` with ``F`` one control step of
    :class:`~softpend.plant.PRBPlant` from the joint state ``x`` under a held torque; ``B`` likewise in the
    torque.  ``x0`` is the straight rod upright at rest.

    Parameters
    ----------
    params : RodParams, optional
    dt_s : float
        Control step [s].
    substeps : int
        Solver steps per control step (as the plant under control).
    state_step, torque_step_nm : float
        Finite-difference steps [rad, rad/s] and [N m].
    """
    params = params if params is not None else RodParams()
    if state_step <= 0 or torque_step_nm <= 0:
        raise ValueError("state_step and torque_step_nm must be positive")
    plant = _upright_plant(params, dt_s=dt_s, substeps=substeps)
    n = plant.n_coordinates

    def step(x: np.ndarray, torque: float) -> np.ndarray:
        plant.reset(x[:n], x[n:])
        plant.step(torque)
        q, qd = plant.joint_state()
        return np.concatenate([q, qd])

    a = np.empty((2 * n, 2 * n))
    for i in range(2 * n):
        e = np.zeros(2 * n)
        e[i] = state_step
        a[:, i] = (step(e, 0.0) - step(-e, 0.0)) / (2 * state_step)
    zero = np.zeros(2 * n)
    b = (step(zero, torque_step_nm) - step(zero, -torque_step_nm)) / (2 * torque_step_nm)
    names = tuple(f"q{i}" for i in range(n)) + tuple(f"q{i}_dot" for i in range(n))
    return LinearModel(a=a, b=b.reshape(-1, 1), dt_s=float(dt_s), state_names=names)


def observation_coordinates_matrix(
    params: RodParams, names: Sequence[str] = OBSERVATION_COORDINATE_NAMES
) -> np.ndarray:
    """Linear map ``y = C q`` from joint angles to observed angles about upright.

    At upright the link angles ``a_i = phi + q_1 + ... + q_i`` are small, the tip angle is the mean link
    angle ``theta = (a_1 + ... + a_n)/n`` (equal links), the tip rotation is ``e_r = a_n``.

    Parameters
    ----------
    params : RodParams
    names : sequence of {"phi_rad", "theta_rad", "er_rad"}

    Returns
    -------
    (len(names), n_links + 1) array
    """
    n = params.n_links
    absolute = np.hstack([np.ones((n, 1)), np.tril(np.ones((n, n)))])  # a_i = phi + sum_{j<=i} q_j
    rows = {
        "phi_rad": np.eye(1, n + 1, 0)[0],
        "theta_rad": absolute.mean(axis=0),
        "er_rad": absolute[-1],
    }
    unknown = [name for name in names if name not in rows]
    if unknown:
        raise ValueError(f"names must be among {sorted(rows)}, got {unknown}")
    return np.array([rows[name] for name in names])


def reduce_to_observation_coordinates(
    model: SecondOrderModel,
    params: RodParams,
    names: Optional[Sequence[str]] = None,
) -> tuple[SecondOrderModel, np.ndarray, tuple[str, ...]]:
    """Project the joint-space mechanics onto observed angles by static condensation (Guyan reduction).

    The joint angles are expressed as ``q = T y`` where ``y`` are the observed angles (hub angle, tip angle,
    tip rotation) and ``T`` is the shape of least elastic energy that produces them: ``T`` minimises
    ``q' K_e q`` (spring stiffness only) subject to ``C q = y``.  The reduced model is
    ``T' M T, T' D T, T' K T, T' b``.  Observed coordinates that are linearly dependent for this chain
    (for ``n = 1``, ``theta = e_r``) are dropped.

    Parameters
    ----------
    model : SecondOrderModel
        Full joint-space model (e.g. from :func:`linearise_exudyn`).
    params : RodParams
        The same rod (sets the observation geometry and the spring stiffnesses).
    names : sequence of str, optional
        Observed coordinates to keep (default :data:`OBSERVATION_COORDINATE_NAMES`).

    Returns
    -------
    reduced : SecondOrderModel
    shape : (n_links + 1, k) array
        The condensation matrix ``T``.
    kept_names : tuple of str
    """
    names = tuple(names) if names is not None else OBSERVATION_COORDINATE_NAMES
    # drop dependent coordinates, in order
    kept: list[str] = []
    for name in names:
        trial = observation_coordinates_matrix(params, kept + [name])
        if np.linalg.matrix_rank(trial, tol=1e-9) == len(kept) + 1:
            kept.append(name)
    c = observation_coordinates_matrix(params, kept)
    n = c.shape[1]
    k_elastic = np.zeros((n, n))
    k_elastic[1:, 1:] = np.diag(params.spring_stiffnesses_nm_per_rad())
    # KKT system [[K_e, C'], [C, 0]] [T; L] = [0; I]
    kkt = np.block([[k_elastic, c.T], [c, np.zeros((len(kept), len(kept)))]])
    rhs = np.vstack([np.zeros((n, len(kept))), np.eye(len(kept))])
    shape = scipy.linalg.lstsq(kkt, rhs)[0][:n]
    reduced = SecondOrderModel(
        mass=shape.T @ model.mass @ shape,
        stiffness=shape.T @ model.stiffness @ shape,
        damping=shape.T @ model.damping @ shape,
        input_vector=shape.T @ model.input_vector,
    )
    return reduced, shape, tuple(kept)
