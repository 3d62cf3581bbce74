"""trainer: retrains the MIL reward model as labels arrive, and has the reward model reload it.

Follows episodes on `nmrm/observation` (as the labeller contract says) and labels on
`nmrm/trajectory_return` (those of `labeller`: labeller ids or prefixes such as `person/`, e.g.
`[person/alice, person/bob]` to use only the labels of the people a team trusts; '' = any); the
latest label per labeller and episode counts, so a correction replaces what it
corrects. Every `retrain_every` new labels it trains a `members`-member ensemble on all the
labelled episodes in a child process (`python -m nmrm_ros.mil.retrain`, warm-started from the
previous version: the newest in `out_dir`, else `checkpoint`), writes the checkpoint
`out_dir/<task>_vNNN` (numbering goes on after the versions already there) and sets the `checkpoint` parameter of
`reward_model` (which swaps it in at its next episode start), of `labeller_web` (which orders
its queue by the new members' disagreement) and of `agent` if named (a learning agent, which
relabels its replay buffer with it once it is served). Labels that arrive during a training count towards
the next one. Every version records the labels it was built from (labeller, source, episode,
return, when) in its checkpoint's JSON (`nmrm labels report --checkpoint C` lists them).

`feedback`: what it learns from — returns (TrajectoryReturn), preferences (TrajectoryPreference
on `nmrm/trajectory_preference`, the same labellers; a Bradley–Terry loss) or both; with
preferences, every `retrain_every` new comparisons trigger a retraining.

`bags`: recordings and labels bags read at start (e.g. an earlier session's), so a restarted
trainer starts from what was labelled before. The child process dies with the node.
"""

from __future__ import annotations

import ctypes
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from rclpy.parameter import Parameter

from nmrm_msgs.msg import EnvObservation, TrajectoryPreference, TrajectoryReturn

from ..feedback import unknown_feedback
from ..ros.episodes import EpisodeFollower, Kind
from ..ros.node_base import NmrmNode
from ..ros.node_main import NodeError, Param, require_task
from ..ros.topics import OBSERVATION, STEP_QOS, TRAJECTORY_PREFERENCE, TRAJECTORY_RETURN

PARAMETERS = {
    "exit_with_upstream": Param(False, "exit (code 0) once the episodes' and labels' publishers have all left, "
                                       "after the retraining in progress (e.g. when the loop's env_sim has finished)"),
    "task": Param("key", "task of the episodes and labels"),
    "labeller": Param(["person/"], "labels used: labeller ids, or prefixes ending in '/' (e.g. "
                                   "[person/alice, person/bob]); '' = any"),
    "retrain_every": Param(10, "retrain after this many new labelled episodes", 1),
    "architecture": Param("csc_lstm", "csc_lstm | instance_lstm | embedding_lstm | instance_nn | transformer"),
    "members": Param(5, "ensemble members (their disagreement orders the labelling queue)", 1),
    "max_epochs": Param(40, "epochs per retraining (warm-started; early stopping as configured)", 1),
    "seed": Param(0, "seed of the splits and of the members' initialisation"),
    "checkpoint": Param("", "starting checkpoint to warm-start the first retraining from ('' = fresh)"),
    "out_dir": Param("checkpoints", "where the versioned checkpoints <task>_vNNN.{pt,json} go"),
    "reward_model": Param("reward_model", "node told to load each new checkpoint ('' = none)"),
    "labeller_web": Param("labeller_web", "node whose queue each new checkpoint orders ('' = none)"),
    "agent": Param("", "learning agent told each new checkpoint, to relabel its replay buffer with it "
                       "once served (e.g. agent; '' = none)"),
    "bags": Param([""], "recordings and labels bags read at start (labels of `labeller`)"),
    "feedback": Param("returns", "what to learn from: returns | preferences (comparisons) | both"),
}


TELL_TIMEOUT_S = 10.0  # wait this long for a node's answer to "load this checkpoint" ...
TELL_ATTEMPTS = 3  # ... and ask this many times in all


