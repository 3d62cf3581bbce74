"""Episodes <-> bags: the bag is the project's one dataset format.

`write_dataset_bag` writes a `TrajectoryDataset` (e.g. a screened dataset) as the live graph
would record it: per episode, EnvObservation steps 0..L (the last one truncated/terminated),
AgentAction steps 0..L-1, OracleStep steps 0..L-1, and one TrajectoryReturn from `oracle/<task>`
(on an image task each observation's pixels as its PNG on `/nmrm/observation_image`, as env_sim
sends them, and the state's other values in the EnvObservation: the labelling page and the LeRobot
export show people those images);
then the dataset's comparisons (`TrajectoryDataset.preferences`) as TrajectoryPreference messages.

`load_bag_dataset` builds MIL bags back from one or more bags: instances from the observations
(on an image task with the pixels of their observation images put back in front; for a task spec
with a frozen encoder, from the episodes of the same spec without it, each image encoded),
labels from TrajectoryReturn messages (in the same bag, or in labels-only bags given beside it,
joined by (source, task, episode)), comparisons from TrajectoryPreference messages joined the same
way (an episode that is only compared has return NaN), oracle ground truth from OracleStep if
present. An episode's
**source** is the namespace of its topics: one recorder can record several graphs
(`/robot1/nmrm/...`, `/robot2/nmrm/...`) and their equal episode numbers do not collide; the
dataset's `meta["sources"]` and `meta["episodes"]` say where each trajectory came from. Episodes that cannot be
used are skipped and counted by reason, never used silently:
  missing_steps, conflicting_duplicates, no_final_observation, wrong_state_size, missing_image, no_label,
  label_length_mismatch; comparisons of an episode not used, or of another length than it has,
  are counted the same way (comparison_of_unused_episode, comparison_length_mismatch).
Identical repeated observations (env_sim re-publishing after an action timeout) are not errors.
"""

from __future__ import annotations

import shutil
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..datasets.trajectories import TrajectoryDataset
from ..tasks import task_info
from .label_records import comparison_record, label_record
from .observation_images import IMAGE_TOPIC, IMAGE_TYPE, BagImages
from .reader import BagError, iter_decoded
from .schemas import TOPIC_TYPES, split_topic
from .writer import BagWriter

T_OBS = "nmrm_msgs/msg/EnvObservation"
T_ACT = "nmrm_msgs/msg/AgentAction"
T_RET = "nmrm_msgs/msg/TrajectoryReturn"
T_ORC = "nmrm_msgs/msg/OracleStep"
T_PREF = "nmrm_msgs/msg/TrajectoryPreference"
TOPIC = {t: topic for topic, t in TOPIC_TYPES.items()}
#: log time of the first message of generated bags (2025-01-01T00:00:00Z), and the step period
BASE_TIME_NS = 1_735_689_600 * 10**9
STEP_NS = 10_000_000


