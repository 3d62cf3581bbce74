"""Online (one step at a time) inference of a trained MIL reward model or ensemble, in NumPy.

The reward-model node calls `step` once per observation, so this path is written for latency:
the weights are copied out of the torch model once, and each step is a handful of small
matrix-vector products (no autograd, no torch dispatch). It computes the same rewards and hidden
states as the batched `model(x, lengths)` forward on the same trajectory (float64 here, float32
there; tests/test_mil_models.py checks agreement to 1e-5).

A single model is an ensemble of one (`as_ensemble`). For a K-member `MILEnsemble`, every step runs all members
(weights stacked on a leading member axis): the reward served is the members' mean, `reward_std`
their spread, `return_std` the spread of their returns so far, and the hidden state is the
serving member's (the best on validation), so that an agent sees one consistent state.
"""

from __future__ import annotations

import numpy as np
import torch

from .architectures import lstm_cell
from .ensemble import MILEnsemble, as_ensemble
from .image_encoder import encode_numpy, pixel_weights
from .models import MILRewardModel
from .served_state import DEFAULT_SERVED_STATE, check_served_state, served_size, served_states


def _arrays(tensor: torch.Tensor) -> np.ndarray:
    """A float64 NumPy copy."""
    return tensor.detach().double().numpy().copy()


