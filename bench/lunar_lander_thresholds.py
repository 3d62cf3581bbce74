"""Does a Lunar Lander reward model know the oracle's two thresholds? (issue 31)

    .venv/bin/python bench/lunar_lander_thresholds.py --checkpoints runs/reproduce_rl/models/lunar_lander_csc_lstm_seed0.pt
    .venv/bin/python bench/lunar_lander_thresholds.py --checkpoints A.pt B.pt \\
        --agent bench/results/reproduce_rl/agents/lunar_lander_model_seed0 --agent-checkpoint OLD.pt

The oracle pays the hover phase (no contact, hover zone) only after 50 steps *on the pad* (both legs
down, |x| <= 0.2). An agent trained on a model learns to take off as early, and to land as far out,
as the model still pays the hover phase for; where the model's thresholds are a few steps or a few
centimetres off the oracle's, the agent's episodes score ~90 with the oracle instead of ~700
(found on Figure 4's first CSC agent: it took off after 45-49 steps on the pad, or sat at x = 0.21).

1. Scripted probes (no action noise, reset seed 0): land at x = land_x, wait `wait` steps, take
   off and hover at (0, 1). Per plan: the oracle's pad count at take-off and return, and each
   model's return (stepped online, as served).
2. With --agent DIR: its greedy policy (DIR/policy.zip) run for --episodes episodes (seeds 777 ...)
   on the reward of --agent-checkpoint (the model it learnt on: its served state needs it); each
   model then scores the same episodes: mean learnt vs oracle return, and how many episodes it
   overpays by more than 100 (a failed take-off paid as a success). The episodes are kept in
   runs/lunar_lander_thresholds/ (keyed by the policy's SHA-256; reused when there). Then where
   along its first two episodes each 25 steps are paid by the oracle and by that model.

Prints both tables (bench/results/lunar_lander/thresholds*.txt are its output); writes nothing else. Takes ~10 s a model for the probes, ~1 min for 20 agent episodes.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EPISODES = ROOT / "runs" / "lunar_lander_thresholds"
WAITS = (40, 44, 46, 47, 48, 49, 50, 52, 55, 60)
LAND_XS = (0.0, 0.25, 0.4, 0.6)  # landing targets: the lander comes to rest at x ~ 0.03, 0.19, 0.27, 0.45


def model_returns(checkpoint: str, states: list) -> np.ndarray:
    """The model's return of each episode (states (T, 8) each), stepped online as served."""
    from nmrm_ros.mil import OnlineRewardModel, load_checkpoint

    model, _ = load_checkpoint(checkpoint, task="lunar_lander")
    online = OnlineRewardModel(model)
    return np.asarray([online.episode_rewards(episode).sum() for episode in states])


def probe_table(checkpoints: list) -> str:
    from nmrm_ros.interpret.lander_probes import EPISODE_LENGTH
    from nmrm_ros.oracles import make_oracle
    from nmrm_ros.tasks.lunar_lander import RewardlessLunarLander, ScriptedLanderController, run_episode

    oracle = make_oracle("lunar_lander")
    env = RewardlessLunarLander(episode_length=EPISODE_LENGTH)
    plans, states = [], []
    for land_x in LAND_XS:
        for wait in WAITS:
            controller = ScriptedLanderController(np.random.default_rng(0))
            controller.set_plan(wait, True, 0.0, 1.0, noise=0.0, land_x=land_x)
            s, _, _ = run_episode(env, controller, 0, EPISODE_LENGTH - 1)
            labels = oracle.label(s[None])
            rest = (s[:, 6] == 1) & (s[:, 7] == 1)
            plans.append((land_x, wait, float(np.median(s[rest, 0])) if rest.any() else float("nan"),
                          int(labels.hidden[0].max()), float(labels.returns[0])))
            states.append(s)
    env.close()
    learnt = {c: model_returns(c, states) for c in checkpoints}
    lines = ["# scripted probes: land at land_x (rests at x), wait, take off, hover at (0, 1); "
             "return of the oracle and of each model",
             f"{'land_x':>6} {'x':>6} {'wait':>4} {'pad':>4} {'oracle':>7} " + " ".join(f"{Path(c).stem[-24:]:>24}" for c in checkpoints)]
    for i, (land_x, wait, x, pad, ret) in enumerate(plans):
        lines.append(f"{land_x:6.2f} {x:6.2f} {wait:4d} {pad:4d} {ret:7.1f} "
                     + " ".join(f"{learnt[c][i]:24.1f}" for c in checkpoints))
    short = [i for i, p in enumerate(plans) if p[3] < 50]
    for c in checkpoints:
        over = learnt[c][short] - np.asarray([plans[i][4] for i in short])
        lines.append(f"# {c}: plans short of 50 pad steps overpaid by up to {over.max():.1f} "
                     f"(mean {over.mean():.1f}; {int((over > 100).sum())} of {len(short)} by more than 100)")
    return "\n".join(lines)


