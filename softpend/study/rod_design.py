"""Why the default rod looks the way it does: it sags visibly, the motor cannot lift it straight, and clamped
upright it does not buckle; figures computed from the plant itself."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from softpend.plant.base import PlantBase
from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant
from softpend.plant.protocol import Plant
from softpend.task import Task

#: Hub angle that points the clamped rod horizontally (to +x) [rad].
HORIZONTAL_HUB_ANGLE_RAD = -math.pi / 2


def horizontal_cantilever(task: Optional[Task] = None) -> Plant:
    """The rod of ``task`` clamped horizontally, resting in its static equilibrium under gravity."""
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


def clamped_upright_buckling_factor(params: RodParams) -> float:
    """Factor by which gravity would have to grow for the rod clamped upright to buckle: the smallest ``lambda`` of
    ``K v = lambda G v``, the Hessians of the elastic and gravity energy by finite differences (steps of 1e-3 rad)."""
    plant = PRBPlant(params, hub_locked_at_rad=0.0)
    n, zeros = plant.n_coordinates, np.zeros(plant.n_coordinates)
    elastic = _hessian(lambda q: plant.energy_j(q, zeros)["elastic_j"], n, 1e-3)
    destabilising = -_hessian(lambda q: plant.energy_j(q, zeros)["gravity_j"], n, 1e-3)
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
    """Design figures of a rod: tip sag clamped horizontal (PRB statics, Euler-Bernoulli), the torque to hold the
    straight rod horizontal, the torque limit, and the buckling load factor clamped upright."""

    params: RodParams
    tip_sag_horizontal_m: float
    tip_sag_euler_bernoulli_m: float
    gravity_torque_horizontal_nm: float
    torque_limit_nm: float
    buckling_load_factor: float

    @property
    def tip_sag_fraction(self) -> float:
        """Horizontal tip sag over the rod length."""
        return self.tip_sag_horizontal_m / self.params.length_m

    @property
    def torque_ratio(self) -> float:
        """Torque limit over the torque to hold the rod horizontal."""
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
    """The design figures of a rod, from the PRB plant."""
    params = params if params is not None else RodParams()
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
    """Points along the rod ``(k, 2)`` [m] of the plant of ``task`` hanging, clamped horizontal (deflected) and
    upright."""
    task = task if task is not None else Task()
    sim = task.make_plant()
    return {
        "hanging": sim.link_points_m(sim.hanging_state()[0]),
        "horizontal": horizontal_cantilever(task).link_points_m(),
        "upright": sim.link_points_m(np.zeros(sim.n_coordinates)),
    }
