"""The control task: which plant, which rod, which time step, which start distribution."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from softpend.checks import int_at_least, non_negative, one_of, positive
from softpend.plant import RodParams, check_plant_name, make_plant, tilt_state
from softpend.plant.base import Plant
from softpend.plant.params import GRAVITY_MPS2

#: Start distributions of the environments (:class:`softpend.envs.SoftPendulumEnv` ``start``).
START_KINDS = ("hanging", "upright", "random")

#: Largest torque limit of a task, as a multiple of the torque that holds its rod horizontal against standard
#: gravity (beyond it the plant's solver fails in the first steps).
MAX_TORQUE_RATIO = 100.0


@dataclass(frozen=True)
class Task:
    """The plant and start distribution a controller is trained and evaluated on (SI units)."""

    plant: str = "prb"
    rod: RodParams = field(default_factory=RodParams)
    dt_s: float = 0.01
    substeps: int = 2
    start: str = "hanging"
    start_noise_rad: float = 0.05

    def __post_init__(self) -> None:
        check_plant_name(self.plant, "task.plant")
        if not isinstance(self.rod, RodParams):
            raise ValueError(f"task.rod must be a RodParams, got {type(self.rod).__name__}")
        object.__setattr__(self, "dt_s", positive("task.dt_s", self.dt_s))
        object.__setattr__(self, "substeps", int_at_least("task.substeps", self.substeps, 1))
        one_of("task.start", self.start, START_KINDS)
        object.__setattr__(self, "start_noise_rad", non_negative("task.start_noise_rad", self.start_noise_rad))
        rod = self.rod
        most = MAX_TORQUE_RATIO * (rod.mass_kg / 2 + rod.tip_mass_kg) * rod.length_m * GRAVITY_MPS2
        if rod.torque_limit_nm > most:
            raise ValueError(
                f"task.rod.torque_limit_nm must be at most {most:.4g} N m ({MAX_TORQUE_RATIO:g} times the "
                f"torque that holds this rod horizontal; see softpend.task.MAX_TORQUE_RATIO), got "
                f"{rod.torque_limit_nm!r}"
            )

    def make_plant(self, **options: Any) -> Plant:
        """A fresh plant of this task (``options``: plant-specific, e.g. ``hub_locked_at_rad``)."""
        return make_plant(self.plant, params=self.rod, dt_s=self.dt_s, substeps=self.substeps, **options)

    def env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :class:`softpend.envs.SoftPendulumEnv` for this task."""
        names = ("plant", "dt_s", "substeps", "start", "start_noise_rad")
        return {"params": self.rod, **{name: getattr(self, name) for name in names}}

    def tilt_state(self, tilt_rad: float) -> tuple[np.ndarray, np.ndarray]:
        """``(q, q_dot)`` of the straight rod at rest, hub and tip tilted by ``tilt_rad`` [rad] from upright."""
        return tilt_state(self.rod, tilt_rad, self.plant)

    @property
    def torque_limit_nm(self) -> float:
        """The motor's torque limit [N m] (``rod.torque_limit_nm``)."""
        return self.rod.torque_limit_nm

    def replace(self, **changes: Any) -> "Task":
        """A copy with task fields changed; any :class:`~softpend.plant.RodParams` field name changes the rod
        (``task.replace(torque_limit_nm=0.05, start="upright")``)."""
        rod_fields = {f.name for f in dataclasses.fields(RodParams)}
        rod_changes = {k: changes.pop(k) for k in list(changes) if k in rod_fields}
        _check_fields(changes)
        if rod_changes:
            changes["rod"] = changes.get("rod", self.rod).replace(**rod_changes)
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain ``dict`` (for JSON), the rod as a nested ``dict``."""
        return {**dataclasses.asdict(self), "rod": self.rod.to_dict()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Task":
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        data = dict(data)
        _check_fields(data)
        if "rod" in data and not isinstance(data["rod"], RodParams):
            data["rod"] = RodParams.from_dict(data["rod"])
        return cls(**data)


def _check_fields(data: Mapping[str, Any]) -> None:
    unknown = set(data) - {f.name for f in dataclasses.fields(Task)}
    if unknown:
        raise ValueError(f"unknown Task fields: {sorted(unknown)}")
