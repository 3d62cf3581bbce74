"""Why an agent on a model of comparisons earns less than one on a model of return labels: the two
models judged on the agents' own episodes.

    .venv/bin/python bench/preference_agents.py --task key --seed 1
    .venv/bin/python bench/preference_agents.py --task key --seed 1 --mapped-agent   # + ~2-5 min

Needs the models and agents of `bench/preferences.py --rl` (CSC models of 4000 comparisons of a
perfect teacher and of 4000 return labels, data seed r; agent seed r) in runs/preferences/<tag>/.

1. Scale: each model's per-step rewards fitted to the oracle's, r' = a r + b, on the 2000 held-out
   episodes of bench/preferences.py (a comparison model's a and b are free: comparisons fix the
   returns only up to them); and the range of the true returns the models were trained on.
2. The agents' episodes: 50 greedy episodes of each agent (episode seeds 10^8 + i, as `nmrm rl
   evaluate`), their oracle return, and what each model pays for them mapped to oracle units,
   (r' - b) / a, split into the steps the oracle pays (r > 0) and the steps it pays nothing.
3. `--mapped-agent`: an agent (same seed and settings) on the comparison model with its rewards
   mapped to oracle units (the reward head's last layer scaled by 1/a and shifted by -b/a; the
   served state is unchanged): if the scale were the cause, this agent would earn what the
   return-label agent earns.

Writes bench/results/preferences/<tag>/agents_diagnosis_<task>_s<r>.txt (and, with
--mapped-agent, the agent's curve in bench/results/preferences/<tag>/agents/<name>_mapped/).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import torch

from nmrm_ros.datasets.cache import cached_dataset

ROOT = Path(__file__).resolve().parents[1]
# what bench/preferences.py --rl wrote (its file layout and run names), read here
RESULTS = ROOT / "bench" / "results" / "preferences"
MODELS = ROOT / "runs" / "preferences"
HELD_OUT_SEED, HELD_OUT_N = 999, 2000  # its held-out episodes
RL_N, FINAL_WINDOW = 4000, 50  # its agents' models: 4000 labels or comparisons; final return: last 50 episodes
EPISODES = 50


def run_name(task: str, arch: str, teacher: str, n: int, r: int) -> str:
    """bench/preferences.py's name of run (task, arch, teacher, n, data seed r)."""
    return f"{task}_{arch}_{teacher}_n{n}_s{r}"