def agent_episodes(agent: Path, checkpoint: str, episodes: int) -> tuple[list, np.ndarray]:
    """The greedy agent's episodes (raw states (T, 8) each) and their oracle returns; cached."""
    from nmrm_ros.rl.evaluation import load_agent
    from nmrm_ros.rl.wrappers import make_reward_env

    import hashlib

    digest = hashlib.sha256((agent / "policy.zip").read_bytes()).hexdigest()[:12]
    cache = EPISODES / f"{agent.name}_{digest}_{episodes}.npz"
    if cache.is_file():
        data = np.load(cache)
        return [s[:n] for s, n in zip(data["states"], data["lengths"])], data["oracle"]
    policy, meta = load_agent(agent / "policy.zip")
    env = make_reward_env("lunar_lander", "model", checkpoint, seed=777, continuous=True,
                          served=meta.get("served_state"))
    runs, oracle, states = [], [], []
    obs, _ = env.reset(seed=777)
    while len(runs) < episodes:
        states.append(obs[:8].copy())
        obs, _, terminated, truncated, info = env.step(policy.predict(obs, deterministic=True)[0])
        if terminated or truncated:
            runs.append(np.asarray(states, dtype=np.float32))
            oracle.append(info["oracle_return"])
            states = []
            obs, _ = env.reset()
    env.close()
    lengths = np.array([len(s) for s in runs])
    padded = np.zeros((episodes, lengths.max(), 8), np.float32)
    for i, s in enumerate(runs):
        padded[i, :len(s)] = s
    EPISODES.mkdir(parents=True, exist_ok=True)
    np.savez(cache, states=padded, lengths=lengths, oracle=np.asarray(oracle))
    return runs, np.asarray(oracle)


def agent_table(agent: Path, agent_checkpoint: str, checkpoints: list, episodes: int) -> str:
    states, oracle = agent_episodes(agent, agent_checkpoint, episodes)
    lines = [f"# {agent.name}'s greedy episodes ({episodes}, seeds 777...): oracle mean return {oracle.mean():.1f}; "
             f"{int((oracle < 200).sum())} of {episodes} below 200 (no hover phase)",
             f"{'model':>40} {'learnt mean':>11} {'overpaid >100':>13} {'mean |learnt - oracle|':>22}"]
    for c in checkpoints:
        learnt = model_returns(c, states)
        lines.append(f"{c[-40:]:>40} {learnt.mean():11.1f} {int((learnt - oracle > 100).sum()):13d} "
                     f"{np.abs(learnt - oracle).mean():22.1f}")
    return "\n".join(lines)


def agent_timeline(agent: Path, agent_checkpoint: str, episodes: int, shown: int = 2, window: int = 25) -> str:
    """Where along its greedy episodes the model pays the agent and the oracle does not: per
    `window` steps of the first `shown` episodes, the lander's mean x, y and leg contacts, the
    oracle's pad count, and the oracle's and the model's pay (issue 31: an agent that hopped after
    its 50 pad steps and sat down again, paid ~1.5 a step by the model, ~0.1 by the oracle)."""
    from nmrm_ros.mil import OnlineRewardModel, load_checkpoint
    from nmrm_ros.oracles import make_oracle

    states, _ = agent_episodes(agent, agent_checkpoint, episodes)
    model, _ = load_checkpoint(agent_checkpoint, task="lunar_lander")
    online = OnlineRewardModel(model)
    oracle = make_oracle("lunar_lander")
    lines = [f"# {agent.name}: its first {shown} greedy episodes per {window} steps, paid by the oracle and by "
             f"{Path(agent_checkpoint).name}",
             f"{'ep':>2} {'t':>4} {'x':>6} {'y':>6} {'legs':>9} {'pad':>4} {'oracle':>7} {'model':>7}"]
    for i, s in enumerate(states[:shown]):
        learnt = online.episode_rewards(s)
        labels = oracle.label(s[None])
        pad = np.asarray(labels.hidden[0]).reshape(len(s), -1)[:, 0]
        paid = labels.rewards[0]
        for a in range(0, len(s), window):
            w = slice(a, a + window)
            lines.append(f"{i:2d} {a:4d} {s[w, 0].mean():6.2f} {s[w, 1].mean():6.2f} "
                         f"{s[w, 6].mean():4.1f}/{s[w, 7].mean():4.1f} {int(pad[min(a + window, len(s)) - 1]):4d} "
                         f"{paid[w].sum():7.1f} {learnt[w].sum():7.1f}")
        lines.append(f"{i:2d} {'all':>4} {'':>6} {'':>6} {'':>9} {'':>4} {paid.sum():7.1f} {learnt.sum():7.1f}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoints", nargs="+", required=True, help="Lunar Lander MIL checkpoints (.pt)")
    parser.add_argument("--agent", type=Path, default=None, help="an agent's directory (policy.zip, agent.json)")
    parser.add_argument("--agent-checkpoint", default=None,
                        help="--agent: the checkpoint it learnt on (default: the first of --checkpoints)")
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()
    for c in args.checkpoints:
        if not Path(c).is_file():
            parser.error(f"no checkpoint {c}")
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    if args.agent is not None and not (args.agent / "policy.zip").is_file():
        parser.error(f"no policy.zip in {args.agent}")
    import torch

    torch.set_num_threads(1)
    print("# command: .venv/bin/python bench/lunar_lander_thresholds.py " + " ".join(sys.argv[1:]), flush=True)
    print(probe_table(args.checkpoints), flush=True)
    if args.agent is not None:
        print(agent_table(args.agent, args.agent_checkpoint or args.checkpoints[0], args.checkpoints, args.episodes))
        print(agent_timeline(args.agent, args.agent_checkpoint or args.checkpoints[0], args.episodes), flush=True)


if __name__ == "__main__":
    main()
