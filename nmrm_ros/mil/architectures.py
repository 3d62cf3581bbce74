"""What each MIL architecture does with its features and its LSTM's states: the one definition
of every architecture's forward (paper Sec. 3.2, App. C.2, D.3, D.4), in a registry.

Every model is: inputs -> feature extractor (FC + ReLU layers: `fe_sizes`) -> per-instance
features f_t (F) -> [a temporal module: hidden states h'_{t+1} (k)] -> head (FC layers to 1) ->
per-step outputs y_t -> rewards and the bag's return. An `Architecture` says the parts in between:

- `uses_lstm` / `uses_attention`: the temporal module, an LSTM or causal self-attention
  (`CausalAttention` in models.py: h'_{t+1} is then its output z_t); neither: k = 0;
- `head_input(f, h)`: what the head sees at step t (f_t, h'_{t+1} or [f_t, h'_{t+1}]);
- `outputs(y, mask, lengths)`: the batched rule from the head's outputs y (..., T) to
  (returns (...), rewards (..., T)) — used by training, evaluation and the served state;
- `step_rewards(y, carry)`: the same rule one step at a time (the online stepper's
  specialisation; tests/test_architectures.py checks the two agree).

The machinery that is the same for every architecture (normalisation, FC layers, the LSTM, the
output activation, K members at once) lives in `MILEnsemble` (batched, torch) and
`OnlineRewardModel` (one step, NumPy); both call the registry and branch on nothing else.

Adding an architecture: a subclass here and an entry in `REGISTRY` (the key is the name a
checkpoint records and `--arch` takes).

    arch = REGISTRY["csc_lstm"]
    y = head(arch.head_input(f, h))           # f (..., F), h (..., k) -> (..., F + k)
    returns, rewards = arch.outputs(y, mask, lengths)
"""

from __future__ import annotations

import numpy as np
import torch


def _cat(a, b):
    """[a, b] along the last axis, for torch tensors or NumPy arrays alike."""
    if isinstance(a, torch.Tensor):
        return torch.cat([a, b], dim=-1)
    return np.concatenate([a, b], axis=-1)


class Architecture:
    """The Instance Space NN's rule (mi-Net, the Markovian baseline): r_t = HN(FE(x_t)); the
    return is the sum of the rewards. Subclasses change what the head sees or what its output is."""

    name = "instance_nn"
    title = "Instance Space NN"
    uses_lstm = False
    uses_attention = False
    #: the smallest temporal width k the architecture is built with (a config's hidden_size below
    #: it is raised to it)
    min_hidden_size = 1
    #: r_t is the head's output y_t (so an affine map of the head's last layer maps the rewards:
    #: `mil.calibration`); False where rewards are differences of the head's outputs
    reward_is_head_output = True

    def head_input_size(self, feature_size: int, hidden_size: int) -> int:
        return feature_size

    def head_input(self, features, hidden):
        """The head's input (..., head_input_size) from features (..., F) and LSTM states
        h'_{t+1} (..., k) (None without an LSTM); torch or NumPy."""
        return features

    def outputs(self, y: torch.Tensor, mask: torch.Tensor, lengths: torch.Tensor) -> tuple:
        """(returns (...), rewards (..., T)) from the head's outputs y (..., T) of padded bags;
        mask (..., T) 1 within each bag's length, lengths (...) int64."""
        rewards = y * mask
        return rewards.sum(-1), rewards

    def step_rewards(self, y: np.ndarray, carry: np.ndarray) -> tuple:
        """One step of `outputs`: (r_t, the carry for the next step) from the head's output y_t
        and the carry (zeros at a bag's start). Shapes () or (K,)."""
        return y, carry


class InstanceSpaceLSTM(Architecture):
    """r_t = HN(h'_{t+1})."""

    name = "instance_lstm"
    title = "Instance Space LSTM"
    uses_lstm = True

    def head_input_size(self, feature_size: int, hidden_size: int) -> int:
        return hidden_size

    def head_input(self, features, hidden):
        return hidden


class CSCInstanceSpaceLSTM(InstanceSpaceLSTM):
    """r_t = HN([FE(x_t), h'_{t+1}]) (a concatenated skip connection)."""

    name = "csc_lstm"
    title = "CSC Instance Space LSTM"

    def head_input_size(self, feature_size: int, hidden_size: int) -> int:
        return feature_size + hidden_size

    def head_input(self, features, hidden):
        return _cat(features, hidden)


