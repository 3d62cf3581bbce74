"""The paper's reported figures (Early, Bewley et al., NeurIPS 2022), to set our results beside:
`PAPER_RETURN[arch][task]` and `PAPER_REWARD[arch][task]` are (mean, SEM) of the test return MSE and
reward MSE; `mean_sem` summarises our repeats the same way, `mean_seconds` their training time."""

from __future__ import annotations

import numpy as np

# Paper values (mean, SEM): App. C Table "toy results" and Sec. 4 Table 1 (Lunar Lander: its top 5 of
# 10 by reward MSE, scaled units; reward MSE in units of 1e-5).
PAPER_RETURN = {
    "instance_nn": {"toggle_switch": (0.030, 0.029), "push_switch": (3.337, 0.054), "dial": (5.489, 0.157),
                    "timer": (130.8, 1.530), "moving": (22.24, 0.441), "key": (7.764, 0.232), "charger": (7.783, 0.214),
                    "lunar_lander": (2.297, 0.058)},
    "embedding_lstm": {"toggle_switch": (0.008, 0.002), "push_switch": (0.663, 0.194), "dial": (0.434, 0.075),
                       "timer": (3.151, 0.662), "moving": (13.04, 0.899), "key": (0.360, 0.055), "charger": (0.689, 0.124),
                       "lunar_lander": (0.416, 0.048)},
    "instance_lstm": {"toggle_switch": (0.062, 0.058), "push_switch": (0.262, 0.154), "dial": (0.111, 0.014),
                      "timer": (7.313, 2.627), "moving": (11.13, 1.169), "key": (0.488, 0.062), "charger": (0.628, 0.126),
                      "lunar_lander": (1.223, 0.431)},
    "csc_lstm": {"toggle_switch": (0.000, 0.000), "push_switch": (0.140, 0.065), "dial": (0.121, 0.043),
                 "timer": (0.605, 0.166), "moving": (5.307, 0.299), "key": (0.391, 0.083), "charger": (0.125, 0.012),
                 "lunar_lander": (0.501, 0.035)},
}
PAPER_REWARD = {
    "instance_nn": {"toggle_switch": (0.002, 0.002), "push_switch": (0.086, 0.001), "dial": (0.954, 0.011),
                    "timer": (0.217, 0.001), "moving": (0.068, 0.000), "key": (0.011, 0.000), "charger": (0.025, 0.000),
                    "lunar_lander": (7.484, 0.861)},
    "embedding_lstm": {"toggle_switch": (0.003, 0.001), "push_switch": (0.206, 0.100), "dial": (0.244, 0.077),
                       "timer": (101.8, 60.35), "moving": (3.033, 0.715), "key": (0.010, 0.008), "charger": (0.037, 0.016),
                       "lunar_lander": (120.2, 24.27)},
    "instance_lstm": {"toggle_switch": (0.004, 0.004), "push_switch": (0.021, 0.008), "dial": (0.026, 0.004),
                      "timer": (0.263, 0.038), "moving": (0.069, 0.005), "key": (0.002, 0.000), "charger": (0.005, 0.001),
                      "lunar_lander": (9.336, 3.116)},
    "csc_lstm": {"toggle_switch": (0.000, 0.000), "push_switch": (0.012, 0.004), "dial": (0.022, 0.007),
                 "timer": (0.073, 0.016), "moving": (0.026, 0.002), "key": (0.001, 0.000), "charger": (0.001, 0.000),
                 "lunar_lander": (7.365, 1.032)},
}


def mean_sem(values: list) -> tuple:
    """(mean, standard error of the mean) of `values` (SEM 0 for a single value)."""
    v = np.asarray(values, dtype=np.float64)
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else 0.0


def mean_seconds(runs: list) -> str:
    """The runs' mean training time, 6 characters: CPU seconds (runs record "clock": "cpu"), or
    wall seconds marked "w" where any run is older and measured wall time (pauses included)."""
    wall = any(r.get("clock") != "cpu" for r in runs)
    return f"{np.mean([r['seconds'] for r in runs]):5.0f}" + ("w" if wall else " ")
