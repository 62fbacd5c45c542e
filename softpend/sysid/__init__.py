"""System identification: motor babbling, datasets and learned dynamics models."""

from softpend.sysid.babble import BabbleProtocol, babble, band_limited_noise
from softpend.sysid.dataset import SCHEMA_VERSION, TrajectoryDataset, load_dataset, save_dataset, write_dataset
from softpend.sysid.differentiation import backward_difference
from softpend.sysid.layout import INFORMATION_LEVELS, StateLayout, TransitionData
from softpend.sysid.metrics import (
    RolloutErrors,
    evaluate_model,
    hub_rate_offset_for_tip_error,
    one_step_errors,
    perturbed_simulator_errors,
    rollout_errors,
    rollout_trial,
)
from softpend.sysid.model import DynamicsEnsemble, DynamicsModel, load_model, save_model
from softpend.sysid.rollout import rollout
from softpend.sysid.training import FitResult, TrainConfig, fit_dynamics_model, split_trials

__all__ = [
    "BabbleProtocol",
    "SCHEMA_VERSION",
    "TrajectoryDataset",
    "babble",
    "backward_difference",
    "band_limited_noise",
    "load_dataset",
    "save_dataset",
    "write_dataset",
    "INFORMATION_LEVELS",
    "StateLayout",
    "TransitionData",
    "RolloutErrors",
    "evaluate_model",
    "hub_rate_offset_for_tip_error",
    "one_step_errors",
    "perturbed_simulator_errors",
    "rollout_errors",
    "rollout_trial",
    "DynamicsEnsemble",
    "DynamicsModel",
    "load_model",
    "save_model",
    "rollout",
    "FitResult",
    "TrainConfig",
    "fit_dynamics_model",
    "split_trials",
]
