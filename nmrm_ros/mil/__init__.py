"""MIL reward models (torch): architectures, training, evaluation, checkpoints, online stepping."""

from .checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from .ensemble import MILEnsemble, as_ensemble
from .evaluation import evaluate
from .models import (ARCHITECTURE_NAMES, ARCHITECTURES, MILOutput, MILRewardModel, ModelConfig,
                     build_model, model_config)
from .online import OnlineRewardModel
from .training import TrainConfig, TrainResult, load_train_config, train_model

__all__ = ["ARCHITECTURES", "ARCHITECTURE_NAMES", "CheckpointError", "MILEnsemble", "MILOutput", "MILRewardModel",
           "ModelConfig", "OnlineRewardModel", "TrainConfig", "TrainResult", "build_model",
           "as_ensemble", "evaluate", "load_checkpoint", "load_train_config", "model_config", "save_checkpoint",
           "train_model"]