def stamped_header(t_ns: int, frame: str = "") -> dict:
    """A std_msgs/Header as a dict: the stamp of `t_ns` nanoseconds and `frame` as frame_id."""
    return {"stamp": {"sec": t_ns // 10**9, "nanosec": t_ns % 10**9}, "frame_id": frame}


def write_dataset_bag(ds: TrajectoryDataset, path: str | Path, labeller: str | None = None,
                      start_ns: int = BASE_TIME_NS, first_episode: int = 0,
                      include_oracle: bool = True, returns: bool = True,
                      preference_labeller: str | None = None) -> Path:
    """Write every trajectory of `ds` as an episode (numbered from `first_episode`), with its
    return label from `labeller` (default oracle/<task>; returns=False: none), then each of its
    comparisons from `preference_labeller` (default: `labeller`). A task whose state is an image
    also gets each step's frame on /nmrm/frame (PNG, `frames.image_state_frame`), as env_sim
    render:=true records it, so the labelling page plays the episodes."""
    if ds.final_states is None:
        raise ValueError("the dataset has no final observations (toy bags are not episodes)")
    labeller = labeller or f"oracle/{ds.task}"
    path = Path(path)
    if path.exists() and (not path.is_dir() or any(path.iterdir())):
        raise FileExistsError(f"bag directory {path} exists and is not empty")
    # written beside and renamed when complete: an interrupted or failed write leaves nothing behind
    partial = path.with_name(path.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    try:
        _write_episodes(ds, partial, labeller, start_ns, first_episode, include_oracle, path.name, returns,
                        preference_labeller or labeller)
        if path.exists():
            path.rmdir()
        partial.rename(path)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return path


def _write_episodes(ds, path, labeller, start_ns, first_episode, include_oracle, name, returns,
                    preference_labeller) -> None:
    from ..tasks import task_info
    from ..tasks.frames import frame_id
    from ..tasks.image_states import IMAGE_STATE_FORMAT, encode_image_state, vector_part

    t = start_ns
    image_shape = task_info(ds.task).image_shape  # an image state: its pixels as observation images
    with BagWriter(path, file_name=f"{name}_0.mcap") as bag:
        for i in range(len(ds)):
            e = first_episode + i
            length = int(ds.lengths[i])
            for step in range(length + 1):
                final = step == length
                state = ds.final_states[i] if final else ds.states[i, step]
                privileged = () if ds.privileged is None or final else ds.privileged[i, step]
                if image_shape:  # the pixels as the observation image, as env_sim sends them
                    bag.write_dict(IMAGE_TOPIC, IMAGE_TYPE, {
                        "header": stamped_header(t, frame_id(e, step)), "format": IMAGE_STATE_FORMAT,
                        "data": encode_image_state(state, image_shape)}, t)
                bag.write_dict(TOPIC[T_OBS], T_OBS, {
                    "header": stamped_header(t, ds.task), "task": ds.task, "episode": e, "step": step,
                    "state": [float(x) for x in (vector_part(state, image_shape) if image_shape else state)],
                    "terminated": False, "truncated": final, "privileged": [float(x) for x in privileged]}, t)
                if not final:
                    if ds.actions is not None:
                        a = np.asarray(ds.actions[i, step], dtype=np.float64).reshape(-1)
                        bag.write_dict(TOPIC[T_ACT], T_ACT, {
                            "header": stamped_header(t), "episode": e, "step": step,
                            "action": [float(x) for x in a]}, t + 1)
                    if include_oracle:
                        bag.write_dict(TOPIC[T_ORC], T_ORC, {
                            "header": stamped_header(t, ds.task), "episode": e, "step": step,
                            "hidden": [float(x) for x in ds.hidden[i, step]],
                            "reward": float(ds.rewards[i, step])}, t + 2)
                t += STEP_NS
            if returns:
                bag.write_dict(TOPIC[T_RET], T_RET, {
                    "header": stamped_header(t), "task": ds.task, "episode": e, "length": length,
                    "return_value": float(ds.returns[i]), "labeller": labeller}, t)
            t += STEP_NS
        for a, b, p in ([] if ds.preferences is None else ds.preferences):
            bag.write_dict(TOPIC[T_PREF], T_PREF, preference_message(
                ds.task, first_episode + int(a), int(ds.lengths[int(a)]), first_episode + int(b),
                int(ds.lengths[int(b)]), float(p), preference_labeller, t), t)
            t += STEP_NS


def preference_message(task: str, episode_a: int, length_a: int, episode_b: int, length_b: int,
                       p: float, labeller: str, t_ns: int, source_a: str = "", source_b: str = "") -> dict:
    """A TrajectoryPreference as a dict; p = P(a better): 1 -> A_BETTER, 0 -> B_BETTER, 0.5 -> EQUAL."""
    return {"header": stamped_header(t_ns), "task": task, "source_a": source_a, "episode_a": int(episode_a),
            "length_a": int(length_a), "source_b": source_b, "episode_b": int(episode_b),
            "length_b": int(length_b), "preference": int(round(2 * p - 1)), "labeller": labeller}


@dataclass
class BagDatasetReport:
    """What `load_bag_dataset` found: counts per reason, labellers seen, episodes used."""

    episodes_seen: int = 0
    episodes_used: int = 0
    skipped: Counter = field(default_factory=Counter)
    labellers: Counter = field(default_factory=Counter)
    with_oracle: int = 0
    comparisons_seen: int = 0
    comparisons_used: int = 0

    def __str__(self) -> str:
        skipped = ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items())) or "none"
        compared = (f"; comparisons: {self.comparisons_seen} in the bags, {self.comparisons_used} used"
                    if self.comparisons_seen else "")
        return (f"{self.episodes_seen} episodes in the bags, {self.episodes_used} used; skipped: "
                f"{skipped}; labellers: {dict(self.labellers)}; with oracle ground truth: "
                f"{self.with_oracle}{compared}")


def _source(topic: str) -> str:
    """The namespace of an nmrm topic; '' for a topic not named like ours (e.g. remapped)."""
    try:
        return split_topic(topic)[0]
    except ValueError:
        return ""


def _read(path: Path):
    """Observations and labels keyed by (source, task, episode), oracle steps by (source, episode),
    comparisons as (key a, key b, message), observation images' PNG bytes by (source, episode,
    step); the source is the namespace of the topic ('' for /nmrm/...), or a comparison's own
    source_a / source_b where given."""
    obs, labels, oracle, prefs, images = defaultdict(list), defaultdict(list), defaultdict(dict), [], BagImages()
    for topic, type_name, _, m in iter_decoded(path):
        if images.take(topic, type_name, m) or type_name not in (T_OBS, T_RET, T_ORC, T_PREF):
            continue
        source = _source(topic)
        if type_name == T_PREF:
            prefs.append(((m.source_a or source, m.task, int(m.episode_a)),
                          (m.source_b or source, m.task, int(m.episode_b)), m))
        elif type_name == T_OBS:
            obs[(source, m.task, int(m.episode))].append(m)
        elif type_name == T_RET:
            labels[(source, m.task, int(m.episode))].append(m)
        else:
            oracle[(source, int(m.episode))][int(m.step)] = m
    return obs, labels, oracle, prefs, images


def load_bag_dataset(paths: list, task: str | None = None, labeller: str | None = None
                     ) -> tuple[TrajectoryDataset, BagDatasetReport]:
    """MIL bags from recorded episodes; see the module docstring for the validation rules.

    A bag with observations is a recording; a bag with labels only is a labels bag whose labels
    join the recordings by (task, episode) (an ambiguous join is an error). With several labellers
    on one episode, `labeller` chooses; without it that is an error naming them. Comparisons of
    every labeller are kept (each is one answer), only those of `labeller` if it is given.
    """
    recordings, extra_labels, comparisons = [], defaultdict(list), []
    for path in paths:
        obs, labels, oracle, prefs, images = _read(Path(path))
        comparisons.extend(c for c in prefs if labeller is None or c[2].labeller == labeller)
        if obs:
            recordings.append((Path(path), obs, labels, oracle, images))
        else:
            for key, ls in labels.items():
                extra_labels[key].extend(ls)
    if not recordings:
        raise BagError(f"no EnvObservation messages in {', '.join(map(str, paths))}")
    tasks = {k[1] for _, obs, *_ in recordings for k in obs}
    if task is None:
        if len(tasks) != 1:
            raise BagError(f"the bags hold episodes of several tasks {sorted(tasks)}; choose one")
        task = tasks.pop()
    wanted, task = task, _recorded_as(task, tasks)  # a frozen encoder's spec reads its camera task's episodes
    info = task_info(task)
    for key in extra_labels:
        owners = [p for p, obs, *_ in recordings if key in obs]
        if len(owners) > 1:
            raise BagError(f"labels-only bag labels {key}, which is in several recordings "
                           f"({', '.join(map(str, owners))}); give them separately")

    report = BagDatasetReport()
    comparisons = [c for c in comparisons if c[2].task == task]
    compared = {key for a, b, _ in comparisons for key in (a, b)}
    rows, index = [], {}
    for _, obs, labels, oracle, images in recordings:
        for key in sorted(k for k in obs if k[1] == task):
            report.episodes_seen += 1
            messages, reason = _with_pixels(obs[key], images, key[0], info)
            row, reason = (None, reason) if reason else _episode(
                messages, labels.get(key, []) + extra_labels.get(key, []), oracle.get((key[0], key[2]), {}),
                info.state_size, labeller, report, compared=key in compared)
            if reason:
                report.skipped[reason] += 1
            else:
                index[key] = len(rows)
                rows.append(row + (key[0],))
    report.episodes_used = len(rows)
    if not rows:
        raise BagError(f"no usable episode of task {task!r}: {report}")
    ds = _stack(task, rows, info.state_size, report)
    if comparisons:
        ds.preferences = _comparisons(comparisons, index, ds, report)
        ds.meta["report"] = str(report)
    return (ds if wanted == task else _encoded(ds, wanted)), report


def _recorded_as(task: str, recorded: set) -> str:
    """The task whose episodes the bags hold for `task`: itself, or, for a task spec with a frozen
    encoder (`encoder=`) that the bags do not hold, the camera task they do hold that is the same
    spec without the encoder (its images are then encoded: `_encoded`)."""
    from dataclasses import replace

    from ..tasks.gym_task import TaskSpecError, is_task_spec, parse_task_spec

    if task in recorded or not is_task_spec(task):
        return task
    try:
        spec = parse_task_spec(task)
    except TaskSpecError:
        return task
    if spec.encoder is None:
        return task
    plain = replace(spec, text="", encoder=None, encoder_weights=None)
    for other in sorted(t for t in recorded if is_task_spec(t)):
        try:
            if replace(parse_task_spec(other), text="") == plain:
                return other
        except TaskSpecError:
            continue
    return task


def _encoded(ds: TrajectoryDataset, task: str) -> TrajectoryDataset:
    """`ds`, episodes of a camera task, as episodes of `task`, the same spec with a frozen encoder:
    each step's image replaced by the encoder's features (the rest of the state kept), as the
    task's env would have given them; meta `encoded_from` (the recorded task) and `encoder_sha256`.
    BagError (one line) if the encoder does not load or run."""
    from dataclasses import replace

    from ..tasks.frozen_encoder import EncoderError
    from ..tasks.gym_task import TaskSpecError, encoder_weights_sha256, task_encoder

    shape = task_info(ds.task).image_shape
    pixels = int(np.prod(shape))
    try:
        size = task_info(task).state_size
        encoder = task_encoder(task, shape)

        def encode(state: np.ndarray) -> np.ndarray:
            image = np.asarray(state[:pixels]).astype(np.uint8).reshape(shape)
            return np.concatenate([encoder(image), state[pixels:]])

        states = np.zeros((len(ds), ds.states.shape[1], size), np.float32)
        for i, n in enumerate(ds.lengths):
            states[i, :n] = [encode(s) for s in ds.states[i, :n]]
        final = np.stack([encode(s) for s in ds.final_states]).astype(np.float32)
    except (EncoderError, TaskSpecError) as exc:
        raise BagError(f"episodes of {ds.task} read as {task}: {exc}") from None
    meta = {**ds.meta, "encoded_from": ds.task}
    weights = encoder_weights_sha256(task)
    if weights:
        meta["encoder_sha256"] = weights[1]
    return replace(ds, task=task, states=states, final_states=final, meta=meta)


def _comparisons(comparisons: list, index: dict, ds: TrajectoryDataset, report: BagDatasetReport) -> np.ndarray:
    """(m, 3) rows (a, b, p) of the comparisons whose both episodes are in the dataset with the
    lengths the labeller saw (their records in ds.meta["comparisons"], provenance as
    meta["labels"] is for returns); the others counted in the report."""

    out, records = [], []
    report.comparisons_seen = len(comparisons)
    for a, b, m in comparisons:
        if a not in index or b not in index:
            report.skipped["comparison_of_unused_episode"] += 1
        elif (int(m.length_a), int(m.length_b)) != (int(ds.lengths[index[a]]), int(ds.lengths[index[b]])):
            report.skipped["comparison_length_mismatch"] += 1
        elif int(m.preference) not in (-1, 0, 1):
            report.skipped["comparison_unknown_preference"] += 1
        else:
            p = (int(m.preference) + 1) / 2
            out.append((index[a], index[b], p))
            stamp = int(m.header.stamp.sec) * 10**9 + int(m.header.stamp.nanosec)
            records.append(comparison_record(m.task, a[0], a[2], m.length_a, b[2], m.length_b, p, m.labeller, stamp))
    report.comparisons_used = len(out)
    ds.meta["comparisons"] = records
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def _with_pixels(messages, images: BagImages, source: str, info) -> tuple:
    """(messages, '') with an image task's pixels put back in front of each observation's state
    (`BagImages.whole_state`); (None, 'missing_image') if an image is missing or cannot be decoded."""
    if not info.image_shape:
        return messages, ""
    from types import SimpleNamespace

    out = []
    for m in messages:
        try:
            state = images.whole_state(source, m, info)
        except ValueError:
            return None, "missing_image"
        out.append(SimpleNamespace(episode=m.episode, step=m.step, terminated=m.terminated, truncated=m.truncated,
                                   privileged=getattr(m, "privileged", ()), state=state))
    return out, ""


def _episode(messages, labels, oracle, state_size, labeller, report, compared=False):
    by_step: dict = {}
    for m in messages:
        state = np.asarray(m.state, dtype=np.float32)
        if state.shape != (state_size,) or not np.all(np.isfinite(state)):
            return None, "wrong_state_size"
        if m.step in by_step:
            prev = by_step[m.step]
            if not (np.array_equal(prev[0], state) and prev[1] == (m.terminated, m.truncated)):
                return None, "conflicting_duplicates"
            continue
        privileged = np.asarray(getattr(m, "privileged", ()), dtype=np.float32)  # absent from older bags
        by_step[int(m.step)] = (state, (bool(m.terminated), bool(m.truncated)), privileged if privileged.size else None)
    length = max(by_step)
    if sorted(by_step) != list(range(length + 1)):
        return None, "missing_steps"
    if not any(by_step[length][1]) or any(any(by_step[t][1]) for t in range(length)) or length == 0:
        return None, "no_final_observation"
    names = sorted({m.labeller for m in labels})
    chosen = labels if labeller is None else [m for m in labels if m.labeller == labeller]
    if not chosen:
        if not compared:
            return None, "no_label"
        return _unlabelled(by_step, length, oracle, messages, report), None  # only compared: return NaN
    if labeller is None and len(names) > 1:
        raise BagError(f"episode {messages[0].episode} has labels from several labellers {names}; "
                       f"choose one (--labeller)")
    label = chosen[-1]
    if int(label.length) != length:
        return None, "label_length_mismatch"
    report.labellers[label.labeller] += 1
    states, rewards, hidden, privileged = _steps(by_step, length, oracle, report)
    stamp = label.header.stamp
    return (states, by_step[length][0], float(label.return_value), rewards, hidden,
            int(messages[0].episode), str(label.labeller), int(stamp.sec) * 10**9 + int(stamp.nanosec),
            privileged), None


def _unlabelled(by_step, length, oracle, messages, report) -> tuple:
    """The row of an episode that is compared but has no return label: return NaN, no labeller."""
    states, rewards, hidden, privileged = _steps(by_step, length, oracle, report)
    return (states, by_step[length][0], float("nan"), rewards, hidden, int(messages[0].episode), "", 0, privileged)


def _steps(by_step, length, oracle, report) -> tuple:
    """(states (L, d), oracle rewards (L,) or None, oracle hidden (L, k) or None, privileged
    states (L, p) or None)."""
    states = np.stack([by_step[t][0] for t in range(length)])
    privileged = (np.stack([by_step[t][2] for t in range(length)])
                  if all(by_step[t][2] is not None for t in range(length)) else None)
    have_oracle = all(t in oracle for t in range(length))
    report.with_oracle += int(have_oracle)
    rewards = np.array([oracle[t].reward for t in range(length)], np.float64) if have_oracle else None
    hidden = (np.array([list(oracle[t].hidden) for t in range(length)], np.float64)
              if have_oracle else None)
    return states, rewards, hidden, privileged


def _stack(task, rows, state_size, report) -> TrajectoryDataset:
    n, horizon = len(rows), max(len(r[0]) for r in rows)
    k = max((r[4].shape[1] for r in rows if r[4] is not None), default=0)
    states = np.zeros((n, horizon, state_size), np.float32)
    final = np.zeros((n, state_size), np.float32)
    lengths = np.zeros(n, np.int64)
    returns = np.zeros(n, np.float64)
    rewards = np.zeros((n, horizon), np.float64)
    hidden = np.zeros((n, horizon, k), np.float64)
    episodes = np.zeros(n, np.int64)
    for i, (s, f, g, r, h, e, *_) in enumerate(rows):
        lengths[i] = len(s)
        states[i, : len(s)] = s
        final[i] = f
        returns[i] = g
        episodes[i] = e
        if r is not None:
            rewards[i, : len(s)] = r
            hidden[i, : len(s), : h.shape[1]] = h
    meta = {"source": "bags", "report": str(report), "episodes": episodes.tolist(),
            "sources": [r[9] for r in rows],
            "labels": [label_record(task, r[9], r[5], len(r[0]), r[2], r[6], r[7]) for r in rows],
            "oracle_ground_truth": report.with_oracle == n}
    privileged = None
    if all(r[8] is not None for r in rows):  # every episode recorded its privileged states
        privileged = np.zeros((n, horizon, rows[0][8].shape[1]), np.float32)
        for i, r in enumerate(rows):
            privileged[i, : len(r[8])] = r[8]
    return TrajectoryDataset(task, states, lengths, returns, rewards, hidden, final_states=final, meta=meta,
                             privileged=privileged)