def _die_with_parent() -> None:
    """In the child, before exec: SIGTERM it when the trainer dies, even by kill -9 (Linux)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


class TrainerNode(NmrmNode):
    executable = "trainer"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        super().__init__()
        p = self.params
        from ..labelling.training_set import TrainingSet
        from ..mil.models import ARCHITECTURES

        self.info = require_task(p["task"])
        self.task = p["task"]
        if p["architecture"] not in ARCHITECTURES:
            raise NodeError(f"unknown architecture {p['architecture']!r}; known: {', '.join(ARCHITECTURES)}")
        if unknown_feedback(p["feedback"]):
            raise NodeError(unknown_feedback(p["feedback"]))
        self.p = p
        self.labellers = [str(x) for x in p["labeller"] if str(x)]
        self.set = TrainingSet(self.task, self.info.state_size, source=self.get_namespace().rstrip("/"))
        self.out_dir = Path(p["out_dir"])
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.version = self._last_version()
        # warm start: the newest version already in out_dir (a restarted trainer), else `checkpoint`
        newest = self.out_dir / f"{self._name(self.version)}.pt"
        self.latest = str(newest) if self.version and newest.is_file() else (p["checkpoint"] or None)
        self.new_labels = 0
        self.child: subprocess.Popen | None = None
        self.job: dict = {}
        self.follower = EpisodeFollower()
        self.states: list = []
        self._read_bags([b for b in p["bags"] if b])
        self.param_clients = {name: self._client(name) for name in (p["reward_model"], p["labeller_web"], p["agent"]) if name}
        subs = self.subscribe_steps(EnvObservation, OBSERVATION, self.on_observation, self.info)
        if p["feedback"] != "preferences":
            subs.append(self.create_subscription(TrajectoryReturn, TRAJECTORY_RETURN, self.on_label, STEP_QOS))
        if p["feedback"] != "returns":
            subs.append(self.create_subscription(TrajectoryPreference, TRAJECTORY_PREFERENCE, self.on_comparison,
                                                 STEP_QOS))
        self.upstream_gone = False
        self.exit_with_upstream(subs, on_gone=self._upstream_left)
        self.create_timer(0.5, self.poll)
        self.get_logger().info(
            f"task {self.task}: retraining a {p['members']}-member {p['architecture']} from {p['feedback']} every "
            f"{p['retrain_every']} new label(s) of {', '.join(self.labellers) or 'any labeller'}; "
            f"{len(self.set.joined())} labelled episode(s) and {len(self.set.joined_comparisons())} "
            f"comparison(s) from bags; next version "
            f"{self._name(self.version + 1)} in {self.out_dir}, warm-started from {self.latest or 'nothing'}")

        self.diagnose(lambda: {"model_version": self.version, "new_labels": self.new_labels,
            "latest": self.latest or ""})

    # -- inputs ------------------------------------------------------------------------------------
    def _wanted(self, labeller: str) -> bool:
        if not self.labellers:
            return True
        return any(labeller.startswith(w) if w.endswith("/") else labeller == w for w in self.labellers)

    def _read_bags(self, bags: list) -> None:
        from ..bags import BagError, iter_decoded
        from ..bags.episodes import load_bag_dataset

        if not bags:
            return
        labels, comparisons = [], []
        for bag in bags:
            try:
                for _, t, log_ns, m in iter_decoded(bag):
                    if t.endswith("TrajectoryReturn") and self.p["feedback"] != "preferences":
                        labels.append(m)
                    elif t.endswith("TrajectoryPreference") and self.p["feedback"] != "returns":
                        comparisons.append((m, log_ns))
            except BagError as exc:
                raise NodeError(str(exc)) from None
        for labeller in sorted({m.labeller for m in labels + [c for c, _ in comparisons] if self._wanted(m.labeller)}):
            try:
                ds, _ = load_bag_dataset(bags, task=self.task, labeller=labeller)
            except BagError:
                continue
            for i, ep in enumerate(ds.meta["episodes"]):
                n = int(ds.lengths[i])
                self.set.add_episode(ep, np.concatenate([ds.states[i, :n], ds.final_states[i][None]]))
                if np.isfinite(ds.returns[i]) and self.p["feedback"] != "preferences":
                    self.set.add_label(labeller, ep, n, float(ds.returns[i]), ds.meta["labels"][i]["stamp_ns"])
        for m, log_ns in comparisons:
            if m.task == self.task and self._wanted(m.labeller) and m.preference in (-1, 0, 1):
                self.set.add_comparison(m.labeller, m.episode_a, m.length_a, m.episode_b, m.length_b,
                                        (m.preference + 1) / 2, log_ns)

    def on_observation(self, msg: EnvObservation) -> None:
        kind, state, _ = self.follower.follow(msg, self.task, self.info.state_size)
        if kind in (Kind.DUPLICATE, Kind.BROKEN):
            return
        if kind is Kind.START:
            self.states = []
        self.states.append(state)
        if msg.terminated or msg.truncated:
            self.follower.finish()
            if msg.step > 0:
                self.set.add_episode(int(msg.episode), np.stack(self.states))
            self.states = []
            self.maybe_retrain()

    def on_label(self, msg: TrajectoryReturn) -> None:
        if msg.task != self.task or not self._wanted(msg.labeller):
            return
        if not np.isfinite(msg.return_value):
            self.get_logger().warning(f"ignoring a non-finite label of episode {msg.episode}")
            return
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        if self.set.add_label(msg.labeller, msg.episode, msg.length, msg.return_value, stamp):
            self.new_labels += 1
        self.maybe_retrain()

    def on_comparison(self, msg: TrajectoryPreference) -> None:
        if msg.task != self.task or not self._wanted(msg.labeller):
            return
        if msg.preference not in (-1, 0, 1) or msg.episode_a == msg.episode_b:
            self.get_logger().warning(f"ignoring a comparison of episodes {msg.episode_a} and {msg.episode_b} "
                                      f"with preference {msg.preference}")
            return
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        if self.set.add_comparison(msg.labeller, msg.episode_a, msg.length_a, msg.episode_b, msg.length_b,
                                   (msg.preference + 1) / 2, stamp):
            self.new_labels += 1
        self.maybe_retrain()

    # -- retraining --------------------------------------------------------------------------------
    def _name(self, version: int) -> str:
        return f"{self.task}_v{version:03d}"

    def _last_version(self) -> int:
        found = [int(m.group(1)) for f in self.out_dir.glob(f"{self.task}_v*.json")
                 if (m := re.fullmatch(rf"{re.escape(self.task)}_v(\d+)\.json", f.name))]
        return max(found, default=0)

    def _upstream_left(self) -> None:
        self.upstream_gone = True
        what = f"after {self.job['name']}" if self.child is not None else "now"
        self.get_logger().info(f"episodes and labels have no publishers left; exiting {what}")
        self.poll()

    def maybe_retrain(self) -> None:
        if self.child is not None or self.new_labels < self.p["retrain_every"] or self.upstream_gone:
            return
        try:
            ds = self.set.dataset()
        except ValueError:
            return
        if len(ds) < 2:
            return
        self.version += 1
        name = self._name(self.version)
        data = self.out_dir / ".datasets"
        data.mkdir(exist_ok=True)
        path = ds.save(data / f"{name}.npz")
        cmd = [sys.executable, "-m", "nmrm_ros.mil.retrain", "--dataset", str(path),
               "--out", str(self.out_dir / name), "--architecture", self.p["architecture"],
               "--members", str(self.p["members"]), "--max-epochs", str(self.p["max_epochs"]),
               "--seed", str(self.p["seed"] + self.version), "--feedback", self.p["feedback"]]
        if self.latest:
            cmd += ["--init", str(self.latest)]
        self.new_labels = 0
        self.job = {"name": name, "labels": len(ds), "started": time.monotonic()}
        compared = f" and {len(ds.preferences)} comparison(s)" if ds.preferences is not None else ""
        self.child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                      preexec_fn=_die_with_parent)
        self.get_logger().info(f"retraining {name} on {len(ds)} episode(s){compared}")

    def poll(self) -> None:
        if self.upstream_gone and self.child is None and self.exit_code is None:
            self.exit_code = 0
        if self.child is None or self.child.poll() is None:
            return
        out, err = self.child.communicate()
        code, self.child = self.child.returncode, None
        name = self.job["name"]
        try:
            summary = json.loads(out.strip().splitlines()[-1])
        except (ValueError, IndexError):
            summary = {"error": (err.strip().splitlines() or [f"exit {code}"])[-1]}
        if code != 0 or "error" in summary:
            self.get_logger().error(f"retraining {name} failed: {summary.get('error')}")
        else:
            self.latest = summary["checkpoint"]
            fit = (f"validation return MSE {summary['val_return_mse']:.3f}"
                   if summary["val_return_mse"] == summary["val_return_mse"] else
                   f"validation preference loss {summary['val_loss']:.3f}")
            self.get_logger().info(
                f"{name}: {summary['labels']} labels, {summary['comparisons']} comparisons, {fit} "
                f"({summary['validation_bags']} bag(s)), members' "
                f"spread {summary['val_return_std']:.3f}, {summary['seconds']:.1f} s, {summary['start']}, "
                f"serving member {summary['serving_member']} ({summary['serving']})")
            for client in self.param_clients.values():
                self._tell(client, self.latest)
        self.maybe_retrain()
        if self.upstream_gone and self.child is None:
            self.exit_code = 0

    # -- telling the other nodes -------------------------------------------------------------------
    def _client(self, name: str):
        from rclpy.parameter_client import AsyncParameterClient

        return AsyncParameterClient(self, name)

    def _tell(self, client, checkpoint: str, attempt: int = 1) -> None:
        """Set `checkpoint` on the node behind `client`; log its answer once.

        A request can go unanswered: a ROS 2 service is two DDS topics, and under load the server
        may not yet have discovered this client's reply reader when it answers (rmw drops the reply
        with a "failed to send response" warning; see ros2/rcl#1048). The parameter is set all the
        same, but without an answer nobody knows: after TELL_TIMEOUT_S the request is sent again
        (setting the same checkpoint twice is harmless), at most TELL_ATTEMPTS times."""
        node = client.remote_node_name
        if not client.services_are_ready():
            self.get_logger().warning(f"{node} is not reachable; it keeps its model")
            return
        future = client.set_parameters([Parameter("checkpoint", value=str(checkpoint))])
        state = {"answered": False}

        def done(f) -> None:
            if state["answered"] or f.cancelled():
                return
            state["answered"] = True
            self.destroy_timer(timer)  # answered: no need to wait (every live timer costs the clock)
            try:
                result = f.result().results[0]
            except Exception as exc:  # noqa: BLE001 - a service failure is reported, not raised
                self.get_logger().warning(f"{node}: setting checkpoint failed: {exc}")
                return
            if result.successful:
                self.get_logger().info(f"{node} loads {checkpoint}")
            else:
                self.get_logger().warning(f"{node} refused {checkpoint}: {result.reason}")

        def no_answer() -> None:
            self.destroy_timer(timer)
            if state["answered"] or checkpoint != self.latest:
                return
            state["answered"] = True  # a late answer to this request is not logged twice
            if attempt < TELL_ATTEMPTS:
                self.get_logger().warning(f"{node} did not answer in {TELL_TIMEOUT_S:g} s; asking again")
                self._tell(client, checkpoint, attempt + 1)
            else:
                self.get_logger().warning(f"{node} did not answer {TELL_ATTEMPTS} requests to load "
                                          f"{checkpoint}; it may keep its model")

        timer = self.create_timer(TELL_TIMEOUT_S, no_answer)
        future.add_done_callback(done)

    def close(self) -> None:
        if self.child is not None and self.child.poll() is None:
            self.child.terminate()
            try:
                self.child.wait(5)
            except subprocess.TimeoutExpired:
                self.child.kill()
            self.get_logger().info(f"retraining {self.job.get('name')} stopped unfinished")


def main(args=None) -> int:
    return TrainerNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