class OnlineRewardModel:
    """`reset()` at each episode start, then `step(s_t) -> (r'_t, served_{t+1})`.

    `hidden` is the current served state (`served_size`,) of the serving member: [h'_t, tanh c'_t]
    (2k values) with served="h_tanh_c" (default), [h'_t, c'_t] with "h_c", h'_t (k) with "h";
    size 0 for the Instance
    Space NN. `states_h`, `states_c` are every member's h', c' ((K, k), or (k,) for one);
    after a step, `rewards` (K,) are the members' r'_t, `reward_std` their standard deviation and
    `return_std` the standard deviation of the members' returns so far (0 for one model).
    """

    def __init__(self, model: MILRewardModel | MILEnsemble, served: str = DEFAULT_SERVED_STATE) -> None:
        self.served = check_served_state(served)
        #: the checkpoint's CheckpointMeta (`from_checkpoint`); None for a stepper built from a model
        self.meta = None
        ens = as_ensemble(model).eval()
        cfg = ens.config
        self.members = ens.members
        self.serving = int(ens.serving_member)
        self.architecture = cfg.architecture
        self.rule = ens.rule  # architectures.REGISTRY: what the head sees, its outputs' rule
        self.input_size = cfg.input_size
        # one member: arrays without the member axis, plain matrix-vector products (a stacked
        # matmul costs twice as much per call, and this runs once per observation)
        single = self.members == 1
        layers = ens.layers(0 if single else None)
        self.shift = _arrays(ens.input_shift[0] if single else ens.input_shift)  # (K, d) or (d,)
        self.scale = _arrays(ens.input_scale[0] if single else ens.input_scale)
        self.return_scale = float(ens.return_scale)
        self.activation = cfg.output_activation
        self.fe = [(_arrays(w), _arrays(b)) for w, b in layers["feature_extractor"]]
        self.image = (cfg.image_shape, cfg.patch) if cfg.image_shape else None
        if self.image:
            self.image_values = cfg.image_values
            self.encoder = pixel_weights(*(_arrays(t) for t in layers["encoder"]))  # W (K, c, ppC) or (c, ppC), b
        self.head = [(_arrays(w), _arrays(b)) for w, b in layers["head"]]
        self.uses_lstm = ens.uses_lstm
        self.uses_attention = ens.uses_attention
        self.k = ens.hidden_size  # the LSTM's hidden size or the attention's width (0: neither)
        self.served_size = served_size(self.k, served, attention=self.uses_attention)
        if self.uses_attention:
            from .architectures import time_code

            a = {n: _arrays(v) for n, v in layers["attention"].items()}
            self.att = a  # inp (K, k, F), query / key / value / out (K, k, k), inp_bias / out_bias (K, k)
            self._time_code = time_code(1024, self.k)  # P(t), extended when an episode is longer
        if self.uses_lstm:
            p = {n: _arrays(v) for n, v in layers["lstm"].items()}
            self.w_ih = p["weight_ih"]  # (K, 4k, F)
            self.w_hh = p["weight_hh"]  # (K, 4k, k)
            self.bias = p["bias_ih"] + p["bias_hh"]  # (K, 4k)
            self.h0, self.c0 = p["h0"], p["c0"]  # (K, k)
        self.reset()

    @classmethod
    def from_checkpoint(cls, path, task: str | None = None, served: str | None = None,
                        state_size: int | None = None) -> "OnlineRewardModel":
        """The served model of a checkpoint: the one way the nodes, the agents' wrappers and
        relabelling get one. task: refuse a checkpoint of another task (None: any; the stepper's
        `task` is the checkpoint's); served: what it serves (None: the checkpoint's own training
        config's `served_state`); state_size: refuse a model of other states. `meta` holds the
        checkpoint's metadata. CheckpointError or ValueError (one line) for anything amiss."""
        from .checkpoint import load_checkpoint

        model, meta = load_checkpoint(path, task=task)
        try:
            stepper = cls(model, served=served or meta.served_state)
        except ValueError as exc:
            raise ValueError(f"checkpoint {path}: {exc}") from None
        if state_size is not None and stepper.input_size != state_size:
            raise ValueError(f"checkpoint {path} takes states of size {stepper.input_size}, task "
                             f"{meta.task} has {state_size}")
        stepper.meta = meta
        return stepper

    @property
    def task(self) -> str | None:
        """The task of the checkpoint it was loaded from (None: built from a model)."""
        return None if self.meta is None else self.meta.task

    def reset(self) -> None:
        """Start a new trajectory: h' = h'_0, c' = c'_0, g_{-1} = 0, returns so far 0."""
        K = self.members
        if self.uses_lstm:
            self.states_h = self.h0.copy()
            self.states_c = self.c0.copy()
            self._serve()
        elif self.uses_attention:
            shape = (0, self.k) if K == 1 else (K, 0, self.k)
            self.keys, self.values = np.zeros(shape), np.zeros(shape)  # the episode's so far
            self.hidden = np.zeros(self.k)  # no step yet: z of nothing
        else:
            self.hidden = np.zeros(0)
        shape = () if K == 1 else (K,)
        self.previous_partial = np.zeros(shape)
        self.partial_returns = np.zeros(shape)
        self.rewards = np.zeros(shape)
        self.reward_std = 0.0
        self.return_std = 0.0
        self.t = 0

    def _serve(self) -> None:
        """Set `hidden` from the serving member's recurrent state."""
        h = self.states_h if self.members == 1 else self.states_h[self.serving]
        if self.served == "h":
            self.hidden = h
            return
        c = self.states_c if self.members == 1 else self.states_c[self.serving]
        self.hidden = np.concatenate([h, np.tanh(c) if self.served == "h_tanh_c" else c])

    @staticmethod
    def _apply(w: np.ndarray, b: np.ndarray | None, z: np.ndarray) -> np.ndarray:
        """Each member's layer on its own input: (K, out, in) x (K, in) -> (K, out)."""
        y = w @ z if w.ndim == 2 else np.matmul(w, z[..., None])[..., 0]
        return y if b is None else y + b

    def _fe(self, x: np.ndarray) -> np.ndarray:
        if self.image:
            v = self.image_values
            z = encode_numpy(x, *self.encoder, (x[v:] - self.shift[..., v:]) / self.scale[..., v:], *self.image)
        else:
            z = (x - self.shift) / self.scale
        for w, b in self.fe:
            z = np.maximum(self._apply(w, b, z), 0.0)
        return z

    def _out(self, z: np.ndarray) -> np.ndarray:
        last = len(self.head) - 1
        for i, (w, b) in enumerate(self.head):
            z = self._apply(w, b, z)
            if i < last:
                z = np.maximum(z, 0.0)
        y = z[..., 0]
        if self.activation == "leaky_relu":
            y = np.where(y < 0, y * 1e-6, y)
        elif self.activation == "softplus":
            y = np.logaddexp(0.0, y)
        return y * self.return_scale

    def step(self, state: np.ndarray) -> tuple[float, np.ndarray]:
        """Consume instance s_t (d,); return (r'_t (members' mean), the served state after it
        (`served_size`,) of the serving member)."""
        x = np.asarray(state, dtype=np.float64).reshape(-1)
        if x.shape[0] != self.input_size:
            raise ValueError(f"expected a state of size {self.input_size}, got {x.shape[0]}")
        if not np.all(np.isfinite(x)):
            raise ValueError("state contains NaN or inf")
        f = self._fe(x)  # (K, F)
        hidden = None
        if self.uses_attention:
            hidden = self._attend(f)
        self.t += 1
        if self.uses_lstm:
            gates = self._apply(self.w_ih, self.bias, f) + self._apply(self.w_hh, None, self.states_h)
            self.states_h, self.states_c = lstm_cell(gates, self.states_c)
            self._serve()
            hidden = self.states_h
        rewards, self.previous_partial = self.rule.step_rewards(
            self._out(self.rule.head_input(f, hidden)), self.previous_partial)
        self.rewards = rewards
        self.partial_returns += rewards
        if self.members == 1:  # no spread to compute (np.std is ~5 µs a call)
            return float(rewards), self.hidden.copy()
        self.reward_std = float(rewards.std())
        self.return_std = float(self.partial_returns.std())
        return float(rewards.mean()), self.hidden.copy()

    def _attend(self, f: np.ndarray) -> np.ndarray:
        """One step of each member's causal attention (`models.CausalAttention`): z_t (K, k) from
        f_t (K, F), the step's key and value appended to the episode's; sets `hidden`."""
        from .architectures import attention_step, time_code

        a = self.att
        if self.t >= len(self._time_code):
            self._time_code = time_code(2 * self.t, self.k)
        x = self._apply(a["inp"], a["inp_bias"], f) + self._time_code[self.t]
        axis = -2
        self.keys = np.concatenate([self.keys, self._apply(a["key"], None, x)[..., None, :]], axis=axis)
        self.values = np.concatenate([self.values, self._apply(a["value"], None, x)[..., None, :]], axis=axis)
        z = np.tanh(x + self._apply(a["out"], a["out_bias"], attention_step(self._apply(a["query"], None, x),
                                                                           self.keys, self.values)))
        self.hidden = z if self.members == 1 else z[self.serving]
        return z

    def episode_rewards(self, states: np.ndarray) -> np.ndarray:
        """r'_t (the members' mean) of a whole episode of states (L, d), stepped as served from a
        fresh start (`reset`, then `step` each), (L,) float64."""
        self.reset()
        return np.array([self.step(s)[0] for s in states], dtype=np.float64)


def batched_reference(model: MILRewardModel | MILEnsemble, states: np.ndarray,
                      served: str = DEFAULT_SERVED_STATE) -> tuple[np.ndarray, np.ndarray]:
    """Rewards (L,) (the members' mean) and served states (L, served_size) (the serving member's)
    of one trajectory (L, d) from the batched forward (`served_states`)."""
    model = as_ensemble(model).eval()
    with torch.no_grad():
        x = torch.as_tensor(np.asarray(states, np.float32))[None]
        out = model(x, torch.tensor([x.shape[1]]))
    return out.rewards.mean(0)[0].double().numpy(), served_states(model, x.numpy(), kind=served)[0]
