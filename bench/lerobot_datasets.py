"""LeRobot datasets: export and import throughput, and LeRobot's own loader on our export.

    .venv/bin/python bench/lerobot_datasets.py throughput [--episodes 2000] [--camera-episodes 200]
    .venv/bin/python bench/lerobot_datasets.py loader [--rebuild-venv]

**throughput**: steps/s and MB per 1000 steps, without and with a camera. Without a camera: a 2000-episode screened Key bag (data seed 20) exported with a Key reward model
(`--checkpoint`, default the time-to-accuracy bench's data-seed-20 model; the learnt reward and
served state computed per step, as served) and imported back. With a camera: random-policy episodes
of gym:CartPole-v1 (seed 0) with every step's frame rendered and JPEG-encoded at 240 pixels wide,
as env_sim records them (render:=true), exported as H.264 video and imported back (frames decoded
and re-encoded as JPEG). A pixel task: the same Key episodes rendered as 32x32x3 image states
(`key_pixels`, data seed 20; `--pixel-episodes`), whose pixels go out as the state column. Wall time of the library calls `export_lerobot` / `import_lerobot`, one
run each; sizes are the directories' bytes. Bags are kept in runs/lerobot_bench/ between runs. Output: bench/results/lerobot/throughput.txt.

**loader**: LeRobot's own loader on our export (episodes, frames, the reward column and camera
frames equal). LeRobot 0.4.4 pins torch < 2.11, so it runs in a venv of its own, `build/lerobot_venv`, made here
with one command (`--rebuild-venv` remakes it): lerobot==0.4.4 with torch 2.9.1 and torchvision
0.24.1 (inside its pins; PyPI's x86_64 builds, CUDA included: ~3 GB of downloads), pandas < 3.
The freeze of that venv is written beside the results. Two exports are read, with
`LeRobotDataset(repo_id, root=DIR, video_backend="pyav")`, offline (HF_HUB_OFFLINE=1), by
`bench/lerobot_reader.py` in that venv: a 200-episode Key export with a reward model's next.reward
and served state, and a 20-episode CartPole export with rendered frames as H.264 video (three
frames per episode decoded by LeRobot, against ours decoded by PyAV). Output:
bench/results/lerobot/loader.txt.
"""

from __future__ import annotations

import installed_check  # noqa: F401  (exits if the installed nmrm_ros is not the source tree's)
import argparse
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WORK = ROOT / "runs" / "lerobot_bench"
CAMERA_TASK = "gym:CartPole-v1"
VENV = ROOT / "build" / "lerobot_venv"
PINS = ["lerobot==0.4.4", "torch==2.9.1", "torchvision==0.24.1", "pandas<3"]
RESULTS = ROOT / "bench" / "results" / "lerobot"


def size_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file()) / 1e6


def key_bag(episodes: int) -> Path:
    from nmrm_ros.bags.episodes import write_dataset_bag
    from nmrm_ros.datasets import generate_screened

    path = WORK / f"key_{episodes}"
    if not path.exists():
        write_dataset_bag(generate_screened("key", episodes, seed=20), path)
    return path


def pixel_bag(episodes: int) -> Path:
    """A pixel Key bag: the screened Key episodes of data seed 20 rendered (32x32x3 states)."""
    from nmrm_ros.bags.episodes import write_dataset_bag
    from nmrm_ros.tasks.pixel_navigation import pixel_dataset
    from nmrm_ros.datasets import generate_screened

    path = WORK / f"key_pixels_{episodes}"
    if not path.exists():
        write_dataset_bag(pixel_dataset(generate_screened("key", episodes, seed=20), "key_pixels"), path)
    return path


