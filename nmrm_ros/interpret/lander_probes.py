"""Probe trajectories of Lunar Lander (paper App. F, Fig. "Lunar Lander task trajectory probing").

Navigation probes are drawn by hand; a lander's path comes out of the physics, so a Lunar Lander
probe is a rollout of `ScriptedLanderController` with a fixed plan, no action noise and a fixed
reset seed (deterministic). `lander_probe_states()` -> [(LanderProbe, states (T, 8) float32)],
T = 500, or fewer where the lander leaves the screen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..tasks.lunar_lander import EPISODE_LENGTH, RewardlessLunarLander, ScriptedLanderController, run_episode


@dataclass(frozen=True)
class LanderProbe:
    """name, description; the controller's plan: `wait` steps on the pad if `land`, then hover at
    (hover_x, hover_y); `seed`: the environment's reset seed."""

    name: str
    description: str
    wait: int
    land: bool = True
    hover_x: float = 0.0
    hover_y: float = 1.0
    seed: int = 0


LANDER_PROBES = (
    LanderProbe("correct", "lands on the pad, stays 60 steps, takes off and hovers in the zone", 60),
    LanderProbe("no hover", "lands on the pad and never takes off", 10**6),
    LanderProbe("too short", "lands, stays 20 steps only, then hovers in the zone", 20),
    LanderProbe("never landed", "never lands; flies off the right edge of the screen", 0, land=False,
                hover_x=1.5, hover_y=0.6),
)


def rollout_probe(probe: LanderProbe, length: int = EPISODE_LENGTH) -> np.ndarray:
    """The probe's states s_0..s_{T-1}, (T, 8) float32."""
    env = RewardlessLunarLander(episode_length=length)
    controller = ScriptedLanderController(np.random.default_rng(probe.seed))
    controller.set_plan(probe.wait, probe.land, probe.hover_x, probe.hover_y, noise=0.0)
    states, _, _ = run_episode(env, controller, probe.seed, length - 1)
    env.close()
    return states


def lander_probe_states() -> list:
    """[(LanderProbe, states (T, 8) float32)] of every Lunar Lander probe."""
    return [(probe, rollout_probe(probe)) for probe in LANDER_PROBES]
