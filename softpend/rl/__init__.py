"""Reinforcement learning: model-free DQN and model-based DQN-MBPO that swing the soft rod up and balance it."""

from softpend.rl.config import DQNConfig, DQNLearner, MBPOConfig, ModelSettings, RolloutSettings, StopRule
from softpend.rl.training_log import TrainingLog

__all__ = ["DQNConfig", "DQNLearner", "MBPOConfig", "ModelSettings", "RolloutSettings", "StopRule", "TrainingLog"]
