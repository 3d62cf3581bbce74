"""labeller_web: a person labels episodes on a local web page; each label is published and stored.

Follows episodes on `nmrm/observation` exactly as the labeller contract says (docs/guide/graph.md; the
oracle labeller does the same): an episode is complete at its final observation, episodes that
could not be followed in full are not offered. Finished episodes wait in a queue on the page
(http://HOST:PORT/), oldest first; the person watches one (its path over the arena, play / pause /
scrub) and enters its return (a number within the task's range, shown on the page) or skips it.
With `checkpoint` (an ensemble, e.g. the trainer's latest), the queue is ordered by how much the
members disagree on an episode's return, largest first, and the page says so per episode; the
trainer sets `checkpoint` again after each retraining (`ros2 param set` works too).

Every label is published at once as TrajectoryReturn with `labeller` = person/<person>, and
written and flushed to a labels-only bag in `labels_dir` (one bag per session), so a crash or
Ctrl-C loses no label. A second label of an episode is a correction: a new TrajectoryReturn;
training uses the latest label per labeller and episode. At start the node reads `labels_dir`
(repairing a session that was killed) and does not ask again for episodes labelled before.
Finished, unlabelled episodes are kept in `labels_dir`/.waiting_episodes/ until labelled, so a
restarted node offers them again (a crash costs at most the episode in progress).

Rendered frames on `nmrm/frame` (env_sim `render:=true`) are kept (`frames_mb`) and the page
plays an episode that has them as a video, with the same controls. They are not kept on disk:
after a restart, the episodes offered again have their states only.

A team: `people` names several people (e.g. [alice, bob]); each gets an access token of their
own, printed at start as their own URL (and kept in `labels_dir`/.team_tokens.json, readable by
you only, so a restarted page keeps the URLs), and every label is `person/<name>` of whoever gave
it, stored in that person's labels bag. `assignment` split (default): each episode goes to one
person (one someone has open is theirs for `take_s` s); overlap: everyone is asked about every
episode, for agreement. The page shows who labelled how much and how far people agree
(`/api/team`; `nmrm labels report` gives the same for any labels bags). `gold_every` N: every
N-th episode is a gold episode, asked of everyone, whose true return the oracle (the task's, or
`oracle`) knows: each person's error on them is shown, and the true returns are written to a
`gold_oracle_*` bag in `labels_dir` (not published), so `nmrm labels report` can check people later.

The page shows what to judge: the task's instruction (our tasks' from the paper; a task module's
`INSTRUCTION`; or the text file `instruction`), a legend of what is drawn, the keyboard shortcuts and
how many labels the person has given and how many wait.

Comparisons: with `feedback` preferences (or both), the page shows two episodes side by side,
played together, and asks which is better: left / right / equal / can't tell (keys ←, →, =, s).
Pairs come from the oldest episodes that still need comparisons (`comparisons_per_episode`), or,
with an ensemble `checkpoint`, where its members disagree most on P(left better). Each answer is
published at once as TrajectoryPreference on `nmrm/trajectory_preference` (labeller
person/<name>) and written to the person's labels bag with their returns; "can't tell" publishes
nothing. Pairs answered in earlier sessions are not asked again.

Safety (as Jupyter's): binds 127.0.0.1 unless `host` says otherwise; every request needs the
access token (`token`, or one generated and printed in the URL at start; `require_token:=false`
drops it on 127.0.0.1 only), the Host header must name this server, and a request that changes
anything must be JSON from the page's own origin (nmrm_ros.labelling.web_app); bodies over 4 KiB
are refused. With `certfile` and `keyfile` the page is served over HTTPS only (the token cookie is
then Secure); beyond loopback without them the node does not start unless `trusted_network`
(nmrm_ros.tls). Tokens are logged only in the URLs printed at start, one per person.
"""

from __future__ import annotations

import secrets
import time
from pathlib import Path

import numpy as np

from nmrm_msgs.msg import EnvObservation, TrajectoryPreference, TrajectoryReturn
from sensor_msgs.msg import CompressedImage

from ..feedback import unknown_feedback
from ..ros.episodes import EpisodeFollower, Kind
from ..ros.messages import oracle_state
from ..ros.node_base import NmrmNode
from ..ros.node_main import SERVER_TLS, NodeError, Param, live_parameter, require_task, start_server
from ..tls import LOOPBACK
from ..web_server import is_any_address
from ..ros.topics import FRAME, OBSERVATION, STEP_QOS, TRAJECTORY_PREFERENCE, TRAJECTORY_RETURN

