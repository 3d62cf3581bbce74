"""What a reward model serves to the agent as its hidden state: the LSTM's memory.

The paper augments the agent's state with the LSTM's output h'_{t+1} (Sec. 3.3, Fig. 2:
`[s_t, h'_{t+1}]`). An LSTM's memory is its *pair* (h'_{t+1}, c'_{t+1}): h' = o * tanh(c') is
what the output gate lets through, and a model may keep what it needs in c' while o hides it
until the reward needs it. Measured on a Charger CSC model (issue 34): while the agent charges,
h' stays flat (h'[0] ~ -0.71, h'[1] ~ 0.00 for 40 steps) and c'[1] counts the charge; an agent
observing h' alone cannot know when it is charged. So by default (`"h_tanh_c"`) we serve the
full recurrent state, 2k values, with the cell state squashed as the output gate reads it:

    served_{t+1} = [h'_{t+1}, tanh(c'_{t+1})]        (k = the LSTM's hidden size)

tanh is one-to-one, so [h', tanh c'] carries what [h', c'] does, and the augmented state
[s_t, served_{t+1}] determines every future reward the model pays: the agent's problem is
Markovian. It keeps every input of the agent's network in [-1, 1]; c' itself is unbounded (on a
Key model one unit reaches 37 while the others stay within +-2), and agents observing raw c'
learnt worse greedy policies (bench/results/served_state_agents_*.txt). `"h_c"` serves the raw
[h', c']; `"h"` h'_{t+1} only (the paper's choice; for comparisons and for agents trained
before this change). The Instance Space NN has no recurrent state: it serves nothing (size 0). The
transformer (`architectures.CausalTransformer`) serves its attention output z_t whatever the kind.

`served_states(model, states)` computes the served states of whole trajectories from the batched
forward (h' from the model, c' by the LSTM's cell recursion on those h'); the online stepper
(`OnlineRewardModel`) computes the same step by step; tests check they agree.
"""

from __future__ import annotations

import numpy as np
import torch

SERVED_STATES = ("h_tanh_c", "h_c", "h")
DEFAULT_SERVED_STATE = "h_tanh_c"


def check_served_state(kind: str) -> str:
    """`kind` if it is one of SERVED_STATES, else a ValueError naming the choices."""
    if kind not in SERVED_STATES:
        raise ValueError(f"unknown served state {kind!r}; use one of {', '.join(SERVED_STATES)} "
                         f"(h_tanh_c: the LSTM's [h', tanh(c')], h_c: [h', c'], h: h' only, as the paper)")
    return kind


def served_size(hidden_size: int, kind: str = DEFAULT_SERVED_STATE, attention: bool = False) -> int:
    """Size of the served state of a model with LSTM hidden size `hidden_size` (0: no LSTM); a
    transformer (`attention`) serves its attention output z_t, `hidden_size` values, whatever the kind."""
    if attention:
        check_served_state(kind)
        return hidden_size
    return hidden_size if check_served_state(kind) == "h" else 2 * hidden_size


@torch.no_grad()
def served_states(model, states: np.ndarray, lengths: np.ndarray | None = None,
                  kind: str = DEFAULT_SERVED_STATE) -> np.ndarray:
    """Served states (N, T, served_size) of trajectories `states` (N, T, d) float or uint8 pixels (zero beyond
    each length). `model`: a `MILEnsemble` (its serving member's state) or a `MILRewardModel`."""
    from .architectures import lstm_cell
    from .ensemble import MILEnsemble, as_ensemble

    check_served_state(kind)
    ens = as_ensemble(model)
    with torch.random.fork_rng(devices=[]):  # building the one-member view draws fresh weights: not from the caller's stream
        serving = MILEnsemble.from_members([ens.member(int(ens.serving_member))]).eval()
    states = np.asarray(states)
    x = torch.as_tensor(states if states.dtype == np.uint8 else states.astype(np.float32))  # pixels stay uint8
    n, t = x.shape[:2]
    lens = torch.full((n,), t) if lengths is None else torch.as_tensor(np.asarray(lengths))
    if not (serving.uses_lstm or serving.uses_attention):
        return np.zeros((n, t, 0))
    h = serving(x, lens).hidden[0].double().numpy()  # (N, T, k) h'_{t+1}, zero beyond each length
    if kind == "h" or serving.uses_attention:  # a transformer serves its attention output z_t
        return h
    lstm = {name: v.double().numpy() for name, v in serving.layers(0)["lstm"].items()}
    f = serving._features(x[None].reshape(1, n * t, -1))[0].double().numpy().reshape(n, t, -1)
    previous = np.concatenate([np.broadcast_to(lstm["h0"], (n, 1, h.shape[-1])), h[:, :-1]], axis=1)  # h'_t
    gates = (f @ lstm["weight_ih"].T + lstm["bias_ih"] + previous @ lstm["weight_hh"].T + lstm["bias_hh"])
    c = np.zeros_like(h)
    cell = np.broadcast_to(lstm["c0"], h[:, 0].shape)
    for step in range(t):  # the cell's recursion on the forward's h' (the online stepper's cell)
        _, cell = lstm_cell(gates[:, step], cell)
        c[:, step] = cell
    mask = (np.arange(t)[None, :] < lens.numpy()[:, None])[..., None]
    if kind == "h_tanh_c":
        c = np.tanh(c)
    return np.concatenate([h, c * mask], axis=-1)
