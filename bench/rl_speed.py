"""Wall time of one DQN learning run without ROS (gymnasium wrapper) and through the ROS graph.

    .venv/bin/python bench/rl_speed.py --checkpoint runs/reproduce_rl/models/key_csc_lstm_seed0

Both sides train the same agent (double DQN, config/rl.yaml, an update every step) on the same
CSC model's reward for the same episodes (seed 0), and are timed the same way: from the start
of the process that learns to the saved policy, each run alone on the machine, one after the
other.
- wrapper: `nmrm rl train --reward model` (one process);
- graph: env_sim -> reward_model -> agent policy:=learn (three node processes, `nmrm launch` of
  learn.launch.yaml without the labeller and recorder: the same work as the wrapper run), and
  the full learn.launch.yaml (labeller and recorder too) with --full.
Prints steps/s and the graph/wrapper ratio (target: at most 1.5x).
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
    {{name: save_every, value: 0}}, {{name: log_every, value: 50}}, {{name: exit_with_upstream, value: true}}]}}
"""


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
    rows.append(("wrapper (nmrm rl train, 1 process)", t))
    print(f"wrapper: {t:.1f} s", flush=True)

    launch = work / "minimal.launch.yaml"
    launch.write_text(MINIMAL_LAUNCH.format(episodes=args.episodes))
    t, _ = timed([BIN / "nmrm", "launch", launch, f"checkpoint:={args.checkpoint}", f"out:={work / 'graph'}"], env)
    rows.append(("graph (env_sim, reward_model, agent)", t))
    print(f"graph: {t:.1f} s", flush=True)

    if args.full:
        t, _ = timed([BIN / "nmrm", "launch", REPO / "launch_scripts" / "learn.launch.yaml", "task:=key",
                      f"episodes:={args.episodes}", "mode:=model", f"checkpoint:={args.checkpoint}",
                      f"out:={work / 'full'}", "save_every:=0"], env)
        rows.append(("learn.launch.yaml (+ labeller, recorder)", t))
        print(f"full launch: {t:.1f} s", flush=True)

    base = rows[0][1]
    print(f"\n# {args.episodes} episodes = {steps} steps of double DQN (update every step), Key, CSC reward, "
          f"seed 0; {os.cpu_count()} cores")
    for name, t in rows:
        print(f"{name:44s} {t:7.1f} s  {steps / t:6.0f} steps/s  {t / base:4.2f}x")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
