"""The modified Lunar Lander task (paper App. D.1): gymnasium's continuous Lunar Lander (box2d)
with the native reward discarded and T = 500.

Landing, coming to rest or touching the ground with the body do not end the episode (the task
asks the lander to take off again); it ends early only when the lander leaves the screen
(|x| >= 1). State (8,) float32 `[x, y, vx, vy, angle, angular_velocity, left_contact,
right_contact]`; action (2,) in [-1, 1]: main and side engine throttles.

`ScriptedLanderController` is a goal-directed policy (land, wait on the pad, take off, hover) with
randomised timing and noise, used to build the trajectory pool of the screened dataset.
"""

from __future__ import annotations

import numpy as np
from gymnasium.envs.box2d.lunar_lander import LunarLander

EPISODE_LENGTH = 500
STATE_SIZE = 8
#: version of `ScriptedLanderController`'s plan distribution, recorded in a dataset's meta ("plans"):
#: 2 (2026-12-04) lands off the pad's centre and waits close to the 50-step target too, so that the
#: oracle's two thresholds are covered from both sides (issue 31: agents on models of version-1
#: data took off after 45-49 steps on the pad, or sat just off it, and were paid in full);
#: 3 (2026-12-04) lands again after some of the take-offs and stays down, so that the data show
#: contact after the pad phase paying nothing (an agent on a model of version-2 data hopped after
#: its 50 pad steps and sat down again, paid ~1.5 a step for it where the oracle pays ~0.1)
SCRIPTED_PLANS = 3
#: fraction of the plans that take off after resting and land again (plans version 3)
RELAND_FRACTION = 0.3
#: half-width of the landing targets drawn off the centre (the pad's is 0.2)
LAND_X_SPREAD = 0.6


