"""Online (one step at a time) inference of a trained MIL reward model, in NumPy.

The reward-model node calls `step` once per observation, so this path is written for latency:
the weights are copied out of the torch model once, and each step is a handful of small
matrix-vector products (no autograd, no torch dispatch). It computes the same rewards and hidden
states as the batched `model(x, lengths)` forward on the same trajectory (float64 here, float32
there; tests/test_mil_models.py checks agreement to 1e-5).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from .models import MILRewardModel


def _linear_layers(seq: nn.Sequential) -> list:
    return [(m.weight.detach().double().numpy().copy(), m.bias.detach().double().numpy().copy())
            for m in seq if isinstance(m, nn.Linear)]


class OnlineRewardModel:
    """`reset()` at each episode start, then `step(s_t) -> (r'_t, h'_{t+1})`.

    `hidden` is the current h'_t (k,) (k = 0 for the Instance Space NN).
    """

    def __init__(self, model: MILRewardModel) -> None:
        model = model.eval()
        cfg = model.config
        self.architecture = cfg.architecture
        self.input_size = cfg.input_size
        self.shift = model.input_shift.double().numpy().copy()
        self.scale = model.input_scale.double().numpy().copy()
        self.return_scale = float(model.return_scale)
        self.leaky = cfg.output_activation == "leaky_relu"
        self.fe = _linear_layers(model.feature_extractor)
        self.head = _linear_layers(model.head)
        self.uses_lstm = model.uses_lstm
        self.k = model.hidden_size
        if self.uses_lstm:
            lstm = model.lstm
            self.w_ih = lstm.weight_ih_l0.detach().double().numpy().copy()
            self.w_hh = lstm.weight_hh_l0.detach().double().numpy().copy()
            self.bias = (lstm.bias_ih_l0 + lstm.bias_hh_l0).detach().double().numpy().copy()
            self.h0 = model.h0.detach().double().numpy().copy()
            self.c0 = model.c0.detach().double().numpy().copy()
        self.reset()

    def reset(self) -> None:
        """Start a new trajectory: h' = h'_0, c' = c'_0, g_{-1} = 0."""
        if self.uses_lstm:
            self.hidden = self.h0.copy()
            self.cell = self.c0.copy()
        else:
            self.hidden = np.zeros(0)
        self.previous_partial = 0.0
        self.t = 0

    def _mlp(self, layers: list, z: np.ndarray) -> np.ndarray:
        last = len(layers) - 1
        for i, (w, b) in enumerate(layers):
            z = w @ z + b
            if i < last:
                z = np.maximum(z, 0.0)
        return z

    def _fe(self, x: np.ndarray) -> np.ndarray:
        z = (x - self.shift) / self.scale
        for w, b in self.fe:
            z = np.maximum(w @ z + b, 0.0)
        return z

    def _out(self, z: np.ndarray) -> float:
        y = float(self._mlp(self.head, z)[0])
        if self.leaky and y < 0:
            y *= 1e-6
        return y * self.return_scale

    def step(self, state: np.ndarray) -> tuple[float, np.ndarray]:
        """Consume instance s_t (d,); return (r'_t, h'_{t+1} (k,))."""
        x = np.asarray(state, dtype=np.float64).reshape(-1)
        if x.shape[0] != self.input_size:
            raise ValueError(f"expected a state of size {self.input_size}, got {x.shape[0]}")
        if not np.all(np.isfinite(x)):
            raise ValueError("state contains NaN or inf")
        f = self._fe(x)
        self.t += 1
        if not self.uses_lstm:
            return self._out(f), self.hidden
        gates = self.w_ih @ f + self.w_hh @ self.hidden + self.bias
        k = self.k
        i = 1.0 / (1.0 + np.exp(-gates[:k]))
        fg = 1.0 / (1.0 + np.exp(-gates[k:2 * k]))
        g = np.tanh(gates[2 * k:3 * k])
        o = 1.0 / (1.0 + np.exp(-gates[3 * k:]))
        self.cell = fg * self.cell + i * g
        self.hidden = o * np.tanh(self.cell)
        if self.architecture == "embedding_lstm":
            partial = self._out(self.hidden)
            reward = partial - self.previous_partial
            self.previous_partial = partial
        elif self.architecture == "csc_lstm":
            reward = self._out(np.concatenate([f, self.hidden]))
        else:
            reward = self._out(self.hidden)
        return reward, self.hidden.copy()


def batched_reference(model: MILRewardModel, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rewards (L,) and hidden states (L, k) of one trajectory (L, d) from the batched forward."""
    with torch.no_grad():
        x = torch.as_tensor(np.asarray(states, np.float32))[None]
        out = model.eval()(x, torch.tensor([x.shape[1]]))
    return out.rewards[0].double().numpy(), out.hidden[0].double().numpy()
