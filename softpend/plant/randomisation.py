"""Rods that differ from the model: random scalings of a :class:`~softpend.plant.RodParams` within a spread."""

from __future__ import annotations

import numpy as np

from softpend.checks import in_unit_interval
from softpend.plant.params import RodParams

#: The fields scaled by :func:`randomised_rod`: what a built rig gets wrong.
RANDOMISED_FIELDS = tuple(
    "mass_kg youngs_modulus_pa joint_damping_nms_per_rad hub_friction_nms_per_rad torque_limit_nm".split()
)


def randomised_rod(rod: RodParams, rng: np.random.Generator, spread: float) -> RodParams:
    """``rod`` with each of :data:`RANDOMISED_FIELDS` scaled by a factor uniform in ``[1 - spread, 1 + spread]``
    drawn from ``rng`` in that order (``spread`` in ``[0, 1)``)."""
    spread = in_unit_interval("spread", spread, include_one=False)
    factors = rng.uniform(1.0 - spread, 1.0 + spread, size=len(RANDOMISED_FIELDS))
    return rod.replace(**{name: getattr(rod, name) * float(f) for name, f in zip(RANDOMISED_FIELDS, factors)})
