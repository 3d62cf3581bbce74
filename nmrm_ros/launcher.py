"""`nmrm launch`: run a ROS 2 YAML launch file's nodes as separate processes, without ros2 launch.

ROS 2's launch / launch_ros are not on PyPI, so this runs the documented subset of the ROS 2 YAML
launch format that our launch files use, with the same typing rules as launch_yaml + launch_ros
(a file one accepts the other accepts; the tests run every launch file under both):

    launch:
    - arg: {name: task, default: key}               # overridable as task:=timer
    - node:
        pkg: nmrm_ros                               # executable: <prefix>/lib/<pkg>/<exec>
        exec: env_sim
        name: env_sim                               # -> --ros-args -r __node:=env_sim
        namespace: /robot1                          # -> -r __ns:=/robot1  (optional)
        param:
        - {name: task, value: $(var task)}          # substituted, then read as YAML
        - {name: rate, value: 1.0}                  # a double ("1.0" quoted is a string)
        - {from: $(find-pkg-share nmrm_ros)/config/graph.yaml}   # -> --params-file ...
        remap:
        - {from: nmrm/observation, to: obs}         # -> -r nmrm/observation:=obs
        args: "--extra args"                        # appended before --ros-args (optional)

Substitutions: $(var NAME), $(find-pkg-share PKG), $(find-pkg-prefix PKG), $(env NAME [DEFAULT]).
Anything else in the file is an error (not silently ignored). Extras over `ros2 launch`: the
launcher exits non-zero naming the node when one dies (ros2 launch exits 0), and stops the others.

Process handling: each node's output is prefixed with its name. Ctrl-C / SIGTERM / SIGHUP are
forwarded as SIGINT to every node (SIGTERM after `grace` seconds, SIGKILL after twice that) and the
launcher exits with 128 + the signal number (an interrupted run is not a success). Each node gets
SIGTERM if the launcher itself dies, even by SIGKILL (Linux parent-death signal). When a node exits
with a non-zero code, the others are stopped and the launcher exits with 1 and names the node.
When every node has exited with 0, the launcher exits with 0.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .ros.node_main import TEARDOWN_CUT_EXIT

_SUBST = re.compile(r"\$\(([^)]*)\)")


class LaunchError(ValueError):
    """The launch file is invalid or uses something outside the supported subset."""


@dataclass
class NodeSpec:
    name: str
    cmd: list = field(default_factory=list)


def _prefix(pkg: str) -> Path:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    from .ros.ament_paths import ensure_ament_prefix_path

    ensure_ament_prefix_path()
    try:
        return Path(get_package_prefix(pkg))
    except (PackageNotFoundError, OSError):  # OSError: AMENT_PREFIX_PATH empty
        raise LaunchError(f"package {pkg!r} not found in the ament index "
                          f"(AMENT_PREFIX_PATH={os.environ.get('AMENT_PREFIX_PATH', '')!r})") from None


def substitute(text, variables: dict, what: str = "value") -> str:
    """Resolve the supported $(...) substitutions in `text` (a string, as launch_yaml requires)."""
    if not isinstance(text, str):
        raise LaunchError(f"{what} must be a string (quote it), got {type(text).__name__} {text!r}")

    def one(match: re.Match) -> str:
        parts = match.group(1).split()
        if not parts:
            raise LaunchError(f"empty substitution in {text!r}")
        kind, rest = parts[0], parts[1:]
        if kind == "var" and len(rest) == 1:
            if rest[0] not in variables:
                raise LaunchError(f"launch argument {rest[0]!r} is not declared")
            return variables[rest[0]]
        if kind == "find-pkg-share" and len(rest) == 1:
            return str(_prefix(rest[0]) / "share" / rest[0])
        if kind == "find-pkg-prefix" and len(rest) == 1:
            return str(_prefix(rest[0]))
        if kind == "env" and len(rest) in (1, 2):
            value = os.environ.get(rest[0], rest[1] if len(rest) == 2 else None)
            if value is None:
                raise LaunchError(f"environment variable {rest[0]} is not set")
            return value
        raise LaunchError(f"unsupported substitution $({match.group(1)}) in {text!r}")

    return _SUBST.sub(one, text)


_SCALARS = (bool, int, float, str)


def parameter_value(raw, variables: dict, name: str):
    """A `name/value` parameter's value as launch_ros hands it to the node (launch_yaml rules).

    A YAML scalar (`true`, `5`, `1.0`) is kept as it is; a string with no substitution stays a
    string (`"true"`, `"1.0"` are strings); a string with `$(...)` is substituted and the result read
    as YAML (`"5"` -> 5, `""` -> ""); a list applies these rules to each item and must be of one
    type. Anything else is a LaunchError, as it is an error under `ros2 launch`.
    """
    def item(value):
        if isinstance(value, (int, float)):  # bool is an int
            return value
        if not isinstance(value, str):
            raise LaunchError(f"parameter {name!r}: unsupported value {value!r}")
        if not _SUBST.search(value):
            return value
        text = substitute(value, variables)
        if text == "":
            return ""
        try:
            parsed = yaml.safe_load(text)
        except yaml.YAMLError:
            raise LaunchError(f"parameter {name!r}: {text!r} is not valid YAML") from None
        if isinstance(parsed, _SCALARS) or (isinstance(parsed, list) and _uniform(parsed)):
            return parsed
        raise LaunchError(f"parameter {name!r}: {text!r} is not a bool, int, float, string or "
                          f"a non-empty list of one of them")

    if isinstance(raw, list):
        values = [item(v) for v in raw]
        if not _uniform(values):
            raise LaunchError(f"parameter {name!r}: a list must be non-empty and of one type, got {raw!r}")
        return values
    return item(raw)


def _uniform(values: list) -> bool:
    return bool(values) and all(type(v) is type(values[0]) and isinstance(v, _SCALARS) for v in values)


def parse_launch_file(path: str | Path, arguments: dict | None = None,
                      params_dir: str | Path | None = None) -> list:
    """The node commands of a launch file, with `arguments` (name -> value) overriding defaults.

    `name/value` parameters are written, as launch_ros does, to parameter files in `params_dir`
    (a new temporary directory if None), values typed by the launch_yaml rules (`parameter_value`)."""
    path = Path(path)
    if not path.is_file():
        raise LaunchError(f"no launch file {path}")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise LaunchError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("launch"), list):
        raise LaunchError(f"{path}: expected a top-level 'launch:' list")
    arguments = dict(arguments or {})
    params_dir = Path(params_dir or tempfile.mkdtemp(prefix="nmrm_launch_"))
    variables: dict = {}
    nodes = []
    for entry in doc["launch"]:
        if not isinstance(entry, dict) or len(entry) != 1:
            raise LaunchError(f"{path}: each launch entry is one of 'arg' or 'node', got {entry!r}")
        (kind, body), = entry.items()
        if kind == "arg":
            name = body.get("name")
            if name in arguments:
                variables[name] = arguments.pop(name)
            elif "default" in body:
                variables[name] = substitute(body["default"], variables, f"default of argument {name!r}")
            else:
                raise LaunchError(f"launch argument {name!r} has no default; give {name}:=VALUE")
        elif kind == "node":
            if _enabled(body, variables, path):
                nodes.append(_node({k: v for k, v in body.items() if k not in ("if", "unless")},
                                   variables, path, params_dir))
        else:
            raise LaunchError(f"{path}: unsupported launch entry {kind!r} (supported: arg, node)")
    if arguments:
        raise LaunchError(f"unknown launch argument(s) {sorted(arguments)}; declared: {sorted(variables)}")
    return nodes


def _enabled(body: dict, variables: dict, path: Path) -> bool:
    """A node's `if:` / `unless:` condition, as launch evaluates it: true/1 or false/0 (any case)."""
    enabled = True
    for key, want in (("if", True), ("unless", False)):
        if key in body:
            value = substitute(str(body[key]), variables, f"node condition {key!r}").strip().lower()
            if value not in ("true", "1", "false", "0"):
                raise LaunchError(f"{path}: node condition {key}: {value!r} is not true, false, 1 or 0")
            enabled = enabled and ((value in ("true", "1")) == want)
    return enabled


