"""A vectorised env over several topic bridges (one `TopicEnv` per robot of a fleet), stepped
concurrently.

SB3's `DummyVecEnv` steps its envs one after another: over topics each step is a round trip
through another robot's graph, so N robots would take N round trips per fleet step. `ThreadedVecEnv`
is a `DummyVecEnv` whose `step_wait` runs every env's step (and its reset at an episode's end) in a
thread of its own and waits for all: one fleet step costs the slowest robot's round trip. The
waiting happens in queue gets that release the GIL; the policy and the learner stay in SB3's
thread. Observations, rewards, dones and infos are exactly those `DummyVecEnv` gives.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from copy import deepcopy

import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv


class ThreadedVecEnv(DummyVecEnv):
    def __init__(self, env_fns: list) -> None:
        super().__init__(env_fns)
        self.pool = ThreadPoolExecutor(max_workers=max(1, self.num_envs), thread_name_prefix="fleet-env")

    def _step_one(self, i: int):
        """Env i's transition; at an episode's end its terminal observation goes to the info and
        the env is reset (as DummyVecEnv does)."""
        obs, reward, terminated, truncated, info = self.envs[i].step(self.actions[i])
        done = terminated or truncated
        info["TimeLimit.truncated"] = truncated and not terminated
        reset_info = None
        if done:
            info["terminal_observation"] = obs
            obs, reset_info = self.envs[i].reset()
        return obs, reward, done, info, reset_info

    def step_wait(self):
        results = list(self.pool.map(self._step_one, range(self.num_envs)))
        for i, (obs, reward, done, info, reset_info) in enumerate(results):
            self.buf_rews[i], self.buf_dones[i], self.buf_infos[i] = reward, done, info
            if reset_info is not None:
                self.reset_infos[i] = reset_info
            self._save_obs(i, obs)
        return self._obs_from_buf(), np.copy(self.buf_rews), np.copy(self.buf_dones), deepcopy(self.buf_infos)

    def close(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)
        super().close()
