"""When a benchmark's finished run still stands for today's code and defaults.

Benchmarks resume: a run whose result file exists is skipped. That is only right while the run
was made with today's training (or RL) settings and on data of today's generator (both checked here)
and, for an agent, while its reward model is the one it learnt on (its recorded `checkpoint_sha256` against the checkpoint's
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
    from nmrm_ros.mil.training import EXECUTION_SETTINGS  # how fast, not what: never stale

    return [f"{k} {v!r} -> {today[k]!r}" for k, v in then.items()
            if k in today and today[k] != v and k not in EXECUTION_SETTINGS]


def stale_rl_settings(recorded: dict | None, task: str, **overrides) -> list[str]:
    """`stale_settings` of a finished agent's recorded RL config against today's for `task`
    (config/rl.yaml with `overrides`)."""
    from nmrm_ros.rl import algorithm_name, load_rl_config

    return stale_settings(recorded, load_rl_config(algorithm_name(task), task=task, **overrides))


def stale_data(recorded_meta: dict | None, task: str) -> list[str]:
    """How a cached dataset (its meta) or a model's recorded training data (checkpoint
    ["data"]["meta"]) differs from what today's generator makes for `task`: Lunar Lander's scripted
    plans are versioned (`nmrm_ros.tasks.lunar_lander.SCRIPTED_PLANS`; data without a version are
    version 1). Empty when current, or when the data were not generated (a bag, a file of the user's)."""
    if task != "lunar_lander" or not recorded_meta or recorded_meta.get("policy") != "scripted":
        return []
    from nmrm_ros.tasks.lunar_lander import SCRIPTED_PLANS

    then = recorded_meta.get("plans", 1)
    return [] if then == SCRIPTED_PLANS else [f"scripted plans {then} -> {SCRIPTED_PLANS}"]