class RewardlessLunarLander(LunarLander):
    """Continuous Lunar Lander with reward 0, no termination on landing/rest/crash, and a
    truncation at `episode_length` steps."""

    def __init__(self, episode_length: int = EPISODE_LENGTH, **kwargs) -> None:
        kwargs.setdefault("continuous", True)
        super().__init__(**kwargs)
        self.episode_length = int(episode_length)
        self.task = "lunar_lander"
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._t = 0
        obs, info = super().reset(seed=seed, options=options)  # takes one no-op step itself
        self._t = 0
        info = dict(info, t=0)
        return obs, info

    def step(self, action):
        if self._t >= self.episode_length:
            raise RuntimeError("episode is over (truncated); call reset()")
        action = np.asarray(action, dtype=np.float32)
        if action.shape != (2,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be 2 finite floats, got {action!r}")
        obs, _native_reward, _native_terminated, _, info = super().step(np.clip(action, -1, 1))
        self._t += 1
        terminated = bool(abs(obs[0]) >= 1.0)
        truncated = self._t >= self.episode_length
        return obs, 0.0, terminated, truncated, dict(info, t=self._t)


class ScriptedLanderController:
    """A PD controller that lands on the pad, stays `wait` steps, takes off and hovers at
    `hover_y` (and in some plans lands again after `reland_after` steps in the air and stays
    down). Timing, targets and action noise are drawn from `rng` per episode, so a pool of
    episodes covers many of the screening classes (never landing, short stays, long stays, with
    and without hovering, back on the ground after the pad phase)."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.reset()

    def reset(self) -> None:
        """Draw a new random plan for the next episode."""
        r = self.rng
        # wait on the pad: not at all, shortly, close to the 50-step target (either side), past
        # it, or for ever
        wait = int(r.choice([0, r.integers(1, 40), r.integers(40, 61), r.integers(61, 120), 10**6]))
        land = bool(r.random() < 0.85)
        # land on the pad's centre, or anywhere from well inside to well outside its edges
        land_x = float(r.choice([0.0, r.uniform(-LAND_X_SPREAD, LAND_X_SPREAD)]))
        hover_y = float(r.uniform(0.4, 1.6))
        hover_x = float(r.uniform(-0.9, 0.9))
        noise = float(r.choice([0.0, 0.2, 0.5]))
        # some take-offs end on the ground again, shortly (a hop) or after a long flight
        reland_after = int(r.integers(1, 150)) if r.random() < RELAND_FRACTION else 0
        reland_x = float(r.choice([0.0, r.uniform(-LAND_X_SPREAD, LAND_X_SPREAD)]))
        self.set_plan(wait, land, hover_x, hover_y, noise, land_x=land_x,
                      reland_after=reland_after, reland_x=reland_x)

    def set_plan(self, wait: int, land: bool = True, hover_x: float = 0.0, hover_y: float = 1.0,
                 noise: float = 0.0, land_x: float = 0.0, reland_after: int = 0,
                 reland_x: float = 0.0) -> None:
        """Start an episode with this plan (`reset` draws one at random): land at x = `land_x`
        (if `land`; the pad is |x| <= 0.2), stay `wait` steps on the ground, then hover at
        (hover_x, hover_y) with action noise std `noise`; with `reland_after` > 0, after that many
        steps of the take-off land again at x = `reland_x` and stay down."""
        self.wait, self.land, self.hover_x, self.hover_y, self.noise = int(wait), bool(land), \
            float(hover_x), float(hover_y), float(noise)
        self.land_x = float(land_x)
        self.reland_after, self.reland_x = int(reland_after), float(reland_x)
        self.pad_steps = 0
        self.air_steps = 0  # steps since the take-off after resting
        self.phase = "descend" if self.land else "hover"

    def __call__(self, s: np.ndarray) -> np.ndarray:
        x, y, vx, vy, ang, vang, cl, cr = (float(v) for v in s)
        on_ground = cl > 0.5 and cr > 0.5
        if self.phase == "descend" and on_ground:
            self.phase = "rest"
        if self.phase == "rest":
            self.pad_steps += 1
            if self.pad_steps >= self.wait:
                self.phase = "hover"
        # a landing plan hovers only after its rest on the ground
        if self.phase == "hover" and self.land and self.reland_after:
            self.air_steps += 1
            if self.air_steps > self.reland_after:
                self.phase, self.land_x = "reland", self.reland_x
        if self.phase == "reland" and on_ground:
            self.phase = "down"
        if self.phase in ("descend", "reland"):
            tx, ty = self.land_x, 0.0
        elif self.phase in ("rest", "down"):
            return np.array([-1.0, 0.0], dtype=np.float32)
        else:
            tx, ty = self.hover_x, self.hover_y
        angle_target = np.clip((x - tx) * 0.5 + vx * 1.0, -0.4, 0.4)
        angle_todo = (angle_target - ang) * 0.5 - vang * 1.0
        if self.phase in ("descend", "reland"):
            hover_todo = (0.55 * abs(x - tx) - y) * 0.5 - vy * 0.5
            if cl > 0.5 or cr > 0.5:
                angle_todo, hover_todo = 0.0, -vy * 0.5
        else:
            hover_todo = (ty - y) * 0.5 - vy * 0.5
        a = np.array([hover_todo * 20 - 1, -angle_todo * 20], dtype=np.float64)
        if self.noise:
            a += self.rng.normal(0.0, self.noise, size=2)
        return np.clip(a, -1.0, 1.0).astype(np.float32)


def run_episode(env: RewardlessLunarLander, policy, seed: int, steps: int):
    """Reset `env` with `seed` and take up to `steps` actions `policy(obs)`, stopping when the
    episode ends. Returns (states (L + 1, 8) float32, actions (L, 2) float32, terminated bool)."""
    obs, _ = env.reset(seed=seed)
    states, actions = [obs], []
    terminated = False
    for _ in range(steps):
        a = policy(obs)
        obs, _, terminated, truncated, _ = env.step(a)
        states.append(obs)
        actions.append(a)
        if terminated or truncated:
            break
    return np.asarray(states, dtype=np.float32), np.asarray(actions, dtype=np.float32), bool(terminated)


def rollout_lunar_lander(n: int, seed: int, policy: str = "scripted",
                         episode_length: int = EPISODE_LENGTH):
    """Roll out `n` episodes sequentially (box2d cannot be batched).

    Episode i resets with seed `seed + i`; the policy's randomness comes from
    `np.random.default_rng(seed)`. Returns a list of (states (L + 1, 8) float32,
    actions (L, 2) float32, terminated bool), L <= episode_length.
    """
    rng = np.random.default_rng(seed)
    env = RewardlessLunarLander(episode_length=episode_length)
    controller = ScriptedLanderController(rng) if policy == "scripted" else None
    if policy not in ("scripted", "random"):
        raise ValueError(f"unknown policy {policy!r}: use 'scripted' or 'random'")
    def random_policy(_obs: np.ndarray) -> np.ndarray:
        return rng.uniform(-1, 1, 2).astype(np.float32)

    out = []
    for i in range(n):
        if controller is not None:
            controller.reset()
        out.append(run_episode(env, controller or random_policy, seed + i, episode_length))
    env.close()
    return out


# --- what the package knows of the task (its TaskInfo) and its screening classes ---

#: x_min, x_max, y_min, y_max of the screen the views draw
ARENA = (-1.0, 1.0, 0.0, 1.5)


def screening_classes(key_fourth_class: bool = False):
    """18 classes, each at most a fifth of the dataset (App. D.2; `lunar_lander_classes`)."""
    from .info import ScreeningSpec

    return ScreeningSpec(18, 0.2)


def lunar_lander_classes(states: np.ndarray, labels, key_fourth_class: bool = False) -> np.ndarray:
    """pad_bin x take_off x hover_bin (App. D.2). Hover steps are counted from the step the pad
    count reaches 50 if it does, else from the first step off the pad after the first landing."""
    from ..oracles.lunar_lander import r_hover, r_no_contact, r_pad

    n, horizon = states.shape[:2]
    out = np.zeros(n, dtype=np.int64)
    for i in range(n):
        length = int(labels.lengths[i])
        s = np.asarray(states[i, :length], dtype=np.float64)
        pad = r_pad(s) == 1
        pad_steps = int(pad.sum())
        if pad_steps == 0:
            continue  # class 0: never on the pad, no take-off, no hover
        first_pad = int(np.argmax(pad))
        off = (~pad) & (np.arange(length) > first_pad)
        airborne = (r_no_contact(s) == 1) & (np.arange(length) > first_pad)
        take_off = int(airborne.any())
        reached = np.flatnonzero(labels.hidden[i, :length, 0] >= 50)
        if reached.size:
            start = int(reached[0])
        elif off.any():
            start = int(np.argmax(off))
        else:
            start = length
        hover = int((r_hover(s[start:]) == 1).sum())
        pad_bin = 1 if pad_steps < 50 else 2
        hover_bin = 0 if hover == 0 else (1 if hover < 20 else 2)
        out[i] = pad_bin * 6 + take_off * 3 + hover_bin
    return out


def map_states(points: np.ndarray) -> np.ndarray:
    """The lander at rest at each (x, y) of `points` (N, 2): velocities and angle 0, both legs on
    the ground on the screen's bottom row only -> (N, 8)."""
    contact = (points[:, 1] <= ARENA[2])[:, None].astype(np.float64)
    return np.concatenate([points, np.zeros((len(points), 4)), contact, contact], axis=1)


def _task_info():
    from ..oracles.lunar_lander import HOVER_ZONE, PAD_HALF_WIDTH
    from .info import MapZone, TaskInfo

    # the oracle's zones (paper App. D.1): the pad on the ground (gold), the hover zone (green)
    zones = (MapZone("pad", "goldenrod", -PAD_HALF_WIDTH, PAD_HALF_WIDTH, 0.0, 0.0, "bar"),
             MapZone("hover zone", "green", *HOVER_ZONE))

    # returns stay within +-1000: the per-step rewards are bounded by the oracle's terms
    return TaskInfo("lunar_lander", STATE_SIZE, False, 2, EPISODE_LENGTH, family="lunar_lander",
                    return_range=(-1000.0, 1000.0), arena=ARENA, screening="pool",
                    screening_classes=screening_classes, classify=lunar_lander_classes, renders=True,
                    map_states=map_states, map_note="The lander at rest there (velocities and angle 0); legs "
                                                    "on the ground on the bottom row only.",
                    map_name="screen", zones=zones, instruction=INSTRUCTION,
                    legend=(("pad", "the landing pad: land here (both legs down) for 50 steps"),))


#: what a person judges (the labelling page), from the paper's task (App. D.1)
INSTRUCTION = ("The lander (its path in red, from the start marked o) should land on the pad (grey, both legs "
               "down, |x| <= 0.2) and stay there for 50 steps, then take off again and hover above the pad "
               "(|x| <= 0.5, height 0.75-1.25; not drawn) until step 500. Until it has been on the pad for 50 "
               "steps in all, each step on the pad earns 1 and slow, steady flight towards the pad up to 0.2 "
               "more; after that, each step with no leg on the ground earns 1, each step in the hover zone 1 "
               "more, and slow, steady, central flight at hover height up to 0.2 more. Judge the whole "
               "episode: landing, waiting 50 steps, taking off and hovering.")


TASK_INFO = _task_info()
