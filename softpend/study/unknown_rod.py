"""Unknown rods for commissioning: a rod and a motor torque gain drawn from a seed, each physical field within a
factor of the default, kept only when the controller designed on its true parameters balances it.

A torque gain ``g`` (the motor gives ``g`` N m per commanded N m) is exactly a rod whose masses, inertias,
friction, stiffness and damping are divided by ``g``: the PRB equations are linear in those and in the torque
(:meth:`UnknownRod.effective_rod`). The twin simulates that rod, so the emulator needs no torque-gain setting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from softpend.checks import instance_of, int_at_least, positive, positive_int
from softpend.evaluation import HOLD_STD_RAD, TEST_EPISODE_S, evaluate
from softpend.plant import RodParams
from softpend.task import Task

#: The rod fields an unknown rod draws (besides the torque gain).
UNKNOWN_FIELDS: tuple[str, ...] = tuple(
    "hub_inertia_kgm2 hub_friction_nms_per_rad youngs_modulus_pa joint_damping_nms_per_rad tip_mass_kg".split()
)
#: Each drawn value lies log-uniformly in ``[default / SPREAD_FACTOR, default * SPREAD_FACTOR]``.
SPREAD_FACTOR = 2.0
#: The rod fields a torque gain divides (every term of the equations of motion but the torque): the mass and the
#: unknown fields.
_GAIN_DIVIDES: tuple[str, ...] = ("mass_kg", *UNKNOWN_FIELDS)
#: Most rods :func:`draw_unknown_rod` draws.
MAX_DRAWS = 50
#: Largest unknown-rod JSON file [bytes].
_MAX_JSON_BYTES = 10**6


@dataclass(frozen=True)
class UnknownRod:
    """A rod and the motor's torque gain [N m per commanded N m]."""

    rod: RodParams
    torque_gain: float = 1.0

    def __post_init__(self) -> None:
        instance_of("rod", self.rod, RodParams)
        object.__setattr__(self, "torque_gain", positive("torque_gain", self.torque_gain))

    def effective_rod(self) -> RodParams:
        """The rod that moves under a commanded torque as :attr:`rod` moves under :attr:`torque_gain` times it (same
        torque limit on the command): what the twin simulates."""
        return self.rod.replace(**{name: getattr(self.rod, name) / self.torque_gain for name in _GAIN_DIVIDES})

    def values(self) -> dict[str, float]:
        """The drawn fields and ``torque_gain`` by name."""
        return {**{name: float(getattr(self.rod, name)) for name in UNKNOWN_FIELDS}, "torque_gain": self.torque_gain}

    def to_dict(self) -> dict[str, Any]:
        return {"rod_params": self.rod.to_dict(), "torque_gain": self.torque_gain}

    @classmethod
    def from_dict(cls, data: Any, what: str = "unknown rod") -> "UnknownRod":
        """A document ``{"rod_params": {...}, "torque_gain": g}`` (what :meth:`to_dict` and ``softpend identify``
        write, the gain also under ``calibration``) or a plain RodParams object with an optional
        ``torque_gain``; ``ValueError`` naming ``what`` otherwise."""
        if not isinstance(data, dict):
            raise ValueError(f"{what} must be a JSON object, got {type(data).__name__}")
        if isinstance(data.get("rod_params"), dict):
            fields = dict(data["rod_params"])
            calibration = data["calibration"] if isinstance(data.get("calibration"), dict) else {}
            gain: Any = data.get("torque_gain", calibration.get("torque_gain", 1.0))
        else:
            fields = dict(data)
            gain = fields.pop("torque_gain", 1.0)
        try:
            return cls(RodParams.from_dict(fields), gain)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{what}: {' '.join(str(exc).split())}") from None

    @classmethod
    def from_json(cls, path: str | Path) -> "UnknownRod":
        from softpend.io.reading import read_json_checked

        try:
            data = read_json_checked(Path(path), "rod file", _MAX_JSON_BYTES)
        except OSError as exc:
            raise ValueError(" ".join(str(exc).split())) from None
        return cls.from_dict(data, f"rod file {path}")


def balanced_starts(
    rod: RodParams, seeds: Sequence[int], duration_s: float = TEST_EPISODE_S, design_rod: RodParams | None = None
) -> int:
    """How many hanging starts ``seeds`` of the simulated ``rod`` the energy swing-up + LQR on the observations,
    designed on ``design_rod`` (default: ``rod`` itself), swings up and holds within :data:`HOLD_STD_RAD`."""
    from softpend.control.identified import design_swingup

    controller = design_swingup(design_rod if design_rod is not None else rod)
    summary = evaluate(controller, Task(rod=rod), seeds=list(seeds), duration_s=duration_s)
    return sum(math.isfinite(r.swing_up_time_s) and r.upright_std_rad <= HOLD_STD_RAD for r in summary.results)


#: A drawn rod counts when the swing-up + LQR designed on its true parameters balances DRAW_NEEDED of DRAW_STARTS
#: hanging starts of DRAW_DURATION_S each.
DRAW_STARTS, DRAW_NEEDED, DRAW_DURATION_S = 10, 9, TEST_EPISODE_S


def draw_unknown_rod(
    seed: int, starts: int = DRAW_STARTS, needed: int = DRAW_NEEDED, duration_s: float = DRAW_DURATION_S
) -> tuple[UnknownRod, int]:
    """``(rod, draws)``: the first rod drawn from ``seed`` whose :data:`UNKNOWN_FIELDS` and torque gain lie
    log-uniformly within :data:`SPREAD_FACTOR` of ``RodParams()`` (gain 1) that the controller designed on its true
    parameters balances from at least ``needed`` of ``starts`` hanging starts, and how many rods were drawn;
    ``ValueError`` when none of :data:`MAX_DRAWS` is."""
    starts, needed = positive_int("starts", starts), positive_int("needed", needed)
    if needed > starts:
        raise ValueError(f"needed must be at most starts ({starts}), got {needed}")
    rng, base, spread = np.random.default_rng(int_at_least("seed", seed, 0)), RodParams(), math.log(SPREAD_FACTOR)
    for draw in range(1, MAX_DRAWS + 1):
        factors = np.exp(rng.uniform(-spread, spread, len(UNKNOWN_FIELDS) + 1))
        rod = base.replace(**{name: getattr(base, name) * f for name, f in zip(UNKNOWN_FIELDS, factors)})
        candidate = UnknownRod(rod, float(factors[-1]))
        seeds = [int(s) for s in rng.integers(0, 2**31 - 1, starts)]
        if balanced_starts(candidate.effective_rod(), seeds, duration_s) >= needed:
            return candidate, draw
    raise ValueError(f"seed {seed}: none of {MAX_DRAWS} drawn rods is balanced from {needed} of {starts} starts")
