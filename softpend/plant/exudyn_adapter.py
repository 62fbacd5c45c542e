"""The old home of :data:`softpend.plant.base.SolverFailure` (the Exudyn solver's failure)."""

from softpend.plant.base import SolverFailure, static_solver_settings

__all__ = ["SolverFailure", "static_solver_settings"]
