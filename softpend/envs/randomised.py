"""Domain randomisation from an identification's uncertainty: rods drawn around a model rod, each field times
``exp(u)``, ``u`` uniform within ``scale`` relative standard deviations (capped at a factor ``e``), and the gym
wrapper that trains on a freshly drawn rod every episode."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional

import gymnasium as gym
import numpy as np

from softpend.checks import non_negative, positive
from softpend.plant import RodParams, make_plant
from softpend.task import Task

#: Salt of a wrapper's rod stream, mixed with the seed of its seeded reset.
ROD_STREAM_SALT = 66


@dataclass(frozen=True)
class RodUncertainty:
    """Relative standard deviations of rod fields (``(name, relative_std)`` pairs) and the draws' width in them."""

    relative_std: tuple[tuple[str, float], ...]
    scale: float = 2.0

    def __post_init__(self) -> None:
        pairs: Any = self.relative_std.items() if isinstance(self.relative_std, Mapping) else self.relative_std
        try:
            named = [(str(name), value) for name, value in pairs]
        except (TypeError, ValueError):
            raise ValueError(f"rod_uncertainty.relative_std must be (field, relative std) pairs, got {pairs!r}"[:300])
        if unknown := [name for name, _ in named if name not in {f.name for f in dataclasses.fields(RodParams)}]:
            raise ValueError(f"rod_uncertainty: {unknown[0]!r} is not a RodParams field")
        object.__setattr__(self, "relative_std", tuple((n, non_negative(f"rod_uncertainty.{n}", v)) for n, v in named))
        positive("rod_uncertainty.scale", self.scale)

    def to_dict(self) -> dict[str, Any]:
        return {"relative_std": dict(self.relative_std), "scale": self.scale}

    @classmethod
    def from_dict(cls, data: Any) -> "RodUncertainty":
        std = data.get("relative_std") if isinstance(data, Mapping) and set(data) == {"relative_std", "scale"} else None
        if not isinstance(std, Mapping):
            raise ValueError(f"rod_uncertainty must be an object of relative_std and scale, got {data!r}"[:300])
        return cls(tuple(std.items()), data["scale"])

    def draw(self, rod: RodParams, rng: np.random.Generator) -> RodParams:
        """``rod`` with each field times ``exp(u)``, ``u`` uniform within ``min(scale * relative_std, 1)``."""
        changes = {}
        for name, relative in self.relative_std:
            changes[name] = getattr(rod, name) * math.exp(rng.uniform(-1.0, 1.0) * min(self.scale * relative, 1.0))
        return rod.replace(**changes)


def optional_uncertainty(data: Optional[Any]) -> Optional[RodUncertainty]:
    """A config's ``rod_uncertainty`` from a :class:`RodUncertainty`, its saved data or None; ``ValueError``
    otherwise."""
    return data if data is None or isinstance(data, RodUncertainty) else RodUncertainty.from_dict(data)


def set_rod(env: Any, task: Task, rod: RodParams) -> None:
    """Rebuild the plant of a :class:`~softpend.envs.SoftPendulumEnv` of ``task`` for ``rod``."""
    env.params = rod
    env.plant = make_plant(task.plant, params=rod, dt_s=task.dt_s, substeps=task.substeps)


class RandomisedRod(gym.Wrapper):
    """Each reset first rebuilds the inner environment's plant for a rod drawn from ``uncertainty`` around
    ``task.rod``; the draws come from a stream seeded by the seed of a seeded reset."""

    def __init__(self, env: gym.Env, task: Task, uncertainty: RodUncertainty) -> None:
        super().__init__(env)
        self.task, self.uncertainty = task, uncertainty
        self.rng = np.random.default_rng(ROD_STREAM_SALT)
        self.rod = task.rod

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None):
        if seed is not None:
            self.rng = np.random.default_rng([int(seed), ROD_STREAM_SALT])
        self.rod = self.uncertainty.draw(self.task.rod, self.rng)
        set_rod(self.env.unwrapped, self.task, self.rod)
        return self.env.reset(seed=seed, options=options)
