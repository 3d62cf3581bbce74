"""Conversions between nmrm_msgs messages and numpy, with validation."""

from __future__ import annotations

import numpy as np


def as_vector(values, size: int | None = None, what: str = "vector") -> np.ndarray:
    """A float32[] field as a float64 array; ValueError if the size is wrong or a value is NaN/inf."""
    v = np.asarray(values, dtype=np.float64)
    if size is not None and v.shape != (size,):
        raise ValueError(f"{what} has size {v.size}, expected {size}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{what} contains NaN or inf")
    return v


def oracle_state(msg, state: np.ndarray, privileged_size: int) -> np.ndarray:
    """What the oracle steps with on an EnvObservation: its privileged state where the task has
    one (`privileged_size` values; ValueError, one line, if it is missing or malformed), else
    `state`."""
    if not privileged_size:
        return state
    return as_vector(getattr(msg, "privileged", []), privileged_size, "privileged state")


def to_float_list(values) -> list:
    """numpy or sequence -> list of Python floats (what float32[] fields accept)."""
    return [float(x) for x in np.asarray(values, dtype=np.float64).reshape(-1)]
