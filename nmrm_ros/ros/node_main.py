"""Entry-point helper shared by every node executable (the nodes are `node_base.NmrmNode`s).

Each node module declares its parameters once, in a `PARAMETERS` table of
`name -> Param(default, description)`; the node declares them from the table, and `--help` prints
it. `run_node` handles `--help`, rclpy init/shutdown, Ctrl-C and SIGTERM (a clean shutdown, so a
recorder closes its bag), and turns a `NodeError` raised at start-up (unknown task, missing
checkpoint...) into a one-line message and exit code 2.
"""

from __future__ import annotations

import argparse
import faulthandler
import signal
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable


@dataclass(frozen=True)
class Param:
    default: Any
    description: str
    minimum: float | None = None  # inclusive lower bound of a number (checked at start-up)


class NodeError(RuntimeError):
    """A configuration or input error that stops a node with a clear message."""


# From the end of spinning: close(), executor shutdown (<= 2 s), flush (<= 3 s), destroy, rclpy shutdown and interpreter
# exit together. ros2 launch escalates SIGINT to SIGTERM after 5 s and to SIGKILL 10 s later: past
# this limit, which comes first, every thread's stack is written to stderr (so a hang says where)
# and the process exits with code 1.
SHUTDOWN_LIMIT_S = 12.0
# The exit code of a node whose work was done (files closed, publishers flushed) but whose DDS
# teardown did not finish within SHUTDOWN_LIMIT_S: its stacks are on stderr. `nmrm launch` counts it
# as a clean exit and says so.
TEARDOWN_CUT_EXIT = int(signal.SIGALRM)  # 14
# An iteration of the spin loop (one callback) that takes longer than this writes every thread's
# stack to stderr (and the node goes on): a node that stops answering, even Ctrl-C (Python runs
# signal handlers only between callbacks), says where it is stuck.
SPIN_STALL_S = 60.0

_TYPE_NAMES = {bool: "a bool", int: "an integer", float: "a double", str: "a string"}


def _type_name(value) -> str:
    if isinstance(value, (list, tuple)):
        inner = _TYPE_NAMES.get(type(value[0]), "a value").split(" ", 1)[1] if value else "string"
        return f"an {inner} array" if inner[0] in "aeiou" else f"a {inner} array"
    return _TYPE_NAMES.get(type(value), type(value).__name__)


def _coerce(name: str, given, default):
    """`given` (an override of another type than `default`) as the declared type, where that is
    lossless and unambiguous: an integer for a double, one string for a string array."""
    if isinstance(default, float) and isinstance(given, int) and not isinstance(given, bool):
        return float(given)
    if isinstance(default, (list, tuple)) and all(isinstance(d, str) for d in default) and isinstance(given, str):
        return [given]
    raise NodeError(f"parameter {name!r} must be {_type_name(default)}, got {_type_name(given)} {given!r}")


