"""Rods that differ from the model: random scalings of a :class:`~softpend.plant.RodParams` within a spread.

Domain randomisation for training and the robustness evaluation draw rods the same way: every field of
:data:`RANDOMISED_FIELDS` is multiplied by its own factor drawn uniformly from ``[1 - spread, 1 + spread]``.
The fields are those a built rig gets wrong: the rod's mass, stiffness (Young's modulus) and joint damping,
the hub's friction, and the torque the motor really delivers.
"""

from __future__ import annotations

import numpy as np

from softpend.checks import in_unit_interval
from softpend.plant.params import RodParams

__all__ = ["RANDOMISED_FIELDS", "randomised_rod"]

#: The fields scaled by :func:`randomised_rod`.
RANDOMISED_FIELDS = (
    "mass_kg",
    "youngs_modulus_pa",
    "joint_damping_nms_per_rad",
    "hub_friction_nms_per_rad",
    "torque_limit_nm",
)


def randomised_rod(rod: RodParams, rng: np.random.Generator, spread: float) -> RodParams:
    """A copy of ``rod`` with each of :data:`RANDOMISED_FIELDS` scaled by a factor uniform in
    ``[1 - spread, 1 + spread]`` (``spread`` a fraction in ``[0, 1)``, e.g. 0.15 for +-15 %), drawn from ``rng``
    in the order of :data:`RANDOMISED_FIELDS`."""
    spread = in_unit_interval("spread", spread, include_one=False)
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    factors = rng.uniform(1.0 - spread, 1.0 + spread, size=len(RANDOMISED_FIELDS))
    return rod.replace(**{name: getattr(rod, name) * float(f) for name, f in zip(RANDOMISED_FIELDS, factors)})