class EmbeddingSpaceLSTM(InstanceSpaceLSTM):
    """g_t = HN(h'_{t+1}) is the partial return after t + 1 instances; the return is g at the
    last instance; rewards are r_t = g_t - g_{t-1} with g_{-1} = 0 (the paper's post-hoc
    g'_0 = 0 rule, in 0-based steps). The carry of `step_rewards` is g_{t-1}."""

    name = "embedding_lstm"
    title = "Embedding Space LSTM"
    reward_is_head_output = False

    def outputs(self, y, mask, lengths):
        previous = torch.cat([y.new_zeros(*y.shape[:-1], 1), y[..., :-1]], dim=-1)
        rewards = (y - previous) * mask
        last = (lengths - 1).clamp(min=0)
        returns = y.gather(-1, last[..., None]).squeeze(-1) * (lengths > 0).to(y.dtype)
        return returns, rewards

    def step_rewards(self, y, carry):
        return y - carry, y


class CausalTransformer(Architecture):
    """r_t = HN([FE(x_t), z_t]), z_t the output of one causal self-attention layer over the
    features f_0..f_t (the Preference Transformer's idea, Kim et al. 2023, in the CSC form; not
    in the paper): x_t = W_in f_t + b_in + P(t), a_t = sum_{j <= t} softmax_j(q_t . k_j / sqrt(k)) v_j
    with q, k, v = W_q x, W_k x, W_v x, and z_t = tanh(x_t + W_o a_t + b_o). P(t) is a sinusoidal
    code of the step (`time_code`). The served state is z_t (k values in [-1, 1]); online, the
    keys and values of the episode so far are kept (a cache: O(t k) per step). k is at least 8,
    so that the time code resolves ~1000 steps."""

    name = "transformer"
    title = "Causal Transformer (CSC)"
    uses_attention = True
    min_hidden_size = 8

    def head_input_size(self, feature_size: int, hidden_size: int) -> int:
        return feature_size + hidden_size

    def head_input(self, features, hidden):
        return _cat(features, hidden)


#: name -> architecture, in the paper's order (the Markovian baseline first), then ours
REGISTRY: dict = {a.name: a for a in (Architecture(), EmbeddingSpaceLSTM(), InstanceSpaceLSTM(),
                                       CSCInstanceSpaceLSTM(), CausalTransformer())}


def time_code(steps: int, width: int) -> np.ndarray:
    """The sinusoidal code P(t) of steps t = 0..steps-1, (steps, width) float64: P[t, 2i] =
    sin(t / 10000^(2i / width)), P[t, 2i + 1] = cos(the same) (Vaswani et al. 2017)."""
    t = np.arange(steps, dtype=np.float64)[:, None]
    i = np.arange(width)[None, :]
    angle = t / np.power(10000.0, (i - i % 2) / width)
    return np.where(i % 2 == 0, np.sin(angle), np.cos(angle))


def attention_step(x: np.ndarray, keys: np.ndarray, values: np.ndarray) -> np.ndarray:
    """a_t of one query per member: x (..., k) queries, keys / values (..., t + 1, k) of the steps
    so far -> (..., k), softmax over the steps (NumPy; the online stepper's)."""
    scores = np.einsum("...d,...td->...t", x, keys) / np.sqrt(x.shape[-1])
    scores = np.exp(scores - scores.max(axis=-1, keepdims=True))
    return np.einsum("...t,...td->...d", scores / scores.sum(axis=-1, keepdims=True), values)


def architecture(name: str) -> Architecture:
    """The registered architecture `name`, or a ValueError naming the known ones."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown architecture {name!r}; known: {', '.join(REGISTRY)}") from None


def lstm_cell(gates: np.ndarray, c: np.ndarray) -> tuple:
    """One LSTM step in NumPy from the pre-activations gates = W_ih f_t + W_hh h_t + b
    (..., 4k, torch's order [i | f | g | o]) and the cell state c (..., k): (h_{t+1}, c_{t+1}).
    The online stepper and the served state's cell recursion both use it."""
    k = c.shape[-1]
    i = 1.0 / (1.0 + np.exp(-gates[..., :k]))
    forget = 1.0 / (1.0 + np.exp(-gates[..., k:2 * k]))
    g = np.tanh(gates[..., 2 * k:3 * k])
    o = 1.0 / (1.0 + np.exp(-gates[..., 3 * k:]))
    c = forget * c + i * g
    return o * np.tanh(c), c
