"""Hand-written probe trajectories of the navigation tasks (paper Fig. 6 and App. F).

A probe is a noise-free path of `EPISODE_LENGTH` states, built from legs: move straight towards a
point at the simulator's step size (0.1 per step), or stay for n steps; after the last leg the
agent stays where it is. `probe_states(task)` -> [(Probe, states (100, 2) float32)].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..oracles import make_oracle
from ..tasks.navigation import EPISODE_LENGTH, STEP_SIZE

LEFT_SPAWN = (0.15, 0.5)
RIGHT_SPAWN = (0.85, 0.5)
TREASURE = (0.5, 0.8)
KEY = (0.5, 0.2)


@dataclass(frozen=True)
class Probe:
    """name: short title; description: what the agent does; legs: ("to", (x, y)) or ("stay", n)
    in order; follow_moving: after the legs, chase Moving's treasure instead of staying."""

    name: str
    description: str
    start: tuple
    legs: tuple
    follow_moving: bool = False


def _charger(name: str, description: str, charge_steps: int) -> Probe:
    return Probe(name, description, LEFT_SPAWN, (("to", KEY), ("stay", charge_steps), ("to", TREASURE)))


PROBES: dict = {
    "timer": (
        Probe("optimal", "waits below the treasure, enters once it pays (t > 50)", LEFT_SPAWN,
              (("to", (0.5, 0.6)), ("stay", 44), ("to", TREASURE))),
        Probe("early", "goes straight into the treasure and stays", LEFT_SPAWN, (("to", TREASURE),)),
    ),
    "moving": (
        Probe("optimal left", "from the left spawn, follows the moving treasure", LEFT_SPAWN,
              (("to", (0.5, 0.8)),), follow_moving=True),
        Probe("optimal right", "from the right spawn, follows the moving treasure", RIGHT_SPAWN,
              (("to", (0.5, 0.8)),), follow_moving=True),
        Probe("static", "stands in the middle of the treasure row; the treasure passes over it",
              LEFT_SPAWN, (("to", (0.5, 0.8)),)),
    ),
    "key": (
        Probe("key first", "collects the key, then goes to the treasure", LEFT_SPAWN,
              (("to", KEY), ("to", TREASURE))),
        Probe("no key", "goes to the treasure without the key", LEFT_SPAWN, (("to", TREASURE),)),
    ),
    "charger": (
        _charger("optimal", "charges for 40 steps, then goes to the treasure", 40),
        _charger("under-charged", "charges for 10 steps only", 10),
        _charger("over-charged", "charges for 75 steps, leaving little time in the treasure", 75),
        Probe("challenging", "moves in and out of the charger four times, then to the treasure",
              LEFT_SPAWN, (("to", KEY), ("stay", 4), ("to", (0.5, 0.45)), ("to", KEY), ("stay", 4),
                           ("to", (0.5, 0.45)), ("to", KEY), ("stay", 4), ("to", (0.5, 0.45)),
                           ("to", KEY), ("stay", 4), ("to", TREASURE))),
    ),
}


def _toward(p: np.ndarray, target: np.ndarray) -> np.ndarray:
    d = target - p
    dist = float(np.hypot(*d))
    return target.copy() if dist <= STEP_SIZE else p + d * (STEP_SIZE / dist)


def build(probe: Probe, length: int = EPISODE_LENGTH) -> np.ndarray:
    """The probe's states s_0..s_{length-1}, (length, 2) float32."""
    p = np.asarray(probe.start, np.float64)
    out = [p.copy()]
    for kind, arg in probe.legs:
        if kind == "stay":
            out.extend(p.copy() for _ in range(int(arg)))
            continue
        target = np.asarray(arg, np.float64)
        while not np.allclose(p, target) and len(out) < length:
            p = _toward(p, target)
            out.append(p.copy())
    if probe.follow_moving:
        oracle = make_oracle("moving")
        hidden = oracle.initial_hidden()
        for s in out:
            hidden, _ = oracle.step(hidden, np.asarray([s]))
        while len(out) < length:
            # the treasure's left edge after this step's update: aim at its centre
            centre = hidden[0, 0] + hidden[0, 1] + oracle.width / 2
            p = _toward(p, np.array([np.clip(centre, 0.0, 1.0), TREASURE[1]]))
            out.append(p.copy())
            hidden, _ = oracle.step(hidden, np.asarray([p]))
    while len(out) < length:
        out.append(p.copy())
    return np.clip(np.asarray(out[:length]), 0.0, 1.0).astype(np.float32)


def probe_states(task: str) -> list:
    """[(Probe, states (100, 2) float32)] of a navigation task; Lunar Lander's rollouts
    (`lander_probes`: (LanderProbe, states (T, 8))); [] for tasks without probes."""
    if task in ROLLOUT_PROBES:  # probes whose paths come out of a simulator
        return ROLLOUT_PROBES[task]()
    return [(probe, build(probe)) for probe in PROBES.get(task, ())]


def _lander_probe_states() -> list:
    from .lander_probes import lander_probe_states

    return lander_probe_states()


#: task -> a function returning its probes as rollouts [(probe, states (T, d))]
ROLLOUT_PROBES: dict = {"lunar_lander": _lander_probe_states}
