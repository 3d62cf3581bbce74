"""Wall time of one DQN learning run without ROS (gymnasium wrapper) and through the ROS graph.

    .venv/bin/python bench/rl_speed.py --checkpoint runs/reproduce_rl/models/key_csc_lstm_seed0

Both sides train the same agent (double DQN, config/rl.yaml, an update every step) on the same
CSC model's reward for the same episodes (seed 0), and are timed the same way: from the start
of the process that learns to the saved policy, each run alone on the machine, one after the
other.
- wrapper: `nmrm rl train --reward model` (one process);
- graph: env_sim -> reward_model -> agent policy:=learn (three node processes, `nmrm launch` of
  learn.launch.yaml without the labeller and recorder: the same work as the wrapper run), with the
  agent's default `overlap_training:=true` (each gradient step runs while the graph computes the
  next state) and with `:=false` (SB3's order, as the wrapper); the full learn.launch.yaml
  (labeller and recorder too) with --full.
Prints steps/s, the graph/wrapper ratio (target: at most 1.3x), each run's final oracle return
(mean of its last 50 episodes) and the agent's per-step split (waiting for the graph vs learning).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def timed(cmd: list, env: dict) -> tuple[float, str]:
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(map(str, cmd))} failed ({res.returncode}):\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}")
    return seconds, res.stdout + res.stderr


MINIMAL_LAUNCH = """launch:
- arg: {{name: checkpoint}}
- arg: {{name: out}}
- node: {{pkg: nmrm_ros, exec: env_sim, name: env_sim, param: [{{name: task, value: key}},
    {{name: episodes, value: {episodes}}}, {{name: seed, value: 0}}, {{name: wait_for_nodes, value: [reward_model]}}]}}
- node: {{pkg: nmrm_ros, exec: reward_model, name: reward_model, param: [{{name: task, value: key}},
    {{name: checkpoint, value: $(var checkpoint)}}, {{name: exit_with_upstream, value: true}}]}}
- node: {{pkg: nmrm_ros, exec: agent, name: agent, param: [{{name: task, value: key}}, {{name: policy, value: learn}},
    {{name: episodes, value: {episodes}}}, {{name: seed, value: 0}}, {{name: out, value: $(var out)}},
    {{name: save_every, value: 0}}, {{name: log_every, value: 50}}, {{name: exit_with_upstream, value: true}},
    {{name: overlap_training, value: {overlap}}}]}}
"""


def final_return(out: Path, checkpoint: str) -> float:
    """The saved policy's greedy oracle return on 50 new episodes (`nmrm rl evaluate`'s)."""
    import numpy as np

    from nmrm_ros.rl import evaluate_agent

    return float(np.mean(evaluate_agent(out / "policy.zip", "key", checkpoint, episodes=50).returns))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", required=True, help="a Key CSC checkpoint")
    parser.add_argument("--episodes", type=int, default=400)
    parser.add_argument("--full", action="store_true", help="also time the full learn.launch.yaml")
    args = parser.parse_args()
    env = dict(os.environ)
    work = Path(tempfile.mkdtemp(prefix="rl_speed_"))
    steps = args.episodes * 100
    rows = []

    t, _ = timed([BIN / "nmrm", "rl", "train", "--task", "key", "--reward", "model", "--checkpoint",
                  args.checkpoint, "--episodes", str(args.episodes), "--seed", "0", "--out", work / "wrapper"], env)
    rows.append(("wrapper (nmrm rl train, 1 process)", t, final_return(work / "wrapper", args.checkpoint), ""))
    print(f"wrapper: {t:.1f} s", flush=True)

    for overlap in ("true", "false"):
        launch = work / f"minimal_{overlap}.launch.yaml"
        launch.write_text(MINIMAL_LAUNCH.format(episodes=args.episodes, overlap=overlap))
        out = work / f"graph_{overlap}"
        t, log = timed([BIN / "nmrm", "launch", launch, f"checkpoint:={args.checkpoint}", f"out:={out}"], env)
        split = next((line.split("; per step ")[1] for line in log.splitlines() if "; per step " in line), "")
        name = "graph, overlap_training" if overlap == "true" else "graph, SB3's order"
        rows.append((name, t, final_return(out, args.checkpoint), split))
        print(f"{name}: {t:.1f} s ({split})", flush=True)

    if args.full:
        t, _ = timed([BIN / "nmrm", "launch", REPO / "launch_scripts" / "learn.launch.yaml", "task:=key",
                      f"episodes:={args.episodes}", "mode:=model", f"checkpoint:={args.checkpoint}",
                      f"out:={work / 'full'}", "save_every:=0"], env)
        rows.append(("learn.launch.yaml (+ labeller, recorder)", t, float("nan"), ""))
        print(f"full launch: {t:.1f} s", flush=True)

    base = rows[0][1]
    print(f"\n# {args.episodes} episodes = {steps} steps of double DQN (update every step), Key, CSC reward, "
          f"seed 0; {os.cpu_count()} cores; greedy = the policy's oracle return on 50 new episodes")
    for name, t, final, split in rows:
        print(f"{name:44s} {t:7.1f} s  {steps / t:6.0f} steps/s  {t / base:4.2f}x  greedy {final:6.2f}  {split}")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
