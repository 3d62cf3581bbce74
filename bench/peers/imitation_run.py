"""One run of imitation's preference comparisons on one of our tasks, as imitation's users run it.

Runs inside the peer venv that `bench/imitation_peer.py --setup` builds (imitation 1.0.1 pins an
older gymnasium and stable-baselines3 than ours), never in ours:

    runs/peers/imitation-venv/bin/python bench/peers/imitation_run.py --task key --comparisons 1000 \
        --teacher perfect --seed 0 --held-out held.npz --out runs/peers/imitation/key_n1000_perfect_s0

What runs is imitation's own script, `imitation.scripts.train_preference_comparisons` (through its
Sacred experiment's Python API), with its defaults (fragments of 100 steps, 5 iterations, 10% of the
comparisons before the agent trains, a hyperbolic query schedule, 3 reward epochs an iteration, its
`BasicRewardNet` with running input and output normalisation, PPO with SB3's hyperparameters on 8
environments trained on the learnt reward all along), and `--ensemble`: its `reward.reward_ensemble`
named config (5 members, trained by its `EnsembleTrainer`); `--trajectories`: its script's
`trajectory_path`, comparisons of a fixed set of episodes (ours: the ones our model learns from)
instead of its agent's, then its agent on the learnt reward; `--true-reward`: no reward learning,
its agent on the oracle's reward (a reference). Two settings are ours: the environment
runs in one process (`environment.parallel=False`, so that a run keeps to one core as ours do) and
the teacher: imitation's gatherer class is replaced by `TeacherGatherer`, which asks our
`SimulatedTeacher` (perfect: beta = inf; noisy: beta = 1, mistake 0.1: `TEACHERS` of its module) to
compare the two fragments' oracle returns. Our navigation episodes are 100 steps, so a fragment
is a whole episode and a comparison is the one our teacher makes.

The environment is our task through its Gymnasium API (`nmrm_ros.rl.wrappers.make_reward_env(task,
"oracle-no-hidden")`): the agent and the reward net observe the task's state, the env's reward is
the oracle's (its hidden state tracked by the wrapper, never observed), which only the teacher and
the judges read.

Writes to --out: `result.json` (the run's settings, wall and CPU seconds, imitation's own rollout
statistics, and our judgement of its final agent: the greedy oracle return of 50 episodes with
`nmrm_ros.rl.evaluation.evaluate_agent`, episode seeds 10^8.., as our agents are judged) and
`held_rewards.npy`: its reward net's per-step rewards (`predict_processed`, what its agent trains
on) for the held-out episodes of --held-out (states (n, L, d), actions (n, L), final_states (n, d),
lengths (n,)), scored by the driver with our metrics.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from nmrm_ros.datasets.preference_teacher import TEACHERS  # the teachers' knobs, as our benches use them



def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", required=True)
    ap.add_argument("--comparisons", type=int, required=True)
    ap.add_argument("--teacher", choices=sorted(TEACHERS), required=True)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--timesteps", type=int, required=True, help="its agent's environment steps (total_timesteps)")
    ap.add_argument("--ensemble", action="store_true", help="its reward.reward_ensemble named config")
    ap.add_argument("--trajectories", type=Path, default=None,
                    help="compare fragments of these episodes (npz: states, actions, final_states, rewards, lengths) "
                         "instead of its agent's (its script's trajectory_path), then train its agent on the learnt reward")
    ap.add_argument("--true-reward", action="store_true",
                    help="no reward learning: its agent (PPO, its script's settings) on the oracle's reward itself")
    ap.add_argument("--held-out", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--eval-episodes", type=int, default=50)
    return ap.parse_args(argv)


def env_id(task: str) -> str:
    return f"NmrmPeer-{task.replace('_', '')}-v0"


#: a reset seed s starts our episode count at s * SEED_SPREAD: SB3 seeds env i of a vectorised env with
#: seed + i, and our envs then step their episode seeds by one an episode (`EpisodeSeeds`), so
#: without the spread env i's k-th episode would be env i + 1's (k - 1)-th (as `train_agent` does)
SEED_SPREAD = 10 ** 6


def register(task: str) -> str:
    """Register our task (oracle reward, hidden state not observed) under a Gymnasium id."""
    import gymnasium as gym

    from nmrm_ros.rl.wrappers import make_reward_env

    class SpreadSeeds(gym.Wrapper):
        def reset(self, *, seed=None, options=None):
            return self.env.reset(seed=None if seed is None else int(seed) * SEED_SPREAD, options=options)

    name = env_id(task)
    if name not in gym.registry:
        gym.register(name, entry_point=lambda: SpreadSeeds(make_reward_env(task, "oracle-no-hidden", seed=0)))
    return name


def teacher_gatherer():
    """imitation's PreferenceGatherer that asks our SimulatedTeacher (a class made here, as the
    import of imitation must follow the venv check)."""
    from imitation.algorithms.preference_comparisons import PreferenceGatherer

    from nmrm_ros.datasets.preference_teacher import SimulatedTeacher

    class TeacherGatherer(PreferenceGatherer):
        """P(fragment 1 preferred) as our teacher answers from the fragments' oracle returns."""

        def __init__(self, beta: float = math.inf, mistake: float = 0.0, rng=None, custom_logger=None) -> None:
            super().__init__(rng=rng, custom_logger=custom_logger)
            self.teacher = SimulatedTeacher(beta=beta, mistake=mistake).check()
            self.rng = rng

        def __call__(self, fragment_pairs) -> np.ndarray:
            ra = np.array([float(np.sum(a.rews)) for a, _ in fragment_pairs])
            rb = np.array([float(np.sum(b.rews)) for _, b in fragment_pairs])
            p, _ = self.teacher.decide(ra, rb, self.rng)
            return p.astype(np.float32)

    return TeacherGatherer


