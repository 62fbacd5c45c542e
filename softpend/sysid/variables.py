"""Names of the observed variables used by system identification (a view on the plant's observation)."""

from __future__ import annotations

from softpend.plant import OBSERVATION_NAMES

#: The sampled positions ``phi, theta, e_x, e_y, e_r`` and their time derivatives, same order.
POSITION_NAMES: tuple[str, ...] = OBSERVATION_NAMES[:5]
VELOCITY_NAMES: tuple[str, ...] = OBSERVATION_NAMES[5:]
#: Position variables that are angles (wrapped to ``[-pi, pi)``).
ANGLE_NAMES: frozenset[str] = frozenset({"phi_rad", "theta_rad", "er_rad"})


def velocity_name(position_name: str) -> str:
    """Name of the derivative of a position variable (``"ex_m"`` -> ``"ex_dot_m_s"``)."""
    if position_name not in POSITION_NAMES:
        raise ValueError(f"position_name must be one of {POSITION_NAMES}, got {position_name!r}")
    return VELOCITY_NAMES[POSITION_NAMES.index(position_name)]


def is_angle(name: str) -> bool:
    return name in ANGLE_NAMES
