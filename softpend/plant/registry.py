"""Plant registry: name -> ``"module:Class"`` entry point, as Gymnasium registers environments.

Every plant takes ``(params, dt_s, **options)`` and implements :class:`~softpend.plant.protocol.Plant`.  Entry
points are imported only when a plant of that name is made, so the registry imports no plant module and an
import error of a plant (a broken Exudyn install) surfaces when that plant is asked for, with its cause.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any, Callable, Union

if TYPE_CHECKING:
    from softpend.plant.protocol import Plant

__all__ = ["check_plant_name", "make_plant", "plant_names", "register_plant"]

EntryPoint = Union[str, Callable[..., "Plant"]]

_PLANTS: dict[str, EntryPoint] = {
    "prb": "softpend.plant.prb:PRBPlant",
    "beam": "softpend.plant.beam:BeamPlant",
}


def register_plant(name: str, entry_point: EntryPoint) -> None:
    """Make ``make_plant(name, ...)`` build ``entry_point`` (a ``"module:Class"`` string or a callable)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"plant name must be a non-empty string, got {name!r}")
    if isinstance(entry_point, str):
        if entry_point.count(":") != 1 or not all(entry_point.split(":")):
            raise ValueError(f"entry_point must look like 'module:Class', got {entry_point!r}")
    elif not callable(entry_point):
        raise ValueError(f"entry_point must be a 'module:Class' string or a callable, got {entry_point!r}")
    _PLANTS[name] = entry_point


def plant_names() -> list[str]:
    """Names accepted by :func:`make_plant`."""
    return sorted(_PLANTS)


def check_plant_name(plant: Any, parameter: str = "plant") -> str:
    """``plant`` if :func:`make_plant` knows it, else a ``ValueError`` naming ``parameter`` and the known plants
    (the one check every config, notebook and command uses before any work starts)."""
    names = plant_names()
    if plant not in names:
        raise ValueError(f"{parameter} must be one of {names}, got {plant!r}")
    return plant


def plant_class(name: str) -> Callable[..., "Plant"]:
    """The constructor registered under ``name`` (its module imported now)."""
    check_plant_name(name)
    entry = _PLANTS[name]
    if not isinstance(entry, str):
        return entry
    module_name, attribute = entry.split(":")
    module = importlib.import_module(module_name)
    try:
        return getattr(module, attribute)
    except AttributeError as exc:
        raise ValueError(f"plant {name!r}: {module_name} has no {attribute!r} (entry point {entry!r})") from exc


def make_plant(name: str = "prb", **kwargs: Any) -> "Plant":
    """Build the plant registered as ``name`` with ``kwargs`` (``params``, ``dt_s``, plant options).

    Raises
    ------
    ValueError
        If ``name`` is unknown.
    """
    return plant_class(name)(**kwargs)
