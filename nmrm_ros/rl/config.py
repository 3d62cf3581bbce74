"""RL hyperparameters (config/rl.yaml) and the SB3 algorithm built from them.

`make_algorithm(env, task, seed)` gives the paper's agent for a task (App. E): double DQN for the 2D
navigation tasks, SAC for Lunar Lander. Plain Python, no rclpy.
"""

from __future__ import annotations

from pathlib import Path

import yaml

CONFIG_FILE = Path(__file__).resolve().parents[2] / "config" / "rl.yaml"


def config_path() -> Path:
    """config/rl.yaml of the source tree, else of the installed share directory."""
    if CONFIG_FILE.is_file():
        return CONFIG_FILE
    from ..ros.ament_paths import require_share_dir

    return require_share_dir("nmrm_ros") / "config" / "rl.yaml"


def algorithm_name(task: str, continuous: bool = False) -> str:
    """"dqn" for the discrete navigation tasks, "sac" for Lunar Lander and continuous variants."""
    from ..tasks import task_info

    info = task_info(task)
    return "dqn" if info.discrete and not continuous else "sac"


#: the RL config's entry of changes for a task spec (your own task: "gym:<id>", "module:attr")
OWN_TASK = "your_own_task"


def load_rl_config(algo: str, path: str | Path | None = None, task: str | None = None, **overrides) -> dict:
    """The `algo` section ("dqn" | "sac") of the RL config; for a task spec (`task` with a colon:
    your own task) then the changes to that section of the config's entry for the spec, else for
    its environment (the spec up to its first comma, e.g. "gym:CartPole-v1"), else of its
    `your_own_task` entry; then the non-None `overrides`."""
    from ..tasks.gym_task import is_task_spec

    source = path or config_path()
    with open(source) as f:
        table = yaml.safe_load(f)
    if not isinstance(table, dict) or not isinstance(table.get(algo), dict):
        raise ValueError(f"no RL config for {algo!r} in {source}")
    cfg = dict(table[algo])
    changes = dict(overrides)
    if task is not None and is_task_spec(task):
        entry = next(k for k in (task, task.split(",")[0], OWN_TASK) if k in table or k == OWN_TASK)
        own = table.get(entry) or {}
        own = (own.get(algo) or {}) if isinstance(own, dict) else own
        if not isinstance(own, dict):
            raise ValueError(f"{entry}.{algo} in {source} must be a table of settings")
        changes = {**own, **{k: v for k, v in overrides.items() if v is not None}}
    unknown = set(changes) - set(cfg) - set(TRUST_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown RL settings {sorted(unknown)}")
    cfg.update({k: v for k, v in changes.items() if v is not None})
    check_trust_settings(cfg, source)
    return cfg


#: the settings that make an agent trustworthy (issue 50) and their defaults, for every task:
#: targets clipped to the value bound (`value_bound`), a policy snapshot every `keep_every`
#: episodes, the best kept (`kept_policy`; 0: keep the last policy), and `catch_up_steps`
#: gradient steps on the relabelled replay buffer when the reward model changes (`replay_relabel`)
TRUST_DEFAULTS = {"bound_values": True, "keep_every": 20, "catch_up_steps": 10000}


def trust_settings(cfg: dict) -> dict:
    """bound_values, keep_every and catch_up_steps of a config section, their defaults where it
    has none (a config written before them)."""
    return {k: cfg.get(k, v) for k, v in TRUST_DEFAULTS.items()}


def check_trust_settings(cfg: dict, source) -> None:
    """ValueError (one line) for a bound_values that is not true/false or a keep_every or
    catch_up_steps that is not a whole number >= 0."""
    trust = trust_settings(cfg)
    if not isinstance(trust["bound_values"], bool):
        raise ValueError(f"bound_values in {source} must be true or false, got {trust['bound_values']!r}")
    every = trust["keep_every"]
    if isinstance(every, bool) or not isinstance(every, int) or every < 0:
        raise ValueError(f"keep_every in {source} must be a whole number of episodes >= 0 (0: keep the last "
                         f"policy), got {every!r}")
    steps = trust["catch_up_steps"]
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise ValueError(f"catch_up_steps in {source} must be a whole number of gradient steps >= 0 (0: none), "
                         f"got {steps!r}")


def make_algorithm(env, algo: str, cfg: dict, episode_length: int, seed: int = 0, verbose: int = 0,
                   image_shape: tuple = ()):
    """The SB3 model for `env` (a gymnasium Env or VecEnv) from a config section.

    episode_length: steps per episode T (SB3 plans its epsilon schedule over `episodes * T` steps).
    image_shape: (H, W, C) when the observation starts with an image's pixels: a small CNN reads
    them (`image_features.ImageStateExtractor`); () for a vector observation.
    """
    from .image_features import image_policy_kwargs

    policy_kwargs = {"net_arch": list(cfg["net_arch"]),
                     "optimizer_kwargs": {"fused": bool(cfg.get("fused_adam", False))},
                     **image_policy_kwargs(image_shape)}
    if algo == "dqn":
        import warnings

        from .double_dqn import DoubleDQN

        with warnings.catch_warnings():
            # With n_envs > 1 (a fleet learner) SB3 warns that the target network then moves once
            # per env.step() call, i.e. per n_envs transitions. That is once per gradient step
            # (train_freq 1, gradient_steps 1), which is what Polyak averaging every step means.
            warnings.filterwarnings("ignore", message="The number of environments used is greater than the target")
            return DoubleDQN(
                "MlpPolicy", env, seed=seed, verbose=verbose, device="cpu",
                learning_rate=cfg["learning_rate"], buffer_size=int(cfg["buffer_size"]),
                learning_starts=int(cfg["learning_starts"]), batch_size=int(cfg["batch_size"]),
                tau=cfg["tau"], gamma=cfg["gamma"], train_freq=int(cfg["train_freq"]),
                gradient_steps=int(cfg["gradient_steps"]),
                target_update_interval=int(cfg["target_update_interval"]),
                exploration_fraction=float(cfg["exploration_fraction"]),
                exploration_initial_eps=cfg["exploration_initial_eps"],
                exploration_final_eps=cfg["exploration_final_eps"], max_grad_norm=cfg["max_grad_norm"],
                double_q=bool(cfg["double_q"]), bound_values=trust_settings(cfg)["bound_values"],
                policy_kwargs=policy_kwargs)
    if algo == "sac":
        from .sac import SplitLRSAC

        return SplitLRSAC(
            "MlpPolicy", env, seed=seed, verbose=verbose, device="cpu",
            learning_rate=cfg["learning_rate"], policy_learning_rate=cfg["policy_learning_rate"],
            buffer_size=int(cfg["buffer_size"]), learning_starts=int(cfg["learning_starts"]),
            batch_size=int(cfg["batch_size"]), tau=cfg["tau"], gamma=cfg["gamma"],
            train_freq=int(cfg["train_freq"]), gradient_steps=int(cfg["gradient_steps"]),
            ent_coef=cfg["ent_coef"], bound_values=trust_settings(cfg)["bound_values"],
            policy_kwargs=policy_kwargs)
    raise ValueError(f"unknown algorithm {algo!r}: use dqn or sac")
