"""System identification: motor babbling, datasets and learned dynamics models."""

from softpend.sysid.babble import BabbleProtocol, babble, band_limited_noise
from softpend.sysid.dataset import TrajectoryDataset, load_dataset, save_dataset, write_dataset
from softpend.sysid.layout import StateLayout
from softpend.sysid.metrics import (
    evaluate_model,
    hub_rate_offset_for_tip_error,
    one_step_errors,
    perturbed_simulator_errors,
    rollout_errors,
    rollout_trial,
)
from softpend.sysid.model import DynamicsEnsemble, DynamicsModel, load_model, rollout, save_model
from softpend.sysid.training import TrainConfig, fit_dynamics_model
from softpend.sysid.variables import backward_difference

__all__ = [
    "BabbleProtocol",
    "TrajectoryDataset",
    "babble",
    "backward_difference",
    "band_limited_noise",
    "load_dataset",
    "save_dataset",
    "write_dataset",
    "StateLayout",
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
    "TrainConfig",
    "fit_dynamics_model",
]