def model_rewards(ens, states: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Per-step rewards (N, T) of the serving member on trajectories `states` (N, T, d)."""
    with torch.no_grad():
        out = ens(torch.as_tensor(states, dtype=torch.float32), torch.as_tensor(lengths))
    return out.rewards[int(ens.serving_member)].double().numpy()


def affine_fit(ens, held) -> tuple[float, float]:
    """(a, b) of the least-squares fit r' = a r + b over the held-out episodes' steps."""
    r_model = model_rewards(ens, held.states, held.lengths)
    mask = np.arange(held.states.shape[1])[None] < held.lengths[:, None]
    a, b = np.polyfit(held.rewards[mask], r_model[mask], 1)
    return float(a), float(b)


def greedy_episodes(agent_dir: Path, checkpoint: Path, task: str) -> tuple[np.ndarray, np.ndarray]:
    """(states (N, T, d) after each step, the oracle's per-step rewards (N, T)) of EPISODES greedy
    episodes of the agent on its own model."""
    from nmrm_ros.rl.evaluation import EVAL_SEED, load_agent, served_state_of
    from nmrm_ros.rl.wrappers import make_reward_env

    agent, meta = load_agent(agent_dir / "policy.zip")
    env = make_reward_env(task, "model", checkpoint, seed=EVAL_SEED,
                          served=served_state_of(agent, task, checkpoint, meta))
    d = env.unwrapped.observation_space.shape[0]
    states, oracle = [], []
    obs, _ = env.reset(seed=EVAL_SEED)
    for _ in range(EPISODES):
        xs, rs = [], []
        while True:
            obs, _, terminated, truncated, info = env.step(agent.predict(obs, deterministic=True)[0])
            xs.append(obs[:d].copy())
            rs.append(info["oracle_reward"])
            if terminated or truncated:
                break
        states.append(np.stack(xs))
        oracle.append(np.asarray(rs, np.float64))
        obs, _ = env.reset()
    if len({len(x) for x in states}) != 1:
        raise SystemExit("episodes of different lengths: this bench is for the fixed-length navigation tasks")
    return np.stack(states), np.stack(oracle)


def mapped_checkpoint(src: Path, dst: Path, a: float, b: float) -> Path:
    """A copy of the CSC checkpoint `src` whose per-step rewards are (r' - b) / a (every member)."""
    from nmrm_ros.mil import Run
    from nmrm_ros.mil.calibration import Calibration, calibrate

    run = Run.load(src)
    fit = Calibration(gain=np.full(run.model.members, a), bias=np.full(run.model.members, b), labels=0)
    return run.replace(model=calibrate(run.model, fit),
                       extra={**run.meta.extra, "mapped": {"from": str(src), "a": a, "b": b,
                                                           "rewards": "(r - b) / a"}}).save(dst)


def final_return(curve: Path) -> float:
    with open(curve) as f:
        returns = [float(row["oracle_return"]) for row in csv.DictReader(f)]
    return float(np.mean(returns[-FINAL_WINDOW:]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="key", choices=("key", "timer", "charger", "moving"))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--tag", default="head")
    parser.add_argument("--mapped-agent", action="store_true", help="train the agent on the mapped model (step 3)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    from nmrm_ros.mil import load_checkpoint

    task, r = args.task, args.seed
    names = {k: run_name(task, "csc_lstm", k, RL_N, r) for k in ("returns", "perfect")}
    ckpt = {k: MODELS / args.tag / "models" / f"{n}.pt" for k, n in names.items()}
    agents = {k: MODELS / args.tag / "agents" / n for k, n in names.items()}
    for path in [*ckpt.values(), *(a / "policy.zip" for a in agents.values())]:
        if not path.is_file():
            sys.exit(f"missing {path}: run bench/preferences.py --rl --tasks {task} --seeds {r} first")
    held = cached_dataset(task, HELD_OUT_N, HELD_OUT_SEED)
    train = cached_dataset(task, 5000, r)
    models = {k: load_checkpoint(p)[0] for k, p in ckpt.items()}
    fits = {k: affine_fit(m, held) for k, m in models.items()}
    lines = [f"# {task}, seed {r}: CSC models of {RL_N} return labels and of {RL_N} perfect comparisons "
             f"(data seed {r}) and the DQN agents on them (agent seed {r})",
             f"# command: .venv/bin/python bench/preference_agents.py --task {task} --seed {r}"
             f"{' --mapped-agent' if args.mapped_agent else ''}",
             f"true returns of the training episodes: median {np.median(train.returns):.1f}, 99th percentile "
             f"{np.percentile(train.returns, 99):.1f}, max {train.returns.max():.1f}"]
    for k, (a, b) in fits.items():
        lines.append(f"model of {k:8s}: per-step rewards on held-out steps r' = {a:.3f} r {b:+.3f}")
    episodes = {k: greedy_episodes(agents[k], ckpt[k], task) for k in agents}
    lines.append(f"{EPISODES} greedy episodes of each agent; what each model pays for them in oracle units "
                 f"((r' - b) / a): total, and per step where the oracle pays (r > 0) / pays nothing")
    lines.append(f"{'agent on model of':18s} {'oracle':>7s} {'paying steps':>13s} | "
                 + " | ".join(f"{'model of ' + k:>33s}" for k in models))
    for ak, (states, oracle) in episodes.items():
        pays = oracle > 0
        row = f"{ak:18s} {oracle.sum(1).mean():7.1f} {pays.sum(1).mean():13.1f} | "
        cells = []
        for mk, m in models.items():
            a, b = fits[mk]
            paid = (model_rewards(m, states, np.full(len(states), states.shape[1])) - b) / a
            on = paid[pays].mean() if pays.any() else float("nan")
            off = paid[~pays].sum() / len(states)
            cells.append(f"{paid.sum(1).mean():7.1f} ({on:5.2f}/paying step, {off:+6.2f} elsewhere)")
        lines.append(row + " | ".join(cells))
    if args.mapped_agent:
        from nmrm_ros.rl import train_agent

        name = f"{names['perfect']}_mapped"
        run_dir = MODELS / args.tag / "agents" / name
        curve = RESULTS / args.tag / "agents" / name / "curve.csv"
        if not curve.is_file():
            mapped = mapped_checkpoint(ckpt["perfect"], MODELS / args.tag / "models" / f"{name}.pt", *fits["perfect"])
            train_agent(task, "model", checkpoint=mapped, episodes=400, seed=r, out=run_dir, progress=False)
            curve.parent.mkdir(parents=True, exist_ok=True)
            curve.write_bytes((run_dir / "curve.csv").read_bytes())
        finals = {k: final_return(RESULTS / args.tag / "agents" / n / "curve.csv") for k, n in names.items()}
        lines.append(f"final oracle return (last {FINAL_WINDOW} of 400 episodes): on the model of returns "
                     f"{finals['returns']:.1f}, of comparisons {finals['perfect']:.1f}, of comparisons mapped to "
                     f"oracle units {final_return(curve):.1f}")
    text = "\n".join(lines)
    print(text)
    out = RESULTS / args.tag / f"agents_diagnosis_{task}_s{r}.txt"
    out.write_text(text + "\n")
    print(f"# written: {out.relative_to(RESULTS.parents[2])}")


if __name__ == "__main__":
    main()
