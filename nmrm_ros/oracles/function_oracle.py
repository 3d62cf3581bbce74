"""A user's oracle: a function of a whole trajectory, named `<module>:<attribute>` or
`<path/to/file.py>:<attribute>`.

    def oracle(states, actions):          # states (T, S) float64, actions (T, A) float64
        ...
        return rewards                    # (T,): r_t for t < T
        # or: return rewards, hidden      # hidden (T, k): h_{t+1}, for OracleStep, the
        #                                 # oracle-with-hidden baseline and the plots

`states[t]` is the flattened observation s_t (`nmrm_ros.tasks.gym_task`), `actions[t]` the action
a_t taken in it (a Discrete action is one column holding its index). `actions` is None where they
are not known: the graph's labeller_oracle and reward_model (mode oracle) follow observations only,
so an oracle that needs the actions labels datasets and judges agents, but not in the graph. The function sees the whole
trajectory, so it may judge anything about the past (a non-Markovian reward by construction), but
r_t may depend only on steps up to t: online labelling and serving call it on the trajectory so far
and use its last reward, and the first trajectory labelled is checked for that. The return label
is the sum of the rewards.

A spec that names nothing callable, and a call that raises, returns the wrong shape or a NaN, is
an `OracleError` (one line naming the oracle), never a traceback or a silently wrong label.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from typing import Callable

import numpy as np

from .base import Oracle, OracleLabels, OracleTracker


class OracleError(ValueError):
    """An oracle spec that names nothing usable, or an oracle that misbehaved (one line)."""


def is_oracle_spec(text: str) -> bool:
    """Whether `text` names a user's oracle function (`module:attribute`, `file.py:attribute`)."""
    return ":" in text


