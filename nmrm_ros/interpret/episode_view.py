"""One recorded episode, step by step: its path, the reward served while it ran (RewardStep), and
the oracle's reward (OracleStep if recorded, else computed from the states).

read_episodes(bag) -> {(source, episode): EpisodeRecord}; the source is the topic namespace ('' for
/nmrm/...), as in `nmrm_ros.bags.load_bag_dataset`.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..bags.observation_images import BagImages
from ..bags.reader import BagError, iter_decoded
from ..bags.schemas import split_topic
from .traces import oracle_traces

_OBS, _REWARD, _ORACLE = "EnvObservation", "RewardStep", "OracleStep"


@dataclass
class EpisodeRecord:
    """task; states (L, d) s_0..s_{L-1} (the final observation excluded); served (L,) the recorded
    r'_t or None; served_by: RewardStep.source values seen; oracle (L,) r_t; oracle_recorded:
    whether the oracle reward came from OracleStep messages (else computed, from the privileged
    state where the task has one); privileged (L, p): the recorded privileged states (e.g. the
    positions behind a pixel task's images), or None."""

    task: str
    states: np.ndarray
    served: np.ndarray | None
    served_by: list
    oracle: np.ndarray
    oracle_recorded: bool
    privileged: np.ndarray | None = None


def _source(topic: str) -> str:
    try:
        return split_topic(topic)[0]
    except ValueError:
        return ""


def _judges_privileged(task: str, privileged: np.ndarray | None) -> bool:
    """Whether `task`'s oracle judges the privileged state recorded (its size is the task's)."""
    if privileged is None:
        return False
    from ..tasks import task_info

    return task_info(task).privileged_size == privileged.shape[-1] > 0


def read_episodes(bag: str | Path) -> dict:
    """Every complete episode of a bag, keyed (source, episode), in recorded order."""
    from ..tasks import task_info

    obs, served, oracle = defaultdict(dict), defaultdict(dict), defaultdict(dict)
    task, images = {}, BagImages()
    for topic, type_name, _, m in iter_decoded(bag):
        if images.take(topic, type_name, m):
            continue
        kind = type_name.rsplit("/", 1)[-1]
        key = (_source(topic), int(m.episode)) if kind in (_OBS, _REWARD, _ORACLE) else None
        if kind == _OBS:
            obs[key][int(m.step)] = m
            task[key] = m.task
        elif kind == _REWARD:
            served[key][int(m.step)] = m
        elif kind == _ORACLE:
            oracle[key][int(m.step)] = m
    episodes = {}
    for key, steps in obs.items():
        last = max(steps)
        if sorted(steps) != list(range(last + 1)) or last == 0:
            continue
        info = task_info(task[key])
        try:  # an image task's pixels from its observation images
            states = np.stack([images.whole_state(key[0], steps[t], info) for t in range(last)])
        except ValueError:  # an image missing: not a complete episode
            continue
        sizes = {len(getattr(steps[t], "privileged", ())) for t in range(last)}
        privileged = (np.array([list(steps[t].privileged) for t in range(last)], np.float32)
                      if len(sizes) == 1 and 0 not in sizes else None)
        have_served = all(t in served[key] for t in range(last))
        have_oracle = all(t in oracle[key] for t in range(last))
        if have_oracle:
            rewards = np.array([oracle[key][t].reward for t in range(last)], np.float64)
        else:
            rewards = oracle_traces(task[key], privileged if _judges_privileged(task[key], privileged)
                                    else states)[0]
        episodes[key] = EpisodeRecord(
            task[key], states,
            np.array([served[key][t].reward for t in range(last)], np.float64) if have_served else None,
            sorted({served[key][t].source for t in served[key]}), rewards, have_oracle, privileged)
    if not episodes:
        raise BagError(f"{bag}: no complete episode (EnvObservation steps 0..L) in the bag")
    return episodes
