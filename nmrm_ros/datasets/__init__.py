"""Datasets of labelled trajectories: toy MIL bags and screened task trajectories."""

from .label_noise import OnlineLabelSwapper, swap_labels, swap_sources
from .prefixes import cut_episodes
from .screening import classify, generate_screened, screen_navigation, screen_pool, screening_spec
from .toy import TOY_DATASETS, make_toy_dataset
from .trajectories import TrajectoryDataset

__all__ = ["OnlineLabelSwapper", "TrajectoryDataset", "TOY_DATASETS", "make_toy_dataset", "classify", "cut_episodes", "generate_screened",
           "screen_navigation", "screen_pool", "screening_spec", "swap_labels", "swap_sources"]
