"""PILCO (Deisenroth & Rasmussen, 2011) on the soft pendulum, in PyTorch."""

from softpend.pilco.controller import RandomTorqueController
from softpend.pilco.loop import (
    CostSettings,
    GPSettings,
    OptimiserSettings,
    Pilco,
    PilcoConfig,
    PilcoResult,
    PolicySettings,
    run_pilco,
)
from softpend.pilco.policy import RBFPolicy
from softpend.pilco.propagation import state_spec

__all__ = [
    "CostSettings",
    "GPSettings",
    "OptimiserSettings",
    "Pilco",
    "PilcoConfig",
    "PilcoResult",
    "PolicySettings",
    "RBFPolicy",
    "RandomTorqueController",
    "run_pilco",
    "state_spec",
]
