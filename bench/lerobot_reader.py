"""Run by bench/lerobot_datasets.py loader in LeRobot's own venv (not ours): load a dataset directory with
LeRobot's `LeRobotDataset`, offline, and save what it gives. No nmrm_ros import.

    build/lerobot_venv/bin/python bench/lerobot_reader.py DATASET OUT.npz [--frames-per-episode 3]
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("out")
    ap.add_argument("--frames-per-episode", type=int, default=3)
    args = ap.parse_args()
    import lerobot
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("local/nmrm_export", root=args.dataset, video_backend="pyav")
    keys = [k for k in ("observation.state", "action", "next.reward", "observation.reward_model_state", "next.done")
            if k in ds.features]
    table = ds.hf_dataset.with_format("numpy")
    arrays = {k.replace(".", "_"): np.asarray(table[k]) for k in keys}
    cameras = list(ds.meta.video_keys)
    picked, frames = [], []
    for e in range(ds.num_episodes):
        start = int(ds.meta.episodes[e]["dataset_from_index"])
        length = int(ds.meta.episodes[e]["length"])
        for j in np.linspace(0, length - 1, min(length, args.frames_per_episode)).round().astype(int):
            item = ds[start + int(j)]
            picked.append(start + int(j))
            if cameras:
                frames.append(item[cameras[0]].numpy())
            if e == 0 and j == 0:
                task = item["task"]
    np.savez_compressed(args.out, **arrays, picked=np.array(picked), frames=np.array(frames),
                        meta=np.array(json.dumps({"lerobot": lerobot.__version__, "episodes": ds.num_episodes,
                                                  "frames": ds.num_frames, "fps": ds.fps, "cameras": cameras,
                                                  "task": task, "keys": keys})))


if __name__ == "__main__":
    main()