def camera_bag(episodes: int) -> Path:
    """Random CartPole episodes with each step's rendered frame, as env_sim records them."""
    from nmrm_ros.bags.episodes import BASE_TIME_NS, STEP_NS, T_ACT, T_OBS, TOPIC, stamped_header
    from nmrm_ros.bags.writer import BagWriter
    from nmrm_ros.tasks import make_env
    from nmrm_ros.tasks.frames import encode_frame, frame_id

    path = WORK / f"cartpole_frames_{episodes}"
    if path.exists():
        return path
    env = make_env(CAMERA_TASK, render=True)
    rng = np.random.default_rng(0)
    t = BASE_TIME_NS

    with BagWriter(path) as bag:
        for e in range(episodes):
            obs, _ = env.reset(seed=e)
            step, done, term = 0, False, False
            while True:
                bag.write_dict("/nmrm/frame", "sensor_msgs/msg/CompressedImage", {
                    "header": stamped_header(t, frame_id(e, step)), "format": "jpeg",
                    "data": encode_frame(env.render(), width=240)}, t)
                final = done
                bag.write_dict(TOPIC[T_OBS], T_OBS, {"header": stamped_header(t, CAMERA_TASK), "task": CAMERA_TASK,
                                                     "episode": e, "step": step,
                                                     "state": [float(x) for x in obs], "terminated": final and term,
                                                     "truncated": final and not term}, t)
                if final:
                    break
                action = int(rng.integers(env.action_space.n))
                bag.write_dict(TOPIC[T_ACT], T_ACT, {"header": stamped_header(t), "episode": e, "step": step,
                                                     "action": [float(action)]}, t + 1)
                obs, _, term, trunc, _ = env.step(action)
                done = term or trunc
                step += 1
                t += STEP_NS
            t += STEP_NS
    env.close()
    return path


def checkpoint(path: str | None) -> str:
    if path:
        return path
    default = ROOT / "runs/time_to_accuracy/head_1207/key_s20.pt"
    if default.exists():
        return str(default)
    from nmrm_ros.datasets import generate_screened
    from nmrm_ros.mil import load_train_config
    from nmrm_ros.mil.pipeline import fit

    return str(fit(generate_screened("key", 500, seed=21), "csc_lstm", load_train_config("key", max_epochs=5),
                   out=WORK / "key_model", progress=False).checkpoint)


def measure(label: str, bags: list, ckpt: str | None) -> str:
    from nmrm_ros.lerobot import export_lerobot, import_lerobot

    out, back = WORK / f"{label}_lerobot", WORK / f"{label}_back"
    for p in (out, back):
        shutil.rmtree(p, ignore_errors=True)
    t0 = time.perf_counter()
    exp = export_lerobot(bags, out, checkpoint=ckpt)
    t1 = time.perf_counter()
    imp = import_lerobot(out, back)
    t2 = time.perf_counter()
    steps = exp.frames
    return (f"{label:24s} {exp.episodes:6d} episodes {steps:8d} steps | bag {size_mb(bags[0]) * 1000 / steps:7.3f} "
            f"MB/1000 steps | export {steps / (t1 - t0):8.0f} steps/s, dataset {size_mb(out) * 1000 / steps:7.3f} "
            f"MB/1000 steps ({exp.camera}) | import {steps / (t2 - t1):8.0f} steps/s, bag "
            f"{size_mb(back) * 1000 / steps:7.3f} MB/1000 steps ({imp.frames} frames)")