def _descriptor(p: Param, dynamic_typing: bool = False):
    """The ROS ParameterDescriptor of `p`: description and, for a minimum, its range (shown by
    `ros2 param describe`, enforced by rclpy on declare and on set)."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    d = ParameterDescriptor(description=p.description, dynamic_typing=dynamic_typing)
    if p.minimum is not None and not dynamic_typing:
        if isinstance(p.default, float):
            d.floating_point_range = [FloatingPointRange(from_value=float(p.minimum), to_value=1e300, step=0.0)]
        else:
            d.integer_range = [IntegerRange(from_value=int(p.minimum), to_value=2**63 - 1, step=0)]
    return d


def _override(node, name: str):
    param = getattr(node, "_parameter_overrides", {}).get(name)
    return None if param is None else param.value


def _below_minimum(name: str, p: Param, value) -> str:
    return f"parameter {name!r} must be at least {p.minimum}, got {value!r}"


def _check_minimum(name: str, value, p: Param) -> None:
    if p.minimum is not None and value < p.minimum:
        raise NodeError(_below_minimum(name, p, value))


def declare_parameters(node, table: dict) -> dict:
    """Declare every parameter of `table` on `node`; return name -> value.

    An override of another type is converted where that is lossless (`start_delay:=4` -> 4.0,
    `wait_for_nodes:=agent` -> ['agent']), else refused with a NodeError, as is a number below its
    `minimum`. Overrides naming no parameter of the node are logged as a warning.
    """
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
    from rclpy.parameter import Parameter

    values = {}
    for name, p in table.items():
        try:
            try:
                node.declare_parameter(name, p.default, _descriptor(p))
                value = node.get_parameter(name).value
            except InvalidParameterTypeException:
                node.declare_parameter(name, p.default, _descriptor(p, dynamic_typing=True))
                value = _coerce(name, node.get_parameter(name).value, p.default)
                node.set_parameters([Parameter(name, value=value)])
                _check_minimum(name, value, p)
        except InvalidParameterValueException:  # below the descriptor's range
            raise NodeError(_below_minimum(name, p, _override(node, name))) from None
        values[name] = value
    unknown = sorted(set(getattr(node, "_parameter_overrides", {})) - set(table) - {"use_sim_time"})
    if unknown:
        node.get_logger().warning(f"ignoring unknown parameter(s) {unknown}; this node has {sorted(table)}")
    return values


def _help(prog: str, description: str, table: dict) -> str:
    lines = [f"usage: {prog} [--help] [--ros-args -p NAME:=VALUE ... --params-file FILE -r FROM:=TO]",
             "", description, "", "parameters (ros__parameters):"]
    for name, p in table.items():
        bound = "" if p.minimum is None else f", minimum {p.minimum}"
        lines.append(f"  {name:24s} {p.description} (default: {p.default!r}{bound})")
    return "\n".join(lines)


def _drain(executor, node, quiet: float = 0.2) -> None:
    """Spin until `node.messages_received` stayed unchanged for `quiet` s (or `node.drain_on_stop`
    s passed): the messages DDS received before the signal are taken, not dropped. A reliable
    publisher sees them acknowledged and may stop its side at once (a CI run: the recorder's bag
    lacked the last 12 of 51 acknowledged steps, SIGINT having arrived before its executor took
    them)."""
    start = last_change = time.monotonic()
    seen = node.messages_received
    while True:
        now = time.monotonic()
        if now - last_change >= quiet or now - start >= node.drain_on_stop:
            return
        executor.spin_once(timeout_sec=0.02)
        if node.messages_received != seen:
            seen, last_change = node.messages_received, time.monotonic()


def run_node(make_node: Callable, prog: str, description: str, table: dict,
             argv: list | None = None, on_spin: Callable | None = None) -> int:
    """Create the node with `make_node()` (an `NmrmNode` class: `node_base`) and spin it until
    shutdown or until it sets its `exit_code`; then `close()` it; returns the exit code.
    `NmrmNode.main` is the one caller (this module does not import `node_base`: no circle)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv if argv is None else argv)
    parser = argparse.ArgumentParser(prog=prog, add_help=False)
    parser.add_argument("-h", "--help", action="store_true")
    own, unknown = parser.parse_known_args(remove_ros_args(argv)[1:])
    if own.help:
        print(_help(prog, description, table))
        return 0
    if unknown:
        print(f"{prog}: unknown arguments {unknown} (node settings are ROS parameters: "
              f"--ros-args -p name:=value)", file=sys.stderr)
        return 2
    from .ament_paths import ensure_ament_prefix_path
    from .discovery import use_discovery_profile

    ensure_ament_prefix_path()  # our config files are found without `source`-ing anything
    use_discovery_profile()  # Fast DDS: re-announce every 0.25 s (see discovery.py)
    rclpy.init(args=argv, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = None
    executor = None
    code = 0
    stop = {"signal": None}

    def _stop(signum, frame):  # Ctrl-C and SIGTERM: leave the spin loop, then clean up below
        stop["signal"] = signum

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    try:
        node = make_node()  # an NmrmNode: NmrmNode.main(cls) is the one caller (tests/test_node_base.py)
        _warn_about_namesakes(node)
        executor = _executor()
        executor.add_node(node)
        armed = 0.0
        while rclpy.ok() and stop["signal"] is None and node.exit_code is None:
            now = time.monotonic()
            if now - armed > 1.0:  # re-arm the stall watchdog about once a second
                faulthandler.dump_traceback_later(SPIN_STALL_S, exit=False)
                armed = now
            executor.spin_once(timeout_sec=0.1)
        if stop["signal"] is not None and getattr(node, "drain_on_stop", 0.0) > 0:
            _drain(executor, node)
        code = node.exit_code or 0
    except NodeError as exc:
        print(f"[{prog}] error: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    finally:
        faulthandler.cancel_dump_traceback_later()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        stopping = time.monotonic()
        if node is not None:
            node.close()  # the node's own files (bags, checkpoints) are complete after this
        # Bound what follows: a hang in the executor's shutdown or in flushing is a failure (exit 1,
        # every thread's stack on stderr; SHUTDOWN_LIMIT_S).
        left = SHUTDOWN_LIMIT_S - (time.monotonic() - stopping)
        faulthandler.dump_traceback_later(max(left, 2.0), exit=True)
        if executor is not None:
            # Stop the executor while the node's entities exist: it holds them "in use", and an
            # executor dropped only when this function returns (after destroy_node and
            # rclpy.shutdown) released them then, finishing their deferred destruction against a
            # shut-down context; that hung until the limit above (a CI run: the agent, 30 s, in
            # event_handler.__exit__ called from main after run_node had returned).
            if node is not None:
                executor.remove_node(node)
            executor.shutdown(timeout_sec=2.0)
            executor = None
        if node is not None:
            _flush_publishers(node, timeout=3.0)
        # The node's work is delivered: its files are closed and subscribers acknowledged what it
        # published. What is left is Fast DDS's teardown, which now and then hangs on a loaded
        # machine (CI runs: env_sim for minutes after "done"; the agent 12 s in destroy_service).
        # Cut it at the limit with TEARDOWN_CUT_EXIT, so a launcher can tell "work done, teardown
        # hung" from a failure; the stacks still say where it hung.
        _arm_teardown_watchdog(max(SHUTDOWN_LIMIT_S - (time.monotonic() - stopping), 2.0), code)
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code


def _arm_teardown_watchdog(seconds: float, code: int) -> None:
    """In `seconds` from now, write every thread's stack to stderr and end the process: with
    TEARDOWN_CUT_EXIT if it was to exit with 0, else with 1. Works while the main thread is stuck
    in C code holding the GIL (where no Python thread or signal handler can run): faulthandler's
    watchdog is a C thread, and the exit is libc's _exit installed as the C handler of SIGALRM
    (which passes the signal number, TEARDOWN_CUT_EXIT, as the exit status)."""
    sys.stdout.flush()
    sys.stderr.flush()
    if code != 0:
        faulthandler.dump_traceback_later(seconds, exit=True)
        return
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    libc.signal.restype = ctypes.c_void_p
    libc.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]
    if libc.signal(int(signal.SIGALRM), ctypes.cast(libc._exit, ctypes.c_void_p).value) == ctypes.c_void_p(-1).value:
        faulthandler.dump_traceback_later(seconds, exit=True)  # no handler: the plain bound
        return
    faulthandler.dump_traceback_later(seconds, exit=False)
    signal.setitimer(signal.ITIMER_REAL, seconds + 0.3)


def _warn_about_namesakes(node, after: float = 2.0) -> None:
    """Once, `after` s from start (discovery done): warn if another node of the same fully
    qualified name runs in this ROS domain (ros2 param, wait_for_nodes and `ros2 node info` cannot
    tell them apart)."""
    def check() -> None:
        node.destroy_timer(timer)
        same = [1 for name, ns in node.get_node_names_and_namespaces()
                if name == node.get_name() and ns == node.get_namespace()]
        if len(same) > 1:
            node.get_logger().warning(
                f"{len(same)} nodes named {node.get_fully_qualified_name()} run in this ROS domain: "
                f"ros2 param, wait_for_nodes and ros2 node info cannot tell them apart; give each its "
                f"own name (--ros-args -r __node:=NAME) or namespace (-r __ns:=/NS)")

    timer = node.create_timer(after, check)


def _flush_publishers(node, timeout: float = 5.0) -> None:
    """Wait (at most `timeout` s in all) until reliable subscribers acknowledged what we published,
    so the last messages (an episode's final observation, its label) are not lost at exit."""
    from rclpy.duration import Duration

    deadline = time.monotonic() + timeout
    for pub in list(node.publishers):
        left = deadline - time.monotonic()
        if left <= 0:
            break
        try:
            pub.wait_for_all_acked(Duration(seconds=left))
        except Exception:  # noqa: BLE001 - best effort at shutdown
            pass


def _executor():
    """The EventsExecutor where rclpy has it (2-3x lower latency), else SingleThreadedExecutor."""
    try:
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    except ImportError:  # pragma: no cover - older rclpy
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor()


EXIT_WITH_UPSTREAM = Param(False, "exit (code 0) once the input topic had publishers and has none "
                                  "left, e.g. when env_sim finished its episodes (set in launch files)")

#: the parameters of a node that serves people (labeller_web, foxglove_server): TLS beyond loopback
SERVER_TLS = {
    "certfile": Param("", "PEM certificate (chain): serve over TLS only, HTTPS / WSS ('' = plain, loopback only; "
                          "`nmrm tls cert` makes a self-signed pair)"),
    "keyfile": Param("", "PEM private key of certfile"),
    "trusted_network": Param(False, "serve beyond loopback without TLS (every request then carries a token in "
                                    "clear text: only on a network that is yours alone)"),
}


def start_server(app, params: dict):
    """Serve `app` on params' host and port (over TLS with certfile / keyfile: `web_server.serve`);
    NodeError (one line) for a certificate that cannot be served, an address beyond loopback
    without TLS or trust, or a port that cannot be bound."""
    from ..tls import TLSError
    from ..web_server import serve

    try:
        return serve(app, str(params["host"]), int(params["port"]), str(params["certfile"]),
                     str(params["keyfile"]), bool(params["trusted_network"]))
    except TLSError as exc:
        raise NodeError(str(exc)) from None
    except OSError as exc:
        raise NodeError(f"cannot serve on {params['host']}:{params['port']}: {exc.strerror or exc}") from None


def exit_with_upstream(node, subscriptions, period: float = 0.2, on_gone=None) -> None:
    """Make `node` end (exit_code 0) when its subscription(s) had publishers and have none left
    (or call `on_gone()` once then, for a node that has work to finish first).

    This is how a launched graph finishes after env_sim's last episode, under `ros2 launch` as
    well as `nmrm launch`: each consumer leaves once its producers have left. A producer that came
    and went between two checks still counts as seen if the node's `messages_received` > 0.
    """
    subs = subscriptions if isinstance(subscriptions, (list, tuple)) else [subscriptions]
    state = {"seen": False, "quiet_since": None}

    def check() -> None:
        count = sum(s.get_publisher_count() for s in subs)
        if count > 0 or node.messages_received > 0:
            state["seen"] = True
        # Messages a lagging node has received but not yet read are still there once their
        # publishers are gone (the executor runs this timer between them): so the node leaves
        # only after a whole period without publishers in which it read nothing more.
        quiet = count == 0 and state["quiet_since"] == node.messages_received
        state["quiet_since"] = node.messages_received if count == 0 else None
        if state["seen"] and quiet and node.exit_code is None and not state.get("gone"):
            state["gone"] = True
            if on_gone is not None:
                on_gone()
                return
            node.get_logger().info("input topic has no publishers left; exiting")
            node.exit_code = 0

    node.create_timer(period, check)


def subscribed_nodes(node, topic: str) -> set:
    """Names of the nodes with a subscription on `topic` (fully qualified name)."""
    return {info.node_name for info in node.get_subscriptions_info_by_topic(topic)}


def require_task(task: str):
    """The TaskInfo of `task`, or a NodeError naming the known tasks."""
    from ..tasks import task_info

    try:
        return task_info(task)
    except ValueError as exc:
        raise NodeError(str(exc)) from None


def require_robot_spec(path: str):
    """The RobotSpec of the robot spec YAML `path`, or a NodeError (one line) saying why not."""
    from .robot_spec import load_robot_spec

    if not path:
        raise NodeError("spec is required: a robot spec YAML file (see nmrm_ros.ros.robot_spec)")
    try:
        return load_robot_spec(path)
    except ValueError as exc:
        raise NodeError(str(exc)) from None


ORACLE = Param("", "your own oracle function, <module>:<function> or <file.py>:<function> "
                  "(nmrm_ros.oracles.function_oracle; '' = the task's own)")


def require_oracle(task: str, oracle: str = ""):
    """The oracle of `task` (or the user's `oracle` function), or a NodeError saying why not."""
    from ..oracles import make_oracle

    try:
        return make_oracle(task, oracle)
    except ValueError as exc:
        raise NodeError(str(exc)) from None


def live_parameter(node, table: dict, name: str, apply: Callable[[str], str]) -> None:
    """Let parameter `name` change while `node` runs: `apply(new value)` returns '' (accepted) or
    why not (refused: `ros2 param set` prints the reason, and the node logs it). Every other
    parameter of `table` is refused as "set at start only"."""
    from rcl_interfaces.msg import SetParametersResult

    def on_set(params):
        for param in params:
            if param.name == name:
                error = apply(param.value)
                if error:
                    node.get_logger().warning(f"{name} {param.value!r} refused: {error}")
                    return SetParametersResult(successful=False, reason=error)
            elif param.name in table:
                return SetParametersResult(successful=False, reason=f"{param.name} is set at start only")
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
