"""Hidden-state embeddings (paper Fig. 5): a model's served states [h'_{t+1}, tanh c'_{t+1}] over many trajectories,
as 2D points, beside the oracle's hidden variable and the time step at each point.

For a hidden size above 2 the points are the first two principal components (NumPy SVD of the
centred states); `Embedding.projection` says which.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .traces import model_traces, oracle_traces

#: What the oracle's hidden variable h[..., 0] is, per task (the colour of the first panel).
ORACLE_VARIABLE = {
    "timer": "time index t + 1 (treasure pays after 50)",
    "moving": "treasure's left edge",
    "key": "key held (1) or not (0)",
    "charger": "charge",
    "lunar_lander": "steps on the pad",
}


@dataclass
class Embedding:
    """points (P, 2); oracle (P,) the oracle's hidden variable; time (P,) step t; projection:
    "hidden state" (k <= 2, k = 1 padded with zeros) or "PCA of the k-D hidden state"; explained
    (2,) variance fractions of the two components (PCA only)."""

    points: np.ndarray
    oracle: np.ndarray
    time: np.ndarray
    projection: str
    explained: np.ndarray | None = None


def project(hidden: np.ndarray) -> tuple[np.ndarray, str, np.ndarray | None]:
    """(P, k) -> ((P, 2), description, explained variance fractions or None)."""
    k = hidden.shape[1]
    if k == 0:
        raise ValueError("the model has no hidden state (Instance Space NN)")
    if k <= 2:
        return np.pad(hidden, ((0, 0), (0, 2 - k))), "hidden state", None
    centred = hidden - hidden.mean(0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    var = s ** 2 / max(float((s ** 2).sum()), 1e-30)
    return centred @ vt[:2].T, f"PCA of the {k}-D hidden state", var[:2]


def hidden_embedding(model, task: str, states: np.ndarray, lengths: np.ndarray, inputs=None) -> Embedding:
    """Embedding of the hidden states of trajectories states (N, T, d) of `task` with `lengths`
    (N,); inputs: what the model reads of the states (`model_traces`; None: the states)."""
    _, hidden = model_traces(model, states, lengths, inputs)
    _, oracle_hidden = oracle_traces(task, states)
    real = np.arange(states.shape[1])[None, :] < np.asarray(lengths)[:, None]
    points, how, explained = project(hidden[real])
    time = np.broadcast_to(np.arange(states.shape[1])[None, :], real.shape)[real]
    return Embedding(points, oracle_hidden[real][:, 0], time.astype(float), how, explained)
