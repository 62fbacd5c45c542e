"""Names of the observed variables used by system identification (a view on the plant's observation)."""

from __future__ import annotations

from softpend.plant import OBSERVATION_NAMES

__all__ = ["POSITION_NAMES", "VELOCITY_NAMES", "ANGLE_NAMES", "velocity_name", "is_angle"]

#: The report's sampled quantities ``q = [phi, theta, e_x, e_y]`` plus the tip rotation ``e_r``.
POSITION_NAMES: tuple[str, ...] = OBSERVATION_NAMES[:5]
#: Their first time derivatives, same order.
VELOCITY_NAMES: tuple[str, ...] = OBSERVATION_NAMES[5:]
#: Position variables that are angles (wrapped to ``[-pi, pi)``; unwrapped before differencing).
ANGLE_NAMES: frozenset[str] = frozenset({"phi_rad", "theta_rad", "er_rad"})

assert len(POSITION_NAMES) == len(VELOCITY_NAMES) == 5


def velocity_name(position_name: str) -> str:
    """Name of the derivative of a position variable (``"ex_m"`` -> ``"ex_dot_m_s"``)."""
    if position_name not in POSITION_NAMES:
        raise ValueError(f"position_name must be one of {POSITION_NAMES}, got {position_name!r}")
    return VELOCITY_NAMES[POSITION_NAMES.index(position_name)]


def is_angle(name: str) -> bool:
    """Whether a position variable is an angle [rad] (else a length [m])."""
    return name in ANGLE_NAMES
