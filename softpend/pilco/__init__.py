"""PILCO (Deisenroth & Rasmussen, 2011) on the soft pendulum, in PyTorch.

* :mod:`~softpend.pilco.moments` -- exact moment matching (GP prediction at a Gaussian input, sin/cos of
  Gaussian angles, the sine saturation, the saturating cost);
* :mod:`~softpend.pilco.gp` -- GP dynamics model (SE-ARD, one GP per output, penalised marginal likelihood);
* :mod:`~softpend.pilco.policy` -- the saturated RBF-network policy;
* :mod:`~softpend.pilco.propagation` -- state representation and the moment-matching rollout with its cost;
* :mod:`~softpend.pilco.controller` -- a policy as a :class:`softpend.evaluation.Controller` (zero-order hold);
* :mod:`~softpend.pilco.loop` -- PILCO on the plant as an object (:class:`Pilco`) and its loop (:func:`run_pilco`).
"""

from softpend.pilco.controller import PilcoController, RandomTorqueController
from softpend.pilco.gp import GPHyperparameters, MultiOutputGP
from softpend.pilco.loop import Pilco, PilcoConfig, PilcoResult, PolicySearch, TrialRecord, run_pilco
from softpend.pilco.policy import RBFPolicy
from softpend.pilco.propagation import STATE_SPECS, Propagator, StateSpec, state_spec

__all__ = [
    "GPHyperparameters",
    "MultiOutputGP",
    "Pilco",
    "PilcoConfig",
    "PilcoController",
    "PilcoResult",
    "PolicySearch",
    "Propagator",
    "RBFPolicy",
    "RandomTorqueController",
    "STATE_SPECS",
    "StateSpec",
    "TrialRecord",
    "run_pilco",
    "state_spec",
]
