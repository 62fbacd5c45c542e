"""The rod's design figures: its sag, the torque to lift it straight and its buckling load clamped upright."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softpend.plant.base import Plant, PlantBase
from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant
from softpend.task import Task

#: Hub angle that points the clamped rod horizontally (to +x) [rad].
HORIZONTAL_HUB_ANGLE_RAD = -math.pi / 2


def horizontal_cantilever(task: Task = Task()) -> Plant:
    """The rod of ``task`` clamped horizontally, resting in its static equilibrium under gravity."""
    sim = task.make_plant(hub_locked_at_rad=HORIZONTAL_HUB_ANGLE_RAD)
    assert isinstance(sim, PlantBase)  # the PRB and beam plants: Exudyn's static solver
    sim.static_equilibrium()
    return sim


def _hessian(function, n: int, step: float) -> np.ndarray:
    """Central finite-difference Hessian of ``function(q)`` at ``q = 0``."""
    e = np.eye(n) * step
    d2 = lambda a, b: (function(a + b) - function(a - b) - function(-a + b) + function(-a - b)) / (4 * step * step)  # noqa: E731
    return np.array([[d2(e[min(i, j)], e[max(i, j)]) for j in range(n)] for i in range(n)])


def clamped_upright_buckling_factor(params: RodParams) -> float:
    """Factor by which gravity would have to grow for the rod clamped upright to buckle (smallest ``lambda`` of
    ``K v = lambda G v``, energy Hessians by finite differences)."""
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
    """Design figures of a rod: tip sag clamped horizontal, torque to hold it horizontal, buckling load factor."""

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

    def to_markdown(self) -> str:
        """The design table as a Markdown table: quantity, value, what it means."""
        p, sag_mm, hold_nm = self.params, self.tip_sag_horizontal_m * 1e3, self.gravity_torque_horizontal_nm
        table = [
            "quantity | value | meaning",
            "--- | --- | ---",
            f"rod length L, links n | {p.length_m:.3g} m, n = {p.n_links} | PRB chain of n rigid links",
            f"rod mass m, tip mass | {p.mass_kg * 1e3:.3g} g, {p.tip_mass_kg * 1e3:.3g} g | uniform rod plus end mass",
            f"bending stiffness EI | {p.bending_stiffness_nm2:.3g} N m² | joint springs k = EI/(L/n) = {p.joint_stiffness_nm_per_rad:.3g} N m/rad",
            f"tip sag, clamped horizontal (PRB statics) | {sag_mm:.1f} mm = {100 * self.tip_sag_fraction:.0f} % of L | the rod visibly bends (target 10-30 % of L)",
            f"tip sag, Euler-Bernoulli (small deflection) | {self.tip_sag_euler_bernoulli_m * 1e3:.1f} mm | linear beam theory, for comparison",
            f"torque limit / torque to hold horizontal | {self.torque_limit_nm:.3g} / {hold_nm:.3g} N m = {self.torque_ratio:.2f} | < 1: the motor cannot lift the rod straight up; swing-up must pump energy",
            f"buckling load factor, clamped upright | {self.buckling_load_factor:.2f} | > 1: the clamped rod stands upright; feedback on the hub can balance it",
        ]
        return "\n".join(f"| {row} |" for row in table)


def rod_design(params: RodParams = RodParams()) -> RodDesign:
    """The design figures of a rod, from the PRB plant."""
    tip = horizontal_cantilever(Task(rod=params)).link_points_m()[-1]
    sag = dict(tip_sag_horizontal_m=float(-tip[1]), tip_sag_euler_bernoulli_m=params.static_sag_euler_bernoulli_m)
    same = {name: getattr(params, name) for name in ("gravity_torque_horizontal_nm", "torque_limit_nm")}
    return RodDesign(params, **sag, **same, buckling_load_factor=clamped_upright_buckling_factor(params))


def rod_poses_m(task: Task = Task()) -> dict[str, np.ndarray]:
    """Points along the rod ``(k, 2)`` [m] hanging, clamped horizontal (deflected) and upright."""
    sim = task.make_plant()
    return {
        "hanging": sim.link_points_m(sim.hanging_state()[0]),
        "horizontal": horizontal_cantilever(task).link_points_m(),
        "upright": sim.link_points_m(np.zeros(sim.n_coordinates)),
    }