def held_rewards(reward_net, held: dict) -> np.ndarray:
    """(n, L) the reward net's processed per-step rewards of the held-out episodes (0 beyond a
    bag's length)."""
    states, actions, lengths = held["states"], held["actions"], held["lengths"]
    n, L, d = states.shape
    nxt = np.concatenate([states[:, 1:], np.zeros_like(states[:, :1])], axis=1)
    nxt[np.arange(n), lengths - 1] = held["final_states"]
    done = np.arange(L)[None, :] == (lengths - 1)[:, None]
    mask = np.arange(L)[None, :] < lengths[:, None]
    out = np.zeros((n, L))
    flat = reward_net.predict_processed(states[mask], actions[mask], nxt[mask], done[mask], update_stats=False)
    out[mask] = flat
    return out


def ppo_agent(args, reward_fn=None):
    """PPO as imitation's script makes it (its rl ingredient: SB3's PPO, 2048 steps a rollout over
    8 environments, minibatch 64, 10 epochs, lr 3e-4, no entropy bonus; its policy ingredient's
    FeedForward32Policy), `--timesteps` steps, seed `--seed`, on `reward_fn` (imitation's RewardFn:
    a learnt net's `predict_processed`) or, without one, on the oracle's reward itself: what its agent
    could reach were its reward model perfect (on the state it observes, without the oracle's memory)."""
    from imitation.policies.base import FeedForward32Policy
    from imitation.rewards.reward_wrapper import RewardVecEnvWrapper
    from imitation.util import util
    from stable_baselines3 import PPO

    venv = util.make_vec_env(register(args.task), n_envs=8, rng=np.random.default_rng(args.seed), parallel=False)
    if reward_fn is not None:
        venv = RewardVecEnvWrapper(venv, reward_fn)
    agent = PPO(FeedForward32Policy, venv, n_steps=2048 // 8, batch_size=64, n_epochs=10, learning_rate=3e-4,
                ent_coef=0.0, seed=args.seed, device="cpu", verbose=0)
    return agent.learn(args.timesteps)


def save_trajectories(src: Path, dst: Path) -> Path:
    """Our episodes (npz) as imitation's trajectories with the oracle's rewards, saved where its
    script's `trajectory_path` reads them."""
    from imitation.data import serialize, types

    with np.load(src) as f:
        states, actions, final, rewards, lengths = (f[k] for k in ("states", "actions", "final_states", "rewards", "lengths"))
    trajs = [types.TrajectoryWithRew(obs=np.concatenate([states[i, :n], final[i][None]]).astype(np.float32),
                                     acts=actions[i, :n], infos=None, terminal=True, rews=rewards[i, :n].astype(np.float32))
             for i, n in enumerate(lengths.astype(int))]
    serialize.save(dst, trajs)
    return dst