def _node(body: dict, variables: dict, path: Path, params_dir: Path) -> NodeSpec:
    known = {"pkg", "exec", "name", "namespace", "param", "remap", "args", "output"}
    extra = set(body) - known
    if extra:
        raise LaunchError(f"{path}: unsupported node attribute(s) {sorted(extra)}")
    def attr(key: str, default=None) -> str:
        return substitute(body.get(key, default), variables, f"node attribute {key!r}")

    pkg, exe = attr("pkg"), attr("exec")
    executable = _prefix(pkg) / "lib" / pkg / exe
    if not os.access(executable, os.X_OK):
        raise LaunchError(f"no executable {exe!r} in package {pkg!r} ({executable})")
    name = attr("name", exe)
    cmd = [str(executable), *shlex.split(attr("args", "")), "--ros-args",
           "-r", f"__node:={name}"]
    namespace = attr("namespace", "")
    if namespace:  # '' = the root namespace, as launch_ros treats it
        cmd += ["-r", f"__ns:={namespace if namespace.startswith('/') else '/' + namespace}"]
    group: dict = {}

    def flush() -> None:
        if group:
            file = params_dir / f"{name}_{len(list(params_dir.iterdir()))}.yaml"
            file.write_text(yaml.safe_dump({"/**": {"ros__parameters": dict(group)}}))
            cmd.extend(["--params-file", str(file)])
            group.clear()

    for p in body.get("param", []) or []:
        if "from" in p:
            flush()
            cmd += ["--params-file", substitute(p["from"], variables)]
        else:
            name_ = substitute(p["name"], variables, "a parameter's name")
            if "value" not in p:
                raise LaunchError(f"{path}: parameter {name_!r} of node {name!r} has no value")
            group[name_] = parameter_value(p["value"], variables, name_)
    flush()
    for r in body.get("remap", []) or []:
        cmd += ["-r", f"{substitute(r['from'], variables)}:={substitute(r['to'], variables)}"]
    return NodeSpec(name, cmd)


