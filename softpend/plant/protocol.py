"""The interface every plant implements (:class:`softpend.plant.base.PlantBase`)."""

from softpend.plant.base import Plant

__all__ = ["Plant"]
