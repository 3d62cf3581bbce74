"""Which episode to ask a person about next (no ROS).

With an ensemble checkpoint, an episode's score is the spread (standard deviation) of the members'
predicted returns for it: where models trained on bootstrap resamples of the labels disagree, a
label tells the most (query by committee, as in Christiano et al. 2017 and BPref's disagreement
sampling). The queue is then ordered by that spread, largest first. A single model has no spread:
the queue stays oldest first (and `ordering` says so).

Pairs to compare are chosen the same way (imitation's active selection): a pair's score is the
spread over the members of their P(a better than b) = sigmoid((R_a - R_b) / return_scale)
(`pair_disagreement`), largest first.
"""

from __future__ import annotations

import threading

import numpy as np
import torch

OLDEST_FIRST = "oldest first"
DISAGREEMENT = "largest disagreement first (std of the ensemble members' predicted returns)"
PAIR_DISAGREEMENT = "largest disagreement first (std of the ensemble members' P(a better than b))"


def pair_disagreement(returns_a: np.ndarray, returns_b: np.ndarray, scale: float = 1.0) -> float:
    """The std over members of P(a better) = sigmoid((R_a - R_b) / scale); returns_*: (K,)."""
    p = 1.0 / (1.0 + np.exp(-np.clip((np.asarray(returns_a) - np.asarray(returns_b)) / scale, -50, 50)))
    return float(np.std(p))


class DisagreementScorer:
    """`score(states (L, d) instances) -> (spread, mean, members' returns (K,))` of the members'
    predicted returns."""

    def __init__(self, checkpoint: str, task: str) -> None:
        from ..mil import load_checkpoint

        model, _ = load_checkpoint(checkpoint, task=task)  # CheckpointError says why it is refused
        self.model = model.eval()
        self.source = str(checkpoint)
        self.members = model.members
        self.return_scale = float(model.return_scale)
        self.lock = threading.Lock()

    @property
    def ordering(self) -> str:
        return DISAGREEMENT if self.members > 1 else OLDEST_FIRST

    @torch.no_grad()
    def score(self, states: np.ndarray) -> tuple:
        x = torch.as_tensor(np.asarray(states, np.float32))[None]
        with self.lock:
            returns = self.model(x, torch.tensor([x.shape[1]])).returns.reshape(-1)
        members = returns.double().numpy()
        if self.members == 1:
            return 0.0, float(returns[0]), members
        return float(returns.std(unbiased=False)), float(returns.mean()), members
