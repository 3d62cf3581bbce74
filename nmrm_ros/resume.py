"""When a finished run still stands for today's code and defaults (what a resuming benchmark checks).

A long run whose result file exists is skipped when it is resumed. That is only right while the run
was made with today's training (or RL) settings (`stale_settings`, `stale_rl_settings`), on data of
today's generator (`nmrm_ros.datasets.cache.stale_data`) and, for an agent, while its reward model is
the one it learnt on (its recorded `checkpoint_sha256` against
`nmrm_ros.mil.checkpoint.recorded_weights_sha256`); otherwise the run is made again.
"""

from __future__ import annotations

from dataclasses import MISSING, asdict, fields


#: RL settings added to config/rl.yaml since runs were first recorded, and what a run that did not
#: record them ran with (the value bound and the kept policy of issue 50 came in off)
RL_SETTINGS_BEFORE = {"bound_values": False, "keep_every": 0}


def stale_settings(recorded: dict | None, cfg) -> list[str]:
    """The settings in which a finished run's recorded config differs from `cfg` (today's defaults:
    a TrainConfig, or an RL config dict), as "name old -> new". A setting added to TrainConfig since
    the run counts as its default there (what the run trained with); one added to an RL config
    counts as its value in `RL_SETTINGS_BEFORE` where it has one, else is not compared. A run that
    recorded no config is stale as a whole."""
    if not recorded:
        return ["no recorded config"]
    today = dict(cfg) if isinstance(cfg, dict) else asdict(cfg)
    then = dict(recorded)
    if not isinstance(cfg, dict):
        then = {f.name: f.default for f in fields(cfg) if f.default is not MISSING} | then
    else:
        then = {k: v for k, v in RL_SETTINGS_BEFORE.items() if k in today} | then
    from .mil.training import EXECUTION_SETTINGS  # how fast, not what: never stale

    return [f"{k} {v!r} -> {today[k]!r}" for k, v in then.items()
            if k in today and today[k] != v and k not in EXECUTION_SETTINGS]


def stale_rl_settings(recorded: dict | None, task: str, **overrides) -> list[str]:
    """`stale_settings` of a finished agent's recorded RL config against today's for `task`
    (config/rl.yaml with `overrides`)."""
    from .rl import algorithm_name, load_rl_config

    return stale_settings(recorded, load_rl_config(algorithm_name(task), task=task, **overrides))