def _pump(stream, name: str, out) -> None:
    for line in iter(stream.readline, ""):
        out.write(f"[{name}] {line}")
        out.flush()


def _die_with_parent() -> None:
    """In the child before exec: get SIGTERM when the launcher dies, even by SIGKILL (Linux
    prctl PR_SET_PDEATHSIG; kept across exec). Elsewhere a no-op."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
        if os.getppid() == 1:  # the launcher died before prctl took effect
            os.kill(os.getpid(), signal.SIGTERM)
    except (OSError, AttributeError):
        pass


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def run(nodes: list, grace: float = 10.0, out=None) -> int:
    """Start every node, forward signals, and wait; returns the launcher's exit code.

    0 when every node ended by itself with 0; 1 when a node failed; 128 + signal number when the
    run was interrupted (Ctrl-C: 130, SIGTERM: 143, SIGHUP: 129), as a shell reports it."""
    out = out or sys.stdout
    procs: list = []
    stopping = {"why": None}

    def stop_all(sig=signal.SIGINT) -> None:
        for _, p in procs:
            if p.poll() is None:
                try:
                    p.send_signal(sig)
                except ProcessLookupError:
                    pass

    def on_signal(signum, frame) -> None:
        if stopping["why"] is None:
            stopping["why"] = signal.Signals(signum).name
            out.write(f"[nmrm launch] {stopping['why']}: stopping {len(procs)} node(s)\n")
        stop_all()

    old = {s: signal.signal(s, on_signal) for s in STOP_SIGNALS}
    threads = []
    try:
        for spec in nodes:
            p = subprocess.Popen(spec.cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 start_new_session=True, preexec_fn=_die_with_parent)
            procs.append((spec.name, p))
            t = threading.Thread(target=_pump, args=(p.stdout, spec.name, out), daemon=True)
            t.start()
            threads.append(t)
        failed = None
        stop_sent_at = None
        while any(p.poll() is None for _, p in procs):
            for name, p in procs:
                code = p.poll()
                if code not in (None, 0, TEARDOWN_CUT_EXIT) and failed is None and stopping["why"] is None:
                    failed = (name, code)
                    out.write(f"[nmrm launch] node '{name}' died with exit code {code}; stopping the others\n")
                    stopping["why"] = "failure"
                    stop_all()
            if stopping["why"] is not None:
                stop_sent_at = stop_sent_at or time.monotonic()
                waited = time.monotonic() - stop_sent_at
                if waited > 2 * grace:
                    stop_all(signal.SIGKILL)
                elif waited > grace:
                    stop_all(signal.SIGTERM)
            time.sleep(0.05)
        for t in threads:
            t.join(timeout=1.0)
        if failed is None:
            for name, p in procs:
                if p.returncode not in (0, TEARDOWN_CUT_EXIT, -signal.SIGINT) and stopping["why"] is None:
                    failed = (name, p.returncode)
        if failed is not None:
            out.write(f"[nmrm launch] failed: node '{failed[0]}' exited with code {failed[1]}\n")
            return 1
        if stopping["why"] not in (None, "failure"):
            codes = ", ".join(f"{name} {p.returncode}" for name, p in procs)
            out.write(f"[nmrm launch] interrupted by {stopping['why']}: {len(procs)} node(s) stopped "
                      f"(exit codes: {codes})\n")
            return 128 + int(signal.Signals[stopping["why"]])
        cut = [name for name, p in procs if p.returncode == TEARDOWN_CUT_EXIT]
        out.write(f"[nmrm launch] all {len(procs)} node(s) exited cleanly\n")
        if cut:
            out.write(f"[nmrm launch] warning: {', '.join(cut)} finished its work but its DDS teardown did not "
                      f"end in time and was cut (exit code {TEARDOWN_CUT_EXIT}; the stacks above say where)\n")
        return 0
    finally:
        stop_all(signal.SIGKILL)
        for s, h in old.items():
            signal.signal(s, h)
