"""Ground-truth labellers (oracles) of every task and toy dataset, and a user's own oracle
function (`function_oracle`). Plain numpy, no ROS."""

from __future__ import annotations

from .base import Oracle, OracleLabels, OracleTracker
from .function_oracle import FunctionOracle, OracleError, is_oracle_spec
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


def make_oracle(task: str, oracle: str = "") -> Oracle:
    """The oracle of a task or toy dataset (a pixel task's: its state task's, which judges the
    privileged state), or (`oracle` = "<module>:<function>") a user's oracle function on `task`;
    ValueError (one line) if there is none."""
    if oracle:
        from ..tasks import task_info

        info = task_info(task)
        return FunctionOracle(oracle, task, info.privileged_size or info.state_size,
                              1 if info.discrete else info.action_size)
    if task not in ORACLES and ":" not in task:
        from ..tasks import TASKS, task_info

        if task in TASKS and task_info(task).pixels_of:  # a pixel task: its state task's, on the privileged state
            return ORACLES[task_info(task).pixels_of]()
    try:
        return ORACLES[task]()
    except KeyError:
        if ":" in task:
            raise OracleError(f"task {task!r} has no oracle of ours: give your own as --oracle "
                              f"<module>:<function> (oracle:=... for a node)") from None
        raise ValueError(f"no oracle for {task!r}; known: {', '.join(ORACLES)}") from None


__all__ = ["FunctionOracle", "Oracle", "OracleError", "OracleLabels", "OracleTracker", "ORACLES",
           "is_oracle_spec", "make_oracle"]