PARAMETERS = {
    "task": Param("key", "task of the episodes to label"),
    "person": Param("anonymous", "who labels: the labels' labeller id is person/<person>"),
    "people": Param([""], "a team: the names of its people, each with a token of their own ([''] = person alone)"),
    "assignment": Param("split", "split: each episode to one person | overlap: every episode to everyone"),
    "take_s": Param(300.0, "split: an episode a person has open is theirs for this many seconds", 1.0),
    "gold_every": Param(0, "every this many-th episode is a gold episode (its oracle return known; 0 = none)", 0),
    "oracle": Param("", "gold episodes: your own oracle function, <module>:<function> ('' = the task's)"),
    "host": Param("127.0.0.1", "address the page is served on (not loopback: a token is required)"),
    "port": Param(8080, "TCP port of the page (0: any free port, printed at start)", 0),
    "token": Param("", "access token; '' = one generated and printed in the page's URL at start"),
    "require_token": Param(True, "require the token on 127.0.0.1 too (false: none there; other "
                                 "addresses always require it)"),
    "labels_dir": Param("labels", "directory of this labeller's labels bags (one per session)"),
    "max_episodes": Param(1000, "finished episodes kept for labelling (oldest dropped)", 1),
    "checkpoint": Param("", "MIL ensemble checkpoint: ask first where its members disagree ('' = oldest first)"),
    "exit_with_upstream": Param(False, "exit when the observation topic's publishers are gone"),
    "feedback": Param("returns", "what the page asks: returns | preferences (pairwise comparisons) | both"),
    "comparisons_per_episode": Param(3, "feedback preferences|both: answered comparisons each episode gets", 1),
    "pair_window": Param(30, "feedback preferences|both: pairs are chosen among this many oldest episodes "
                             "that need comparisons", 2),
    "frames_mb": Param(200, "rendered frames (nmrm/frame) kept for the page, in MB (oldest episodes' dropped)", 1),
    "instruction": Param("", "a UTF-8 text file of what people judge, shown on the page ('' = the task's own words)"),
    **SERVER_TLS,
}

MAX_INSTRUCTION = 4000  # characters of an instruction file


def read_instruction(path: str) -> str:
    """The text of an instruction file (whitespace folded); NodeError if it is not a readable
    UTF-8 text file of 1 to MAX_INSTRUCTION characters."""
    file = Path(path)
    try:
        if file.is_dir():
            raise NodeError(f"instruction {path}: a directory, not a text file")
        if file.exists() and not file.is_file():
            raise NodeError(f"instruction {path}: not a regular file")
        if file.exists() and file.stat().st_size > 4 * MAX_INSTRUCTION:  # checked before reading it
            raise NodeError(f"instruction {path}: over {4 * MAX_INSTRUCTION} bytes; give 1 to "
                            f"{MAX_INSTRUCTION} characters")
        text = file.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise NodeError(f"instruction {path}: not UTF-8 text") from None
    except OSError as exc:
        raise NodeError(f"instruction {path}: {exc.strerror or exc}") from None
    text = " ".join(text.split())
    if not text or len(text) > MAX_INSTRUCTION:
        raise NodeError(f"instruction {path}: {len(text)} characters; give 1 to {MAX_INSTRUCTION}")
    return text


