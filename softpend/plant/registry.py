"""Name -> plant constructor, so environments, controllers and the rig emulator can run on any plant.

Every plant takes ``(params, dt_s, **options)`` and offers the interface of :class:`~softpend.plant.PRBPlant`:
``reset(q, q_dot)``, ``step(torque_nm) -> Observation``, ``observe()``, ``joint_state()``,
``hanging_state()``, ``link_points_m()``, ``energy_j()``, ``time_s``, ``n_coordinates``, ``params``.
"""

from __future__ import annotations

from typing import Any, Callable

_PLANTS: dict[str, Callable[..., Any]] = {}


def register_plant(name: str, factory: Callable[..., Any]) -> None:
    """Make ``make_plant(name, ...)`` call ``factory(...)``."""
    _PLANTS[name] = factory


def plant_names() -> list[str]:
    """Names accepted by :func:`make_plant`."""
    _load_builtin()
    return sorted(_PLANTS)


def check_plant_name(plant: Any, parameter: str = "plant") -> str:
    """``plant`` if :func:`make_plant` knows it, else a ``ValueError`` naming ``parameter`` and the known plants
    (the one check every config, notebook and command uses before any work starts)."""
    names = plant_names()
    if plant not in names:
        raise ValueError(f"{parameter} must be one of {names}, got {plant!r}")
    return plant


def make_plant(name: str = "prb", **kwargs: Any) -> Any:
    """Build a plant by name (``"prb"``; other plants register themselves on import).

    Raises
    ------
    ValueError
        If ``name`` is unknown.
    """
    check_plant_name(name)
    return _PLANTS[name](**kwargs)


def _load_builtin() -> None:
    from .prb import PRBPlant

    _PLANTS.setdefault("prb", PRBPlant)
    try:  # the continuum-beam plant is optional until it exists
        from . import beam  # noqa: F401
    except ImportError:
        pass
