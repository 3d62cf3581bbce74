"""Run in LeRobot's own venv (bench/lerobot_datasets.py loader makes it): write a small dataset with LeRobot's
own `LeRobotDataset.create` / `add_frame` / `save_episode` / `finalize`, offline, as the test
fixture tests/fixtures/lerobot_v30_small (3 episodes of 12, 9 and 15 frames; a 2-D state, a 1-D
action, next.reward, one 32x48 camera as LeRobot's default AV1 video; numpy seed 0). No nmrm_ros import.

    build/lerobot_venv/bin/python bench/lerobot_fixture.py tests/fixtures/lerobot_v30_small
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np


def main() -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = Path(sys.argv[1])
    shutil.rmtree(root, ignore_errors=True)
    features = {
        "observation.state": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        "action": {"dtype": "float32", "shape": (1,), "names": ["push"]},
        "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
        "observation.images.top": {"dtype": "video", "shape": (32, 48, 3), "names": ["height", "width", "channels"]},
    }
    ds = LeRobotDataset.create("local/lerobot_v30_small", fps=10, root=root, features=features, use_videos=True)
    rng = np.random.default_rng(0)
    for length in (12, 9, 15):
        for j in range(length):
            y, x = np.mgrid[0:32, 0:48]
            image = np.stack([x * 5, y * 7, np.full_like(x, 20 * j)], -1).clip(0, 255).astype(np.uint8)
            ds.add_frame({"observation.state": rng.normal(size=2).astype(np.float32),
                          "action": rng.normal(size=1).astype(np.float32),
                          "next.reward": np.array([float(j == length - 1)], np.float32),
                          "observation.images.top": image, "task": "push the block to the line"})
        ds.save_episode()
    ds.finalize()
    print(f"wrote {root}: {ds.meta.total_episodes} episodes, {ds.meta.total_frames} frames")


if __name__ == "__main__":
    main()
