"""`nmrm fleet`: N robots and one learner on this machine, from the fleet's two launch files.

Each robot i (namespace /robot<i>) runs `launch_scripts/fleet_robot.launch.yaml` (env_sim, reward
model, oracle labeller) with seed `seed + i * ROBOT_SEED_STRIDE`, so no two robots play the same
episode; `launch_scripts/fleet_learner.launch.yaml` runs the learning agent over all of them and
the fleet's recorder. On several machines, start the same launch files there instead
(docs/guide/several-machines.md).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from .launcher import LaunchError, NodeSpec, parse_launch_file, run

#: robot i's env_sim seed is seed + i * ROBOT_SEED_STRIDE (episode e of it: that + e)
ROBOT_SEED_STRIDE = 100_000


def _launch_file(name: str) -> Path:
    from ament_index_python.packages import get_package_share_directory

    from .ros.ament_paths import ensure_ament_prefix_path

    ensure_ament_prefix_path()
    return Path(get_package_share_directory("nmrm_ros")) / "launch_scripts" / name


def robot_namespaces(robots: int) -> list:
    """['/robot1', ..., '/robot<robots>']."""
    if robots < 1:
        raise LaunchError(f"a fleet has at least one robot, got {robots}")
    return [f"/robot{i + 1}" for i in range(robots)]


def fleet_nodes(robots: int, task: str = "key", episodes: int = 100, out: str | Path = "runs/fleet",
                mode: str = "oracle", checkpoint: str | Path = "", seed: int = 0, save_every: int = 50,
                learning_starts: int = -1, save_replay_buffer: bool = False) -> list:
    """The node commands of a fleet: `episodes` episodes per robot; the learner learns from all
    robots × episodes of them. Node names are prefixed with their robot's namespace."""
    namespaces = robot_namespaces(robots)
    params_dir = Path(tempfile.mkdtemp(prefix="nmrm_fleet_"))
    nodes: list = []
    for i, ns in enumerate(namespaces):
        for spec in parse_launch_file(_launch_file("fleet_robot.launch.yaml"), {
                "namespace": ns.lstrip("/"), "task": task, "episodes": str(episodes),
                "seed": str(seed + i * ROBOT_SEED_STRIDE), "mode": mode, "checkpoint": str(checkpoint or "")},
                params_dir=params_dir):
            nodes.append(NodeSpec(f"{ns.lstrip('/')}/{spec.name}", spec.cmd))
    nodes += parse_launch_file(_launch_file("fleet_learner.launch.yaml"), {
        "robots": "[" + ", ".join(namespaces) + "]", "task": task, "episodes": str(robots * episodes),
        "seed": str(seed), "out": str(out), "save_every": str(save_every),
        "learning_starts": str(learning_starts), "save_replay_buffer": str(save_replay_buffer).lower()},
        params_dir=params_dir)
    return nodes


def run_fleet(robots: int, grace: float = 10.0, **kwargs) -> int:
    """Run `fleet_nodes(robots, **kwargs)` until every node has exited; the launcher's exit code."""
    return run(fleet_nodes(robots, **kwargs), grace=grace)