def main(argv=None) -> None:
    args = parse_args(argv)
    if args.comparisons < 1 or args.timesteps < 1 or args.eval_episodes < 1:
        sys.exit("error: --comparisons, --timesteps and --eval-episodes must be >= 1")
    import torch

    torch.set_num_threads(1)
    from imitation.scripts.train_preference_comparisons import train_preference_comparisons_ex

    from nmrm_ros.rl.evaluation import evaluate_agent

    args.out.mkdir(parents=True, exist_ok=True)
    updates = {
        "seed": args.seed,
        "total_comparisons": args.comparisons,
        "total_timesteps": args.timesteps,
        "gatherer_cls": teacher_gatherer(),
        "gatherer_kwargs": TEACHERS[args.teacher],
        "environment": {"gym_id": register(args.task), "parallel": False},
        "logging": {"log_dir": str(args.out / "log"), "log_format_strs": ["csv"]},
    }
    named = ["reward.reward_ensemble"] if args.ensemble else []
    from stable_baselines3 import PPO

    if args.trajectories:
        updates["trajectory_path"] = str(save_trajectories(args.trajectories, args.out / "trajectories"))
    start = (time.perf_counter(), time.process_time())  # the run and its agent's training, not the judging
    if args.true_reward:
        agent, config, stats = ppo_agent(args), {"total_timesteps": args.timesteps, "seed": args.seed}, {}
    else:
        run = train_preference_comparisons_ex.run(config_updates=updates, named_configs=named,
                                                  options={"--loglevel": "WARNING"})
        reward_net = torch.load(args.out / "log" / "checkpoints" / "final" / "reward_net.pt", weights_only=False)
        if args.trajectories:  # no agent trained meanwhile: its agent on the learnt reward, as its docs do
            import functools

            agent = ppo_agent(args, functools.partial(reward_net.predict_processed, update_stats=False))
        else:
            agent = PPO.load(args.out / "log" / "checkpoints" / "final" / "policy" / "model.zip", device="cpu")
        stats = run.result.get("imit_stats", {}) if isinstance(run.result, dict) else {}
        config = run.config
    wall, cpu = time.perf_counter() - start[0], time.process_time() - start[1]
    if not args.true_reward:
        with np.load(args.held_out) as f:
            held = {k: f[k] for k in f.files}
        np.save(args.out / "held_rewards.npy", held_rewards(reward_net, held))
    judged = evaluate_agent(agent, args.task, episodes=args.eval_episodes, reward="oracle-no-hidden")
    import imitation

    result = {
        "task": args.task, "teacher": args.teacher, "teacher_knobs": dict(TEACHERS[args.teacher]),
        "comparisons": args.comparisons, "seed": args.seed, "timesteps": args.timesteps,
        "variant": ("true_reward" if args.true_reward else "offline" if args.trajectories
                    else "ensemble" if args.ensemble else "defaults"), "imitation": imitation.__version__,
        "wall_seconds": wall, "cpu_seconds": cpu, "threads": 1,
        "agent_greedy_oracle_returns": [float(r) for r in judged.returns],
        "agent_greedy_oracle_return": float(np.mean(judged.returns)),
        "random_policy_oracle_return": float(np.mean(judged.random_returns)),
        "imitation_rollout_stats": {k: float(v) for k, v in stats.items() if np.isscalar(v)},
        "config": {k: (v if isinstance(v, (int, float, str, bool, type(None), list, dict)) else repr(v))
                   for k, v in config.items() if k not in ("gatherer_cls",)},
        "pid": os.getpid(),
    }
    (args.out / "result.json").write_text(json.dumps(result, indent=1, default=repr))
    print(f"{args.task} n{args.comparisons} {args.teacher} s{args.seed}: greedy oracle return "
          f"{result['agent_greedy_oracle_return']:.2f} (random {result['random_policy_oracle_return']:.2f}), {wall:.0f} s")


if __name__ == "__main__":
    main()