class LabellerWebNode(NmrmNode):
    executable = "labeller_web"
    PARAMETERS = PARAMETERS

    def __init__(self) -> None:
        self.messages_received = 0
        super().__init__()
        p = self.params
        from ..labelling import FrameStore, LabelQueue, LabelStore, WaitingEpisodes, make_app
        from ..labelling.label_store import WAITING_DIR

        self.info = require_task(p["task"])
        instruction = read_instruction(p["instruction"]) if p["instruction"] else self.info.instruction
        self.task = p["task"]
        team = [str(x).strip() for x in p["people"] if str(x).strip()]
        people = team or [str(p["person"]).strip()]
        for person in people:
            if not person or "/" in person or len(person) > 64 or person != person.strip():
                raise NodeError(f"a person's name must be short and without '/', got {person!r}")
        if len(set(people)) != len(people):
            raise NodeError(f"people must be different names, got {people}")
        if p["assignment"] not in ("split", "overlap"):
            raise NodeError(f"assignment must be split or overlap, got {p['assignment']!r}")
        if unknown_feedback(p["feedback"]):
            raise NodeError(unknown_feedback(p["feedback"]))
        self.feedback = p["feedback"]
        self.people = people
        self.labeller = f"person/{people[0]}"
        tokens = self._tokens(p, people, bool(team))
        self.queue = LabelQueue(self.task, max_episodes=int(p["max_episodes"]), people=tuple(people),
                                assignment=p["assignment"], take_s=float(p["take_s"]),
                                comparisons_per_episode=int(p["comparisons_per_episode"]),
                                pair_window=int(p["pair_window"]))
        self.gold_every = int(p["gold_every"])
        self.gold_returns: dict = {}
        self.finished = 0
        if self.gold_every:
            from ..oracles import make_oracle

            try:
                self.gold_oracle = make_oracle(self.task, str(p["oracle"]))
            except ValueError as exc:
                raise NodeError(f"gold_every needs an oracle: {exc}") from None
        if p["checkpoint"]:
            error = self._use_checkpoint(p["checkpoint"])
            if error:
                raise NodeError(error)
        live_parameter(self, PARAMETERS, "checkpoint", lambda value: self._use_checkpoint(str(value)))
        topic = self.resolve_topic_name(TRAJECTORY_RETURN)
        pref_topic = self.resolve_topic_name(TRAJECTORY_PREFERENCE)
        labels_dir = Path(p["labels_dir"])
        created_labels_dir = not labels_dir.exists()  # removed again if the page cannot be served
        self.stores = {person: LabelStore(p["labels_dir"], f"person/{person}", topic=topic,
                                          preference_topic=pref_topic) for person in people}
        self.store = self.stores[people[0]]
        self.queue.done_before = {person: s.labelled_episodes(self.task) for person, s in self.stores.items()}
        self.queue.compared_before = {(person, *pair) for person, s in self.stores.items()
                                      for pair in s.compared_pairs(self.task)}
        for session in {r for s in self.stores.values() for r in s.repaired}:
            self.get_logger().warning(f"repaired the labels bag of an interrupted session: {session}")
        self.gold_store = LabelStore(p["labels_dir"], "gold/oracle", topic=topic) if self.gold_every else None
        self.waiting = WaitingEpisodes(Path(p["labels_dir"]) / WAITING_DIR, self.task)
        self._offer_waiting_episodes(int(p["max_episodes"]))
        self.follower = EpisodeFollower()
        self.states: list = []
        self.oracle_states: list = []  # gold_every: what the oracle steps with, per step
        self.return_pub = self.create_publisher(TrajectoryReturn, TRAJECTORY_RETURN, STEP_QOS)
        self.pref_pub = self.create_publisher(TrajectoryPreference, TRAJECTORY_PREFERENCE, STEP_QOS)
        self.subs = self.subscribe_steps(EnvObservation, OBSERVATION, self.on_observation, self.info)
        self.frames = FrameStore(int(p["frames_mb"]) * 1_000_000)
        self.frame_sub = self.create_subscription(CompressedImage, FRAME, self.on_frame, STEP_QOS)
        allowed_hosts = None if is_any_address(str(p["host"])) else set()  # filled once the port is bound
        words = {"instruction": instruction, "legend": [list(pair) for pair in self.info.legend]}
        app = make_app(self.queue, self.on_label, words, tokens=tokens or None, frames=self.frames,
                       allowed_hosts=allowed_hosts, team=self._gold_report, on_compare=self.on_compare,
                       feedback=self.feedback)
        try:
            self.server = start_server(app, p)
        except NodeError:
            for store in [*self.stores.values(), *([self.gold_store] if self.gold_store else [])]:
                store.close()  # no label yet: no bag left
            if created_labels_dir:
                for empty in (labels_dir / WAITING_DIR, labels_dir):
                    if empty.is_dir() and not any(empty.iterdir()):
                        empty.rmdir()
            raise
        if allowed_hosts is not None:  # the Host a browser sends for this address and port
            allowed_hosts.update(self.server.allowed_hosts())
        base = self.server.url()
        by_person = {person: tok for tok, person in (tokens or {}).items()}
        for person in people:
            url = base + (f"?token={by_person[person]}" if person in by_person else "")
            self.tell_starter(f"labelling page: {url} (task {self.task}, labeller person/{person}, "
                                   f"{len(self.queue.done_before[person])} episode(s) labelled before, "
                                   f"labels to {self.stores[person].path})")
        self.exit_with_upstream(self.subs)
        self.diagnose(lambda: {"steps": self.messages_received,
            "finished_episodes": self.finished}, rate_of="steps")

    def _offer_waiting_episodes(self, max_episodes: int) -> None:
        """Queue the unlabelled episodes an earlier run of this node kept."""
        before = set().union(*self.queue.done_before.values())
        kept, errors = self.waiting.load({e for e in before if self.queue.done(e)}, max_episodes)
        for line in errors:
            self.get_logger().warning(f"kept episode not offered: {line}")
        offered = 0
        for ep in kept:
            if ep.states.shape[1] != self.info.state_size:
                self.get_logger().warning(f"kept episode {ep.episode} not offered: states of size "
                                          f"{ep.states.shape[1]}, {self.task} has {self.info.state_size}")
                continue
            offered += self.queue.add(ep.episode, ep.states, finished_at=ep.finished_at)
        if offered:
            self.get_logger().info(f"{offered} unlabelled episode(s) from before wait for a label")

    def _use_checkpoint(self, path: str) -> str:
        """Order the queue by `path`'s members' disagreement ('' : oldest first); an error or ''."""
        from ..labelling.active import DisagreementScorer
        from ..mil import CheckpointError

        if not path:
            self.queue.set_scorer(None)
            return ""
        try:
            scorer = DisagreementScorer(path, self.task)
        except (CheckpointError, ValueError) as exc:
            return str(exc)
        self.queue.set_scorer(scorer)
        self.get_logger().info(f"queue ordered {scorer.ordering}, by {path}")
        return ""

    # -- episodes (ROS thread) ---------------------------------------------------------------------
    def on_observation(self, msg: EnvObservation) -> None:
        self.messages_received += 1
        kind, state, why = self.follower.follow(msg, self.task, self.info.state_size)
        if kind in (Kind.DUPLICATE, Kind.BROKEN):
            if kind is Kind.BROKEN and self.follower.just_broke:
                self.get_logger().warning(f"episode {msg.episode} not offered for labelling: {why}")
            return
        if kind is Kind.START:
            self.states, self.oracle_states = [], []
        self.states.append(state)
        if self.gold_every:  # what the oracle steps with: the privileged state where the task has one
            try:
                self.oracle_states.append(oracle_state(msg, state, self.info.privileged_size))
            except ValueError as exc:
                self.oracle_states.append(str(exc))
        if msg.terminated or msg.truncated:
            self.follower.finish()
            states, finished_at = np.stack(self.states), time.time()
            if msg.step > 0:
                self.finished += 1
                if self.gold_every and self.finished % self.gold_every == 0:
                    self._make_gold(int(msg.episode), self.oracle_states, len(states))
            if msg.step > 0 and self.queue.add(int(msg.episode), states, finished_at=finished_at):
                try:
                    self.waiting.save(int(msg.episode), states, finished_at)
                except OSError as exc:
                    self.get_logger().warning(f"episode {msg.episode} not kept on disk (a restart will "
                                              f"not offer it again): {exc}")
                self.get_logger().info(f"episode {msg.episode} ({msg.step} steps) waits for a label")
            self.states, self.oracle_states = [], []

    def _make_gold(self, episode: int, oracle_states: list, length: int) -> None:
        """Episode `episode` is gold: its oracle return is kept (and written to the gold bag), and
        it is asked of everyone. oracle_states: per step what the oracle steps with (the privileged
        state where the task has one; a str: why a step had none); length: the episode's states."""
        from ..oracles import OracleError

        missing = next((s for s in oracle_states if isinstance(s, str)), None)
        try:
            if missing is not None:
                raise ValueError(missing)
            value = float(self.gold_oracle.label(np.stack(oracle_states)[None, :-1]).returns[0])
        except (OracleError, ValueError) as exc:
            self.get_logger().warning(f"episode {episode} is not a gold episode: {exc}")
            return
        self.gold_returns[episode] = value
        self.queue.gold.add(episode)
        self.gold_store.append(self.task, episode, length - 1, value)

    def _gold_report(self) -> dict:
        """/api/team's gold figures: per person, gold episodes labelled and the mean absolute error."""
        gold = {}
        for person in self.people:
            errs = [abs(r.value - self.gold_returns[r.episode]) for r in self.queue.history(person)
                    if r.episode in self.gold_returns]
            gold[person] = {"n": len(errs), "mae": float(np.mean(errs)) if errs else None}
        return {"gold": gold, "gold_episodes": len(self.gold_returns)}

    def _tokens(self, p: dict, people: list, team: bool) -> dict:
        """Access token -> person. One person: `token`, or one generated (none with
        require_token:=false on loopback). A team: a token per person, kept in labels_dir."""
        import json
        import os

        if not team:
            token = str(p["token"])
            if not token and (p["host"] not in LOOPBACK or p["require_token"]):
                token = secrets.token_urlsafe(24)
            return {token: people[0]} if token else {}
        if str(p["token"]):
            raise NodeError("token is for one person; a team (people) gets a token per person")
        path = Path(p["labels_dir"]) / ".team_tokens.json"
        kept = {}
        try:
            kept = {str(k): str(v) for k, v in json.loads(path.read_text()).items()}
        except (OSError, ValueError, AttributeError):
            pass
        by_person = {person: tok for person, tok in kept.items() if person in people and len(tok) >= 20}
        for person in people:
            by_person.setdefault(person, secrets.token_urlsafe(24))
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            with os.fdopen(fd, "w") as f:
                json.dump(by_person, f)
        except OSError as exc:
            raise NodeError(f"cannot keep the team's tokens in {path}: {exc.strerror or exc}") from None
        return {tok: person for person, tok in by_person.items()}

    def on_frame(self, msg: CompressedImage) -> None:
        from ..tasks.frames import FRAME_FORMATS, parse_frame_id

        where = parse_frame_id(msg.header.frame_id)
        if where is None or msg.format not in FRAME_FORMATS:
            return  # not a frame of ours (another publisher on the topic): ignored
        self.frames.add(where[0], where[1], msg.format, bytes(msg.data))

    # -- labels (web server's thread) --------------------------------------------------------------
    def on_label(self, label, episode) -> None:
        stamp = time.time_ns()
        labeller = f"person/{label.person}"
        self.stores[label.person].append(self.task, episode.episode, episode.length, label.value, stamp)
        if self.queue.done(episode.episode):
            self.waiting.remove(episode.episode)
        out = TrajectoryReturn(task=self.task, episode=episode.episode, length=episode.length,
                               return_value=float(label.value), labeller=labeller)
        out.header.stamp.sec, out.header.stamp.nanosec = stamp // 10**9, stamp % 10**9
        self.return_pub.publish(out)
        what = "corrected" if label.corrections else "labelled"
        who = f"{labeller} " if len(self.people) > 1 else ""
        self.get_logger().info(f"{who}{what} episode {episode.episode}: return {label.value:g}")

    def on_compare(self, comparison, ep_a, ep_b) -> None:
        """A person's comparison: written to their labels bag, then published."""
        stamp = time.time_ns()
        message = self.stores[comparison.person].append_comparison(
            self.task, ep_a.episode, ep_a.length, ep_b.episode, ep_b.length, comparison.p, stamp)
        out = TrajectoryPreference(task=self.task, episode_a=ep_a.episode, length_a=ep_a.length,
                                   episode_b=ep_b.episode, length_b=ep_b.length,
                                   preference=message["preference"], labeller=message["labeller"])
        out.header.stamp.sec, out.header.stamp.nanosec = stamp // 10**9, stamp % 10**9
        self.pref_pub.publish(out)
        for ep in (ep_a, ep_b):
            if self.feedback == "preferences" and not self.queue.needs_comparisons(ep.episode):
                self.waiting.remove(ep.episode)
        what = "corrected" if comparison.corrections else "compared"
        verdict = {1.0: "left better", 0.0: "right better", 0.5: "equal"}[comparison.p]
        self.get_logger().info(f"{message['labeller']} {what} episodes {ep_a.episode} and {ep_b.episode}: {verdict}")

    def close(self) -> None:
        self.server.stop()
        for store in self.stores.values():
            store.close()
            compared = f", {store.compared} comparison(s)" if store.compared else ""
            self.get_logger().info(f"{store.written} label(s){compared} this session, in {store.path}")
        if self.gold_store is not None:
            self.gold_store.close()


def main(args=None) -> int:
    return LabellerWebNode.main(args)


if __name__ == "__main__":
    raise SystemExit(main())
