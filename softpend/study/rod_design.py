"""Why the project's default rod looks the way it does: design figures computed from the plant itself.

The default :class:`~softpend.plant.params.RodParams` are chosen so that the control problem has the
three features the report is about:

* the rod is *soft*: held horizontal by a locked hub it sags visibly (10-30 % of its length) under its
  own weight and the tip mass, computed with the PRB plant's static solver;
* the motor is *weak*: the torque limit is below the torque needed to hold the straight rod horizontal,
  so the rod cannot be lifted straight up and a swing-up has to pump energy;
* the rod is *stiff enough to stand*: clamped pointing up it does not buckle under its own weight (the
  gravity load factor at which the clamped PRB chain buckles is well above 1), so upright is a shape the
  hub can balance by feedback (the classical-control chapter's LQR does it).

:func:`rod_design` computes these figures; :meth:`RodDesign.to_markdown` renders the design table shown in
the book's Figure 1 notebook, and :func:`rod_poses_m` gives the joint positions drawn there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from softpend.checks import positive
from softpend.plant.base import PlantBase
from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant
from softpend.plant.protocol import Plant
from softpend.task import Task

__all__ = ["RodDesign", "clamped_upright_buckling_factor", "horizontal_cantilever", "rod_design", "rod_poses_m"]

#: Hub angle that points the clamped rod horizontally (to +x) [rad].
HORIZONTAL_HUB_ANGLE_RAD = -math.pi / 2


def horizontal_cantilever(task: Optional[Task] = None) -> Plant:
    """The rod of ``task`` (default ``Task()``) clamped horizontally (hub locked at ``-pi/2``) and resting in
    its deflected static equilibrium under gravity, as a hub-locked plant."""
    sim = (task if task is not None else Task()).make_plant(hub_locked_at_rad=HORIZONTAL_HUB_ANGLE_RAD)
    assert isinstance(sim, PlantBase)  # the PRB and beam plants: Exudyn's static solver
    sim.static_equilibrium()
    return sim


def _hessian(function, n: int, step: float) -> np.ndarray:
    """Central finite-difference Hessian of ``function(q)`` at ``q = 0``."""
    hessian = np.zeros((n, n))
    eye = np.eye(n) * step
    for i in range(n):
        for j in range(i, n):
            value = (
                function(eye[i] + eye[j])
                - function(eye[i] - eye[j])
                - function(-eye[i] + eye[j])
                + function(-eye[i] - eye[j])
            ) / (4 * step * step)
            hessian[i, j] = hessian[j, i] = value
    return hessian


def clamped_upright_buckling_factor(params: Optional[RodParams] = None, step_rad: float = 1e-3) -> float:
    """Factor by which gravity would have to grow for the rod, clamped pointing straight up, to buckle.

    The clamped (hub-locked) PRB chain is stable upright when the Hessian of its potential energy
    ``K_elastic - G_gravity`` at the straight configuration is positive definite; the critical load factor
    is the smallest generalised eigenvalue ``lambda`` of ``K v = lambda G v``.  Both Hessians are taken by
    finite differences of :meth:`PRBPlant.energy_j`, i.e. from the plant's own geometry.

    Parameters
    ----------
    params : RodParams, optional
        Rod parameters (default: the project's default rod).
    step_rad : float
        Finite-difference step [rad].

    Returns
    -------
    float
        The buckling load factor (> 1: the clamped rod stands up on its own; ``inf`` without gravity).
    """
    positive("step_rad", step_rad)
    plant = PRBPlant(params if params is not None else RodParams(), hub_locked_at_rad=0.0)
    n = plant.n_coordinates
    zeros = np.zeros(n)
    elastic = _hessian(lambda q: plant.energy_j(q, zeros)["elastic_j"], n, step_rad)
    destabilising = -_hessian(lambda q: plant.energy_j(q, zeros)["gravity_j"], n, step_rad)
    if not np.any(np.abs(destabilising) > 0):
        return math.inf
    # K v = lambda G v with K symmetric positive definite: lambda = 1 / eig(K^-1/2 G K^-1/2)
    k_eigvals, k_eigvecs = np.linalg.eigh(elastic)
    if np.min(k_eigvals) <= 0:
        return 0.0  # no bending stiffness: a hinged chain falls over under any gravity
    k_inv_sqrt = k_eigvecs @ np.diag(k_eigvals**-0.5) @ k_eigvecs.T
    largest = float(np.max(np.linalg.eigvalsh(k_inv_sqrt @ destabilising @ k_inv_sqrt)))
    return math.inf if largest <= 0 else 1.0 / largest


@dataclass(frozen=True)
class RodDesign:
    """Design figures of a rod (see :func:`rod_design`).

    Attributes
    ----------
    params : RodParams
        The rod they describe.
    tip_sag_horizontal_m : float
        Vertical drop of the tip below the hub axis when the rod is clamped horizontally, from the PRB
        plant's static equilibrium [m].
    tip_sag_euler_bernoulli_m : float
        The same from small-deflection Euler-Bernoulli beam theory [m] (over-estimates large sag).
    gravity_torque_horizontal_nm : float
        Torque needed to hold the straight rod horizontal [N m].
    torque_limit_nm : float
        Motor torque limit [N m].
    buckling_load_factor : float
        See :func:`clamped_upright_buckling_factor` (dimensionless).
    """

    params: RodParams
    tip_sag_horizontal_m: float
    tip_sag_euler_bernoulli_m: float
    gravity_torque_horizontal_nm: float
    torque_limit_nm: float
    buckling_load_factor: float

    @property
    def tip_sag_fraction(self) -> float:
        """Horizontal tip sag as a fraction of the rod length (dimensionless)."""
        return self.tip_sag_horizontal_m / self.params.length_m

    @property
    def torque_ratio(self) -> float:
        """Torque limit over the torque needed to hold the rod horizontal (< 1: swing-up must pump)."""
        return self.torque_limit_nm / self.gravity_torque_horizontal_nm

    def rows(self) -> list[tuple[str, str, str]]:
        """The design table as ``(quantity, value, what it means)`` rows of formatted text."""
        p = self.params
        return [
            ("rod length L, links n", f"{p.length_m:.3g} m, n = {p.n_links}", "PRB chain of n rigid links"),
            (
                "rod mass m, tip mass",
                f"{p.mass_kg * 1e3:.3g} g, {p.tip_mass_kg * 1e3:.3g} g",
                "uniform rod plus end mass",
            ),
            (
                "bending stiffness EI",
                f"{p.bending_stiffness_nm2:.3g} N m²",
                f"joint springs k = EI/(L/n) = {p.joint_stiffness_nm_per_rad:.3g} N m/rad",
            ),
            (
                "tip sag, clamped horizontal (PRB statics)",
                f"{self.tip_sag_horizontal_m * 1e3:.1f} mm = {100 * self.tip_sag_fraction:.0f} % of L",
                "the rod visibly bends (target 10-30 % of L)",
            ),
            (
                "tip sag, Euler-Bernoulli (small deflection)",
                f"{self.tip_sag_euler_bernoulli_m * 1e3:.1f} mm",
                "linear beam theory, for comparison",
            ),
            (
                "torque limit / torque to hold horizontal",
                f"{self.torque_limit_nm:.3g} / {self.gravity_torque_horizontal_nm:.3g} N m = {self.torque_ratio:.2f}",
                "< 1: the motor cannot lift the rod straight up; swing-up must pump energy",
            ),
            (
                "buckling load factor, clamped upright",
                f"{self.buckling_load_factor:.2f}",
                "> 1: the clamped rod stands upright; feedback on the hub can balance it",
            ),
        ]

    def to_markdown(self) -> str:
        """The design table as a Markdown table."""
        lines = ["| quantity | value | meaning |", "| --- | --- | --- |"]
        lines += [f"| {a} | {b} | {c} |" for a, b, c in self.rows()]
        return "\n".join(lines)


def rod_design(params: Optional[RodParams] = None) -> RodDesign:
    """Compute the design figures of a rod with the PRB plant.

    Parameters
    ----------
    params : RodParams, optional
        Rod parameters (default: the project's default rod).

    Returns
    -------
    RodDesign
        Horizontal tip sag (PRB statics and beam theory), torque ratio and buckling load factor.
    """
    params = params if params is not None else RodParams()
    if not isinstance(params, RodParams):
        raise ValueError(f"params must be a RodParams, got {type(params).__name__}")
    tip = horizontal_cantilever(Task(rod=params)).link_points_m()[-1]
    return RodDesign(
        params=params,
        tip_sag_horizontal_m=float(-tip[1]),
        tip_sag_euler_bernoulli_m=params.static_sag_euler_bernoulli_m,
        gravity_torque_horizontal_nm=params.gravity_torque_horizontal_nm,
        torque_limit_nm=params.torque_limit_nm,
        buckling_load_factor=clamped_upright_buckling_factor(params),
    )


def rod_poses_m(task: Optional[Task] = None) -> dict[str, np.ndarray]:
    """Points along the rod ``(k, 2)`` [m] of three poses of the plant of ``task`` (default ``Task()``), from
    the plant's own geometry (the PRB joints, or the beam nodes).

    Returns
    -------
    dict
        ``"hanging"`` (straight, hub at ``pi``), ``"horizontal"`` (clamped horizontally, deflected by
        gravity: the static equilibrium of :func:`horizontal_cantilever`) and ``"upright"`` (straight up).
    """
    task = task if task is not None else Task()
    sim = task.make_plant()
    hanging_q, _ = sim.hanging_state()
    return {
        "hanging": sim.link_points_m(hanging_q),
        "horizontal": horizontal_cantilever(task).link_points_m(),
        "upright": sim.link_points_m(np.zeros(sim.n_coordinates)),
    }
