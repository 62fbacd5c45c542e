"""Physical parameters of the soft pendulum (the report's Table 1, in SI units).

The rod is a pseudo-rigid-body (PRB) chain: ``n_links`` rigid links of equal length ``L/n`` joined by
torsional springs and dampers, clamped to a motor hub that is driven by the base torque.

Mapping from beam properties to joint stiffness
-----------------------------------------------
For a beam of Young's modulus ``E`` and rectangular cross-section of width ``W`` and depth ``D`` (``D`` is
the thickness in the bending direction) the second moment of area is ``I = W*D**3/12`` and the usual PRB
joint stiffness is ``k = E*I/(L/n)``: each spring lumps the compliance of one segment of length ``L/n``.
The springs sit at the clamp and between links, so the spring at the clamp only lumps the half segment
next to it and gets ``2*k``; with this choice the static tip deflection is the trapezoidal rule applied to
the Euler-Bernoulli curvature integral, which converges as ``1/n**2`` (1.6% at ``n = 8``). Joint damping
is lumped the same way (``zeta`` interior, ``2*zeta`` at the clamp).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from softpend.checks import finite, int_at_least, non_negative, positive

GRAVITY_MPS2 = 9.81

#: Most links a PRB rod may have: 64.  The PRB chain is simulated with dense linear algebra on its
#: ``n_links + 1`` joint coordinates at every Newton iteration (memory and time grow as ``n**2`` and ``n**3``:
#: 100 000 links would need some 80 GB for one matrix), and the PRB discretisation error of the static tip
#: deflection falls as ``1/n**2`` (1.6 % at ``n = 8``), so that at 64 links it is about 0.03 %, far below the
#: uncertainty of the rod's measured parameters: more links add cost, not accuracy.
MAX_N_LINKS = 64


@dataclass(frozen=True)
class RodParams:
    """Parameters of the motor hub and the soft rod (SI units).

    Parameters
    ----------
    length_m : float
        Rod length ``L`` from the hub axis to the tip [m].
    n_links : int
        Number of rigid links ``n`` (1 to :data:`MAX_N_LINKS`).
    mass_kg : float
        Rod mass ``m`` (uniformly distributed over the links) [kg].
    width_m, depth_m : float
        Cross-section width ``W`` and depth ``D`` (bending direction) [m].
    youngs_modulus_pa : float
        Young's modulus ``E`` [Pa]; sets the spring constant ``k = E*W*D**3/12/(L/n)``.
    joint_damping_nms_per_rad : float
        Damping ``zeta`` of each interior joint [N m s/rad] (twice this at the clamp).
    tip_mass_kg : float
        Point mass at the tip (the rig's end mass and tracking dot) [kg].
    hub_inertia_kgm2 : float
        Rotor inertia of the motor hub, reflected through the gearbox [kg m^2].
    hub_friction_nms_per_rad : float
        Viscous friction of the hub bearing and motor [N m s/rad].
    torque_limit_nm : float
        Largest base torque magnitude the motor can apply [N m].
    gravity_mps2 : float
        Gravitational acceleration [m/s^2].
    stiffness_scale : float
        Multiplies every joint stiffness (1 = beam theory; 0 = a chain of freely hinged links).
    """

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
        for field in dataclasses.fields(self):
            finite(field.name, getattr(self, field.name))
        n_links = int_at_least("n_links", self.n_links, 1)
        if n_links > MAX_N_LINKS:
            raise ValueError(
                f"n_links must be at most {MAX_N_LINKS} (see softpend.plant.params.MAX_N_LINKS), got {self.n_links!r}"
            )
        for name in ("length_m", "mass_kg", "width_m", "depth_m", "torque_limit_nm"):
            positive(name, getattr(self, name))
        for name in (
            "youngs_modulus_pa",
            "joint_damping_nms_per_rad",
            "tip_mass_kg",
            "hub_inertia_kgm2",
            "hub_friction_nms_per_rad",
            "gravity_mps2",
            "stiffness_scale",
        ):
            non_negative(name, getattr(self, name))
        object.__setattr__(self, "n_links", n_links)

    # ----------------------------------------------------------------- derived quantities
    @property
    def second_moment_m4(self) -> float:
        """Second moment of area ``I = W*D**3/12`` [m^4]."""
        return self.width_m * self.depth_m**3 / 12.0

    @property
    def bending_stiffness_nm2(self) -> float:
        """Flexural rigidity ``E*I`` [N m^2] (times ``stiffness_scale``)."""
        return self.youngs_modulus_pa * self.second_moment_m4 * self.stiffness_scale

    @property
    def link_length_m(self) -> float:
        """Length of one rigid link ``L/n`` [m]."""
        return self.length_m / self.n_links

    @property
    def link_mass_kg(self) -> float:
        """Mass of one rigid link ``m/n`` [kg] (the tip mass is extra)."""
        return self.mass_kg / self.n_links

    @property
    def joint_stiffness_nm_per_rad(self) -> float:
        """Interior PRB spring constant ``k = E*I/(L/n)`` [N m/rad]."""
        return self.bending_stiffness_nm2 / self.link_length_m

    def spring_stiffnesses_nm_per_rad(self) -> list[float]:
        """Stiffness of the ``n`` springs, clamp first (``2k, k, ..., k``) [N m/rad]."""
        k = self.joint_stiffness_nm_per_rad
        return [2.0 * k] + [k] * (self.n_links - 1)

    def spring_dampings_nms_per_rad(self) -> list[float]:
        """Damping of the ``n`` springs, clamp first (``2 zeta, zeta, ...``) [N m s/rad]."""
        z = self.joint_damping_nms_per_rad
        return [2.0 * z] + [z] * (self.n_links - 1)

    @property
    def total_mass_kg(self) -> float:
        """Rod plus tip mass [kg]."""
        return self.mass_kg + self.tip_mass_kg

    @property
    def gravity_torque_horizontal_nm(self) -> float:
        """Torque needed to hold the straight rod horizontal, ``g*(m*L/2 + m_tip*L)`` [N m]."""
        return self.gravity_mps2 * (self.mass_kg * self.length_m / 2 + self.tip_mass_kg * self.length_m)

    @property
    def static_sag_euler_bernoulli_m(self) -> float:
        """Euler-Bernoulli tip deflection of the horizontal clamped rod under its own weight and the tip
        mass: ``w*L**4/(8*E*I) + P*L**3/(3*E*I)`` [m] (small-deflection theory)."""
        ei = self.bending_stiffness_nm2
        if ei == 0:
            return math.inf
        w = self.mass_kg * self.gravity_mps2 / self.length_m
        p = self.tip_mass_kg * self.gravity_mps2
        return w * self.length_m**4 / (8 * ei) + p * self.length_m**3 / (3 * ei)

    def replace(self, **changes: Any) -> "RodParams":
        """Return a copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, float]:
        """Plain ``dict`` of the fields (for JSON metadata)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "RodParams":
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"unknown RodParams fields: {sorted(unknown)}")
        return cls(**data)

    @classmethod
    def from_json(cls, path: "str | Path") -> "RodParams":
        """Read parameters from a JSON file: an object of :meth:`to_dict` fields, or a document whose
        ``rod_params`` member is one (what ``softpend identify --out`` writes, beside the estimates and their
        uncertainties).

        Raises
        ------
        ValueError
            If the file cannot be read, is not a JSON object, or its fields are unknown or invalid (the message
            names the file).
        """
        from softpend.io.reading import read_json_checked

        path = Path(path)
        try:  # a regular file of at most _MAX_JSON_BYTES (a FIFO or device would block or never end)
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


#: Largest rod-parameter JSON file read by :meth:`RodParams.from_json` [bytes].
_MAX_JSON_BYTES = 10**6
