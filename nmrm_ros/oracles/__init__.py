"""Ground-truth labellers (oracles) of every task and toy dataset. Plain numpy, no ROS."""

from __future__ import annotations

from .base import Oracle, OracleLabels, OracleTracker
from .lunar_lander import LunarLanderOracle
from .navigation import ChargerOracle, KeyOracle, MovingOracle, TimerOracle
from .toy import DialOracle, PushSwitchOracle, ToggleSwitchOracle

ORACLES: dict[str, type[Oracle]] = {
    "timer": TimerOracle,
    "moving": MovingOracle,
    "key": KeyOracle,
    "charger": ChargerOracle,
    "lunar_lander": LunarLanderOracle,
    "toggle_switch": ToggleSwitchOracle,
    "push_switch": PushSwitchOracle,
    "dial": DialOracle,
}


def make_oracle(task: str) -> Oracle:
    """The oracle of a task or toy dataset; ValueError naming the known ones otherwise."""
    try:
        return ORACLES[task]()
    except KeyError:
        raise ValueError(f"no oracle for {task!r}; known: {', '.join(ORACLES)}") from None


__all__ = ["Oracle", "OracleLabels", "OracleTracker", "ORACLES", "make_oracle"]
