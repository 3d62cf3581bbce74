"""Rendered frames: bag size and throughput with env_sim render:=true, against render:=false.

    .venv/bin/python bench/frames.py --episodes 20

Real processes in a DDS domain of their own: env_sim (CartPole, seed 0), a random agent acting on
observations, and the recorder. Reported per setting: steps, frames, bag size, env_sim's steps/s
(its own log) and the recorder's messages/s (its own count and clock).
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXE = Path(os.environ.get("NMRM_VENV", ROOT / ".venv")) / "lib" / "nmrm_ros"
TASK = "gym:CartPole-v1"


def node(name: str, **params) -> subprocess.Popen:
    args = [str(EXE / name), "--ros-args"]
    for k, v in params.items():
        args += ["-p", f"{k}:={v}"]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def run(episodes: int, render: bool, width: int, work: Path, domain: int) -> dict:
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    bag = work / f"bag_render_{render}"
    rec = node("recorder", output=bag, exit_with_upstream="true")
    agent = node("agent", task=TASK, observe="observation", exit_with_upstream="true")
    sim = node("env_sim", task=TASK, episodes=episodes, render=str(render).lower(), render_width=width,
               wait_for_nodes="[recorder, agent]", wait_for_subscribers=2)
    out = {p: p.communicate(timeout=600)[0] for p in (sim, agent, rec)}
    done = re.search(r"done: \d+ episodes, (\d+) steps in ([\d.]+) s \((\d+) steps/s\)", out[sim])
    frames = re.search(r"(\d+) frame\(s\), ([\d.]+) MB", out[sim])
    rate = re.search(r"(\d+) messages written in ([\d.]+) s \((\d+) msg/s\)", out[rec])
    size = sum(f.stat().st_size for f in bag.rglob("*") if f.is_file())
    return {"render": render, "steps": int(done.group(1)), "env_steps_per_s": int(done.group(3)),
            "frames": int(frames.group(1)) if frames else 0, "bag_mb": size / 1e6,
            "recorder_msgs_per_s": int(rate.group(3)) if rate else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--width", type=int, default=240)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="nmrm_frames_"))
    try:
        print(f"# bench/frames.py --episodes {args.episodes} --width {args.width}: {TASK}, seed 0, random agent")
        base = None
        for i, render in enumerate((False, True)):
            r = run(args.episodes, render, args.width, work, 180 + i)
            base = r["bag_mb"] if base is None else base
            per_frame = (f", +{1e3 * (r['bag_mb'] - base) / r['frames']:.2f} KB of bag per frame over render "
                         f"false (MCAP chunks compressed)" if r["frames"] else "")
            print(f"render {str(render).lower():5s}: {r['steps']} steps, {r['frames']} frames, bag {r['bag_mb']:.2f} MB"
                  f"{per_frame}; env_sim {r['env_steps_per_s']} steps/s; recorder {r['recorder_msgs_per_s']} msg/s")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
