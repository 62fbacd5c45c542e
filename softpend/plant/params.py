"""Physical parameters of the soft pendulum (the report's Table 1, in SI units).

The rod is ``n_links`` rigid links of length ``L/n`` joined by torsional springs ``k = E*W*D**3/12/(L/n)``
(``2k`` at the clamp, which lumps a half segment) and dampers (``zeta``, ``2 zeta`` at the clamp).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from softpend.checks import in_unit_interval, int_at_least, non_negative, positive

GRAVITY_MPS2 = 9.81

#: Most links a PRB rod may have.
MAX_N_LINKS = 64

#: Largest rod-parameter JSON file read by :meth:`RodParams.from_json` [bytes].
_MAX_JSON_BYTES = 10**6


#: The fields of :class:`RodParams` that must be positive (the other floats must be non-negative).
POSITIVE_FIELDS = ("length_m", "mass_kg", "width_m", "depth_m", "torque_limit_nm")


@dataclass(frozen=True)
class RodParams:
    """Parameters of the motor hub and the soft rod (SI units; ``depth_m`` in the bending direction,
    ``joint_damping_nms_per_rad`` of each interior joint, ``hub_inertia_kgm2`` reflected through the gearbox,
    ``stiffness_scale`` multiplies every joint stiffness: 0 for freely hinged links)."""

    length_m: float = 0.30
    n_links: int = 4
    mass_kg: float = 0.058
    width_m: float = 0.020
    depth_m: float = 0.008
    youngs_modulus_pa: float = 50.0e6
    joint_damping_nms_per_rad: float = 2.0e-4
    tip_mass_kg: float = 0.010
    hub_inertia_kgm2: float = 2.0e-4
    hub_friction_nms_per_rad: float = 2.0e-3
    torque_limit_nm: float = 0.06
    gravity_mps2: float = GRAVITY_MPS2
    stiffness_scale: float = 1.0

    def __post_init__(self) -> None:
        n_links = int_at_least("n_links", self.n_links, 1)
        if n_links > MAX_N_LINKS:
            raise ValueError(
                f"n_links must be at most {MAX_N_LINKS} (see softpend.plant.params.MAX_N_LINKS), got {self.n_links!r}"
            )
        for field in dataclasses.fields(self):
            if field.name != "n_links":
                (positive if field.name in POSITIVE_FIELDS else non_negative)(field.name, getattr(self, field.name))
        object.__setattr__(self, "n_links", n_links)

    @property
    def bending_stiffness_nm2(self) -> float:
        """Flexural rigidity ``E*W*D**3/12`` [N m^2] (times ``stiffness_scale``)."""
        return self.youngs_modulus_pa * (self.width_m * self.depth_m**3 / 12.0) * self.stiffness_scale

    @property
    def link_length_m(self) -> float:
        return self.length_m / self.n_links

    @property
    def link_mass_kg(self) -> float:
        """Mass of one link ``m/n`` [kg] (the tip mass is extra)."""
        return self.mass_kg / self.n_links

    @property
    def joint_stiffness_nm_per_rad(self) -> float:
        """Interior spring constant ``k = E*I/(L/n)`` [N m/rad]."""
        return self.bending_stiffness_nm2 / self.link_length_m

    def spring_stiffnesses_nm_per_rad(self) -> list[float]:
        """The ``n`` spring stiffnesses, clamp first (``2k, k, ..., k``)."""
        k = self.joint_stiffness_nm_per_rad
        return [2.0 * k] + [k] * (self.n_links - 1)

    def spring_dampings_nms_per_rad(self) -> list[float]:
        """The ``n`` spring dampings, clamp first (``2 zeta, zeta, ...``)."""
        z = self.joint_damping_nms_per_rad
        return [2.0 * z] + [z] * (self.n_links - 1)

    @property
    def gravity_torque_horizontal_nm(self) -> float:
        """Torque that holds the straight rod horizontal, ``g*(m*L/2 + m_tip*L)`` [N m]."""
        return self.gravity_mps2 * (self.mass_kg * self.length_m / 2 + self.tip_mass_kg * self.length_m)

    @property
    def static_sag_euler_bernoulli_m(self) -> float:
        """Euler-Bernoulli tip deflection of the horizontal clamped rod under its weight and the tip mass [m]."""
        ei = self.bending_stiffness_nm2
        if ei == 0:
            return math.inf
        w = self.mass_kg * self.gravity_mps2 / self.length_m
        p = self.tip_mass_kg * self.gravity_mps2
        return w * self.length_m**4 / (8 * ei) + p * self.length_m**3 / (3 * ei)

    def replace(self, **changes: Any) -> "RodParams":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "RodParams":
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        if unknown := set(data) - {f.name for f in dataclasses.fields(cls)}:
            raise ValueError(f"unknown RodParams fields: {sorted(unknown)}")
        return cls(**data)

    @classmethod
    def from_json(cls, path: "str | Path") -> "RodParams":
        """Read a JSON object of :meth:`to_dict` fields, or a document with one as ``rod_params`` (what
        ``softpend identify --out`` writes); any problem is a ``ValueError`` naming the file."""
        from softpend.io.reading import read_json_checked

        path = Path(path)
        try:
            data = read_json_checked(path, "rod parameter file", _MAX_JSON_BYTES)
        except OSError as exc:
            raise ValueError(f"{path}: cannot read rod parameters: {' '.join(str(exc).split())}") from None
        if isinstance(data, dict) and isinstance(data.get("rod_params"), dict):
            data = data["rod_params"]
        if not isinstance(data, dict):
            raise ValueError(f"{path}: rod parameters must be a JSON object, got {type(data).__name__}")
        try:
            return cls.from_dict(data)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}: {' '.join(str(exc).split())}") from None


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
