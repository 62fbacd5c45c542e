"""PILCO (Deisenroth & Rasmussen, 2011) on the soft pendulum, in PyTorch."""

from softpend.pilco.controller import PilcoController, RandomTorqueController
from softpend.pilco.gp import GPHyperparameters, MultiOutputGP
from softpend.pilco.loop import (
    CostSettings,
    GPSettings,
    OptimiserSettings,
    Pilco,
    PilcoConfig,
    PilcoResult,
    PolicySearch,
    PolicySettings,
    TrialRecord,
    run_pilco,
)
from softpend.pilco.policy import RBFPolicy
from softpend.pilco.propagation import STATE_SPECS, Propagator, StateSpec, state_spec

__all__ = [
    "CostSettings",
    "GPHyperparameters",
    "GPSettings",
    "MultiOutputGP",
    "OptimiserSettings",
    "Pilco",
    "PilcoConfig",
    "PilcoController",
    "PilcoResult",
    "PolicySearch",
    "PolicySettings",
    "Propagator",
    "RBFPolicy",
    "RandomTorqueController",
    "STATE_SPECS",
    "StateSpec",
    "TrialRecord",
    "run_pilco",
    "state_spec",
]