def load_oracle_function(spec: str) -> Callable:
    """The callable named by `module:attribute` or `path/to/file.py:attribute` (a dotted
    attribute path is followed)."""
    module_name, _, attribute = spec.strip().rpartition(":")
    if not module_name or not attribute:
        raise OracleError(f"oracle {spec!r}: give it as <module>:<function> or <file.py>:<function>, "
                          f"e.g. my_pkg.oracles:crossings")
    try:
        target = _import(module_name)
    except OracleError as exc:
        raise OracleError(f"oracle {spec!r}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - the user's module failed while importing
        raise OracleError(f"oracle {spec!r}: importing {module_name!r} raised "
                          f"{type(exc).__name__}: {exc}") from None
    for part in attribute.split("."):
        if not hasattr(target, part):
            raise OracleError(f"oracle {spec!r}: {module_name!r} has no attribute {attribute!r}")
        target = getattr(target, part)
    if not callable(target):
        raise OracleError(f"oracle {spec!r}: {attribute!r} is a {type(target).__name__}, not a function")
    return target


def _import(name: str):
    """A module by import name, or by the path of a .py file (imported once per path)."""
    if not name.endswith(".py"):
        try:
            return importlib.import_module(name)
        except ImportError as exc:
            raise OracleError(f"cannot import {name!r}: {exc}") from None
    path = Path(name).expanduser().resolve()
    if not path.is_file():
        raise OracleError(f"no file {name}")
    key = f"nmrm_user_oracle_{abs(hash(str(path)))}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[key]
            raise
    return sys.modules[key]


class FunctionOracle(Oracle):
    """The `Oracle` of a trajectory function (see module docstring) on a task.

    state_size S and action width A come from the task; the hidden size k from a first call on a
    two-step trajectory of zeros (0 when the function returns rewards only)."""

    def __init__(self, spec: str, task: str, state_size: int, action_width: int,
                 function: Callable | None = None) -> None:
        self.spec, self.task = spec, task
        self.state_size, self.action_width = int(state_size), int(action_width)
        self.function = load_oracle_function(spec) if function is None else function
        self.hidden_size = 0
        self.causal_checked = False
        _, hidden = self.call(np.zeros((2, self.state_size)), np.zeros((2, self.action_width)))
        self.returns_hidden = hidden is not None
        self.hidden_size = 0 if hidden is None else hidden.shape[1]

    # -- one trajectory --------------------------------------------------------------------------
    def call(self, states: np.ndarray, actions: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """(rewards (T,), hidden (T, k) or None) of one trajectory, checked; OracleError if not."""
        states = np.asarray(states, dtype=np.float64)
        n = len(states)
        if actions is not None:
            actions = np.asarray(actions, dtype=np.float64).reshape(n, -1).copy()
        try:
            out = self.function(states.copy(), actions)
        except Exception as exc:  # noqa: BLE001 - the user's code: one line naming it
            where = " (actions are None here: this node follows observations only)" if actions is None else ""
            raise OracleError(f"oracle {self.spec}: raised {type(exc).__name__}: {exc}{where}") from None
        hidden = None
        if isinstance(out, tuple):
            if len(out) != 2:
                raise OracleError(f"oracle {self.spec}: returned a tuple of {len(out)}; expected "
                                  f"rewards (T,) or (rewards (T,), hidden (T, k))")
            out, hidden = out
        rewards = self._array(out, "rewards")
        if rewards.shape != (n,):
            raise OracleError(f"oracle {self.spec}: rewards of shape {rewards.shape} for {n} steps; "
                              f"expected ({n},)")
        if hidden is not None:
            hidden = self._array(hidden, "hidden")
            if hidden.ndim == 1:
                hidden = hidden[:, None]
            if hidden.ndim != 2 or hidden.shape[0] != n:
                raise OracleError(f"oracle {self.spec}: hidden of shape {hidden.shape} for {n} steps; "
                                  f"expected ({n}, k)")
            if self.hidden_size and hidden.shape[1] != self.hidden_size:
                raise OracleError(f"oracle {self.spec}: hidden of size {hidden.shape[1]}, earlier "
                                  f"{self.hidden_size}")
        elif self.hidden_size:
            raise OracleError(f"oracle {self.spec}: returned no hidden state, earlier one of size "
                              f"{self.hidden_size}")
        return rewards, hidden

    def _array(self, value, what: str) -> np.ndarray:
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise OracleError(f"oracle {self.spec}: {what} is a {type(value).__name__}, not numbers") from None
        if not np.all(np.isfinite(array)):
            raise OracleError(f"oracle {self.spec}: {what} contain NaN or inf")
        return array

    def check_causal(self, states: np.ndarray, actions: np.ndarray | None, rewards: np.ndarray) -> None:
        """OracleError if r_t of the first half of a trajectory changes when the rest is cut off."""
        cut = len(states) // 2
        if cut < 1:
            return
        head, _ = self.call(states[:cut], None if actions is None else actions[:cut])
        if not np.allclose(head, rewards[:cut], rtol=1e-6, atol=1e-9):
            t = int(np.argmax(~np.isclose(head, rewards[:cut], rtol=1e-6, atol=1e-9)))
            raise OracleError(f"oracle {self.spec}: r_{t} is {rewards[t]:g} on the whole trajectory but "
                              f"{head[t]:g} on its first {cut} steps; a reward may depend on steps up to "
                              f"its own only")
        self.causal_checked = True

    # -- the Oracle interface ----------------------------------------------------------------------
    def initial_hidden(self, n: int = 1) -> np.ndarray:
        return np.zeros((n, self.hidden_size))

    def step(self, hidden, states, actions=None):
        raise NotImplementedError(f"oracle {self.spec} judges whole trajectories: use label() or tracker()")

    def label(self, states: np.ndarray, actions: np.ndarray | None = None,
              lengths: np.ndarray | None = None) -> OracleLabels:
        """Label trajectories: states (n, L, d), actions (n, L, A) or None, lengths (n,) (default L)."""
        states = np.asarray(states)
        if states.ndim != 3:
            raise ValueError(f"states must be (n, L, d), got shape {states.shape}")
        actions = None if actions is None else np.asarray(actions)
        n = states.shape[0]
        if lengths is None:
            lengths = np.full(n, states.shape[1] if actions is None else actions.shape[1])
        lengths = np.asarray(lengths, dtype=np.int64)
        horizon = int(lengths.max()) if n else 0
        rewards = np.zeros((n, horizon))
        hidden = np.zeros((n, horizon, self.hidden_size))
        for i in range(n):
            T = int(lengths[i])
            s, a = states[i, :T], None if actions is None else actions[i, :T].reshape(T, -1)
            r, h = self.call(s, a)
            if not self.causal_checked and T >= 2:
                self.check_causal(s, a, r)
            rewards[i, :T] = r
            if h is not None:
                hidden[i, :T] = h
        return OracleLabels(rewards.sum(axis=1), rewards, hidden, lengths.astype(np.int64))

    def tracker(self) -> "FunctionOracleTracker":
        return FunctionOracleTracker(self)


class FunctionOracleTracker(OracleTracker):
    """Online use of a trajectory function: each step calls it on the trajectory so far and takes
    its last reward (and hidden state). Costs O(t) per step."""

    oracle: FunctionOracle

    def reset(self) -> None:
        super().reset()
        self.states: list = []
        self.actions: list = []

    def step(self, state: np.ndarray, action: np.ndarray | None = None) -> tuple[float, np.ndarray]:
        """(r_t, h_{t+1}) of the trajectory so far; `action` a_t, or None where it is not known
        (then the function gets actions None for the whole trajectory)."""
        self.states.append(np.asarray(state, dtype=np.float64).reshape(-1))
        if action is not None:
            self.actions.append(np.asarray(action, dtype=np.float64).reshape(-1))
        actions = np.stack(self.actions) if len(self.actions) == len(self.states) else None
        rewards, hidden = self.oracle.call(np.stack(self.states), actions)
        self.hidden = np.zeros((1, 0)) if hidden is None else hidden[-1:].copy()
        self.t += 1
        self.total += float(rewards[-1])
        return float(rewards[-1]), self.hidden[0].copy()