def make_venv(rebuild: bool) -> Path:
    python = VENV / "bin" / "python"
    if rebuild:
        shutil.rmtree(VENV, ignore_errors=True)
    if not python.exists() or subprocess.run([python, "-c", "import lerobot"], capture_output=True).returncode:
        subprocess.run(["python3.11", "-m", "venv", str(VENV)], check=True)
        subprocess.run([python, "-m", "pip", "install", "-q", "--disable-pip-version-check", *PINS], check=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    freeze = subprocess.run([python, "-m", "pip", "freeze"], capture_output=True, text=True, check=True).stdout
    (RESULTS / "lerobot_venv_freeze.txt").write_text(freeze)
    return python


def exports() -> list:
    """(label, dataset dir) of the two exports read by LeRobot."""
    from nmrm_ros.lerobot import export_lerobot

    out = []
    for label, bags, ckpt in (("key200", [key_bag(200)], checkpoint(None)), ("cartpole20", [camera_bag(20)], None)):
        path = WORK / f"loader_{label}"
        shutil.rmtree(path, ignore_errors=True)
        export_lerobot(bags, path, checkpoint=ckpt)
        out.append((label, path))
    return out


def compare(label: str, path: Path, theirs: dict) -> str:
    import pyarrow.parquet as pq

    from nmrm_ros.lerobot.video import read_frames

    meta = json.loads(str(theirs["meta"]))
    info = json.loads((path / "meta/info.json").read_text())
    ours = pq.read_table(sorted((path / "data").glob("*/*.parquet"))[0])
    lines = [f"{label}: LeRobot {meta['lerobot']} read {meta['episodes']} episodes, {meta['frames']} frames at "
             f"{meta['fps']} fps (ours: {info['total_episodes']}, {info['total_frames']}, {info['fps']}); "
             f"task {meta['task']!r}; cameras {meta['cameras']}"]
    for key in meta["keys"]:
        mine = np.asarray(ours.column(key).to_pylist(), dtype=np.float64).reshape(len(ours), -1)
        got = np.asarray(theirs[key.replace(".", "_")], dtype=np.float64).reshape(len(ours), -1)
        lines.append(f"  {key:32s} equal: {bool(np.array_equal(mine, got))} (max |diff| {np.abs(mine - got).max():.3g})")
    if meta["cameras"]:
        cam = meta["cameras"][0]
        frames = [rgb for _, rgb in read_frames(next((path / "videos" / cam).glob("*/*.mp4")))]
        picked = theirs["picked"]
        diffs = [np.abs(theirs["frames"][i].transpose(1, 2, 0) * 255.0 - frames[int(j)]).max()
                 for i, j in enumerate(picked)]
        lines.append(f"  {cam}: {len(picked)} frames decoded by LeRobot, max |diff| against PyAV's "
                     f"{max(diffs):.2f} of 255")
    return "\n".join(lines)


def loader(args) -> None:
    python = make_venv(args.rebuild_venv)
    WORK.mkdir(parents=True, exist_ok=True)
    lines = []
    for label, path in exports():
        npz = WORK / f"loader_{label}.npz"
        env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HOME": str(WORK / "hf_home")}
        env.pop("PYTHONPATH", None)
        res = subprocess.run([python, ROOT / "bench" / "lerobot_reader.py", path, npz], capture_output=True,
                             text=True, env=env)
        if res.returncode:
            lines.append(f"{label}: LeRobot failed to load it:\n{res.stderr[-2000:]}")
            continue
        lines.append(compare(label, path, dict(np.load(npz))))
    text = "\n".join(lines)
    print(text)
    (RESULTS / "loader.txt").write_text(f"# .venv/bin/python bench/lerobot_datasets.py loader\n{text}\n")


def throughput(args) -> None:
    WORK.mkdir(parents=True, exist_ok=True)
    lines = [measure("key (with next.reward)", [key_bag(args.episodes)], checkpoint(args.checkpoint)),
             measure("cartpole (camera)", [camera_bag(args.camera_episodes)], None),
             measure("key_pixels (image state)", [pixel_bag(args.pixel_episodes)], None)]
    text = "\n".join(lines)
    print(text)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "throughput.txt").write_text(
        f"# .venv/bin/python bench/lerobot_datasets.py throughput --episodes {args.episodes} "
        f"--camera-episodes {args.camera_episodes} --pixel-episodes {args.pixel_episodes}\n{text}\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    tp = sub.add_parser("throughput", help="export and import steps/s and sizes")
    tp.add_argument("--episodes", type=int, default=2000, help="Key episodes (no camera)")
    tp.add_argument("--camera-episodes", type=int, default=200, help="CartPole episodes with frames")
    tp.add_argument("--pixel-episodes", type=int, default=200, help="pixel Key episodes (the state is an image)")
    tp.add_argument("--checkpoint", default=None, help="a Key reward model for next.reward")
    lp = sub.add_parser("loader", help="LeRobot's LeRobotDataset on our export, in its own venv")
    lp.add_argument("--rebuild-venv", action="store_true")
    args = ap.parse_args()
    (throughput if args.command == "throughput" else loader)(args)


if __name__ == "__main__":
    main()
