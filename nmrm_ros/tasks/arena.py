"""The arena of a task: its bounds, its zones and which state dimensions are the position (no ROS).

Shared by the labelling page (drawn under an episode's path) and the visualizer node (markers).
"""

from __future__ import annotations


def arena(task: str) -> dict | None:
    """What is drawn under a path: {"bounds": [x0, x1, y0, y1] or None, "zones": [[x0, x1, y0, y1,
    kind], ...], "xy": [i, j] (the state dimensions of the position)}; None for a task of the
    user's without `xy` (the page then plots each state dimension over time) and for a task whose
    state is an image (the page shows its frames). A task of the
    user's module may say more with a module attribute `ARENA = {"bounds": [...], "zones": [...]}`
    (e.g. nmrm_ros.robots.delivery)."""
    from . import task_info

    if task_info(task).image_shape:
        return None  # an image state: people see its frames; its pixels are not a path
    if ":" in task:
        import importlib

        from .gym_task import parse_task_spec

        spec = parse_task_spec(task)
        if spec.xy is None:
            return None
        own = {}
        if spec.kind == "import":
            own = getattr(importlib.import_module(spec.target.split(":")[0]), "ARENA", None) or {}
        return {"bounds": own.get("bounds"), "zones": [list(z) for z in own.get("zones", [])], "xy": list(spec.xy)}
    if task == "lunar_lander":
        return {"bounds": [-1.5, 1.5, -0.2, 1.6], "zones": [[-0.2, 0.2, -0.05, 0.0, "pad"]],
                "xy": [0, 1]}
    from .navigation import CHARGE_Y_MAX, KEY_ZONE, SPAWN_ZONES, TREASURE_ZONE

    def zone(z, kind):
        return [z.x_min, z.x_max, z.y_min, z.y_max, kind]

    zones = [zone(z, "spawn") for z in SPAWN_ZONES]
    zones.append([0.0, 1.0, TREASURE_ZONE.y_min, TREASURE_ZONE.y_max, "treasure row"] if task == "moving"
                 else zone(TREASURE_ZONE, "treasure"))
    if task == "key":
        zones.append(zone(KEY_ZONE, "key"))
    if task == "charger":
        zones.append([0.0, 1.0, 0.0, CHARGE_Y_MAX, "charger"])
    return {"bounds": [0.0, 1.0, 0.0, 1.0], "zones": zones, "xy": [0, 1]}
