"""MIL reward models (torch): architectures, training, evaluation, runs and checkpoints, online stepping."""

from .checkpoint import CheckpointError, CheckpointMeta, DataSource, load_checkpoint
from .ensemble import MILEnsemble, as_ensemble
from .evaluation import evaluate
from .models import (ARCHITECTURE_NAMES, ARCHITECTURES, MILOutput, MILRewardModel, ModelConfig,
                     build_model, model_config)
from .online import OnlineRewardModel
from .pipeline import fit
from .run import Run
from .training import TrainConfig, TrainResult, load_train_config, train_model

__all__ = ["ARCHITECTURES", "ARCHITECTURE_NAMES", "CheckpointError", "CheckpointMeta", "DataSource", "Run", "MILEnsemble", "MILOutput", "MILRewardModel",
           "ModelConfig", "OnlineRewardModel", "TrainConfig", "TrainResult", "build_model",
           "as_ensemble", "evaluate", "fit", "load_checkpoint", "load_train_config", "model_config",
           "train_model"]
