"""Plant registry: name -> ``"module:Class"`` entry point, imported only when a plant of that name is made."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from softpend.plant.base import Plant

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
