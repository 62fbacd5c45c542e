"""Plant registry: name -> ``"module:Class"`` entry point, imported only when a plant of that name is made."""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np

from softpend.plant.base import Plant
from softpend.plant.params import RodParams

_PLANTS: dict[str, str] = {"prb": "softpend.plant.prb:PRBPlant", "beam": "softpend.plant.beam:BeamPlant"}


def plant_names() -> list[str]:
    """Names accepted by :func:`make_plant`."""
    return sorted(_PLANTS)


def check_plant_name(plant: Any, parameter: str = "plant") -> str:
    """``plant`` if :func:`make_plant` knows it, else a ``ValueError`` naming ``parameter``."""
    names = plant_names()
    if plant not in names:
        raise ValueError(f"{parameter} must be one of {names}, got {plant!r}")
    return plant


def make_plant(name: str = "prb", **kwargs: Any) -> "Plant":
    """Build the plant registered as ``name`` with ``kwargs`` (``params``, ``dt_s``, plant options)."""
    module_name, attribute = _PLANTS[check_plant_name(name)].split(":")
    return getattr(importlib.import_module(module_name), attribute)(**kwargs)


def tilt_state(params: RodParams, tilt_rad: float, plant: str = "prb") -> tuple[np.ndarray, np.ndarray]:
    """``(q, q_dot)`` of the straight rod at rest tilted by ``tilt_rad`` from upright, for plant ``plant``."""
    n = params.n_links + 1 if plant == "prb" else make_plant(plant, params=params).n_coordinates
    q = np.zeros(n)
    q[0] = tilt_rad
    return q, np.zeros_like(q)
