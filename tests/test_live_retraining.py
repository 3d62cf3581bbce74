"""Live retraining: labels arrive -> the trainer writes a new checkpoint -> the reward model serves
it from the next episode on, never mid-episode. Nodes are real processes; the test publishes the
observations and labels itself, so it knows exactly where each episode boundary is."""

from __future__ import annotations


import numpy as np
import pytest
import torch

from nmrm_ros.testing.graph import Capture, finish, start
from nmrm_msgs.msg import EnvObservation, TrajectoryPreference, TrajectoryReturn
from nmrm_ros.labelling import LabelQueue
from nmrm_ros.labelling.active import DisagreementScorer
from nmrm_ros.labelling.training_set import TrainingSet
from nmrm_ros.mil import OnlineRewardModel, Run
from nmrm_ros.mil.checkpoint import EnsembleInfo, load_checkpoint
from nmrm_ros.mil.ensemble import init_ensemble
from nmrm_ros.mil.models import model_config
from nmrm_ros.mil.retrain import retrain, retrain_splits
from nmrm_ros.ros.topics import OBSERVATION, TRAJECTORY_PREFERENCE, TRAJECTORY_RETURN


def _ensemble_checkpoint(path, seeds, hidden_size: int = 2):
    ens = init_ensemble(model_config("csc_lstm", "key", 2, hidden_size=hidden_size), seeds)
    Run.of(ens, "key", ensemble=EnsembleInfo(len(seeds), 0, seeds=list(seeds))).save(path)
    return path.with_suffix(".pt"), ens


def _states(episode: int, length: int) -> np.ndarray:
    """A seeded random walk in the arena: (length + 1, 2)."""
    rng = np.random.default_rng(episode)
    return np.clip(0.5 + np.cumsum(rng.normal(0, 0.05, (length + 1, 2)), axis=0), 0, 1).astype(np.float32)


# -- core (no ROS) -------------------------------------------------------------------------------
def test_training_set_joins_latest_labels_by_episode_and_length():
    ts = TrainingSet("key", 2)
    ts.add_episode(0, _states(0, 10))
    ts.add_episode(1, _states(1, 12))
    assert ts.add_label("person/a", 0, 10, 3.0)
    assert not ts.add_label("person/a", 0, 10, 4.0)       # a correction, not a new label
    assert ts.add_label("person/b", 0, 10, 5.0)           # another person's opinion: its own bag
    assert ts.add_label("person/a", 1, 11, 1.0)           # wrong length: not joined
    assert ts.add_label("person/a", 2, 10, 1.0)           # no such episode (yet)
    ds = ts.dataset()
    assert ds.returns.tolist() == [4.0, 5.0] and ds.lengths.tolist() == [10, 10]
    np.testing.assert_array_equal(ds.states[0, :10], _states(0, 10)[:-1])
    np.testing.assert_array_equal(ds.final_states[0], _states(0, 10)[-1])
    ts.add_episode(2, _states(2, 10))
    assert len(ts.dataset()) == 3


def test_retrain_splits_hold_out_a_fifth_and_bootstrap_the_rest():
    splits = retrain_splits(11, 3, seed=4)
    val = splits[0][1]
    assert len(val) == 2 and all(np.array_equal(v, val) for _, v in splits)
    for train, _ in splits:
        assert len(train) == 9 and not set(train) & set(val)
    assert len({tuple(t) for t, _ in splits}) == 3        # each member its own resample
    with pytest.raises(ValueError, match="at least 2"):
        retrain_splits(1, 3, 0)


def test_a_warm_started_retrain_keeps_serving_the_member_it_continues(tmp_path):
    """The agent learnt on the serving member's hidden units: a retrain that continues the ensemble
    serves the same member (its successor), whichever member is now best on validation; a fresh
    one, or one model copied into every member, serves the best."""
    from nmrm_ros.datasets.toy import make_toy_dataset

    ds = make_toy_dataset("dial", 40, seed=0)
    first = retrain(ds, tmp_path / "v0", members=3, max_epochs=2, seed=0)
    assert first["start"].startswith("fresh")
    for served in range(3):
        ens, _ = load_checkpoint(first["checkpoint"], task="dial")
        ens.serving_member.fill_(served)
        Run.of(ens, "dial", ensemble=EnsembleInfo(3, served, seeds=[0, 1, 2])).save(tmp_path / f"s{served}")
        again = retrain(ds, tmp_path / f"v1_{served}", members=3, max_epochs=2, seed=1, init=str(tmp_path / f"s{served}.pt"))
        assert again["start"].startswith("warm-started")
        assert int(load_checkpoint(again["checkpoint"], task="dial")[0].serving_member) == served
    one = init_ensemble(model_config("csc_lstm", "dial", ds.state_size), [5])
    Run.of(one, "dial").save(tmp_path / "one")
    spread = retrain(ds, tmp_path / "v1_one", members=3, max_epochs=2, seed=1, init=str(tmp_path / "one.pt"))
    model, meta = load_checkpoint(spread["checkpoint"], task="dial")
    assert int(model.serving_member) == int(np.argmin(meta.metrics["member_val_loss"]))


def test_queue_asks_first_where_the_members_disagree(tmp_path):
    path, ens = _ensemble_checkpoint(tmp_path / "ens", [0, 1, 2])
    scorer = DisagreementScorer(str(path), "key")
    q = LabelQueue("key")
    for e in range(4):
        q.add(e, _states(e, 100), finished_at=float(e))
    assert [e.episode for e in q.pending()] == [0, 1, 2, 3]
    q.set_scorer(scorer)
    spreads = {}
    for e in range(4):
        x = torch.as_tensor(_states(e, 100)[:-1])[None]
        with torch.no_grad():
            returns = ens.eval()(x, torch.tensor([100])).returns[:, 0]
        spreads[e] = float(returns.std(unbiased=False))
        assert q.episodes[e].spread == pytest.approx(spreads[e], rel=1e-5)
        assert q.episodes[e].predicted == pytest.approx(float(returns.mean()), rel=1e-5, abs=1e-6)
    assert [e.episode for e in q.pending()] == sorted(spreads, key=lambda e: -spreads[e])
    assert q.pending()[0].why.startswith("models disagree: return ")
    q.set_scorer(None)
    assert [e.episode for e in q.pending()] == [0, 1, 2, 3]


# -- nodes ---------------------------------------------------------------------------------------
class Driver(Capture):
    """The test as env_sim and labeller: publishes observations step by step, and labels."""

    def __init__(self) -> None:
        super().__init__()
        self.obs = self.publisher(EnvObservation, OBSERVATION)
        self.labels = self.publisher(TrajectoryReturn, TRAJECTORY_RETURN)
        self.comparisons = self.publisher(TrajectoryPreference, TRAJECTORY_PREFERENCE)
        self.param_clients: dict = {}

    def wait_for_subscribers(self, observation: int, labels: int = 0, timeout: float = 60.0) -> None:
        """Until `observation` and `labels` nodes subscribe (besides this one's own subscriptions)."""
        ok = self.spin_until(lambda: self.obs.get_subscription_count() >= observation + 1
                             and self.labels.get_subscription_count() >= labels + 1
                             and self.subs["reward_step"].get_publisher_count() >= 1, timeout)
        assert ok, (self.obs.get_subscription_count(), self.labels.get_subscription_count())

    def play(self, episode: int, states: np.ndarray, steps: range | None = None) -> list:
        """Publish steps (default all) of an episode (the last state final); return their RewardSteps."""
        steps = range(len(states)) if steps is None else steps
        got = []
        for t in steps:
            before = len(self.msgs["reward_step"])
            final = t == len(states) - 1
            self.obs.publish(EnvObservation(task="key", episode=episode, step=t, state=states[t].tolist(),
                                            terminated=False, truncated=final))
            assert self.spin_until(lambda: len(self.msgs["reward_step"]) > before, 20), (episode, t)
            got.append(self.msgs["reward_step"][-1])
        return got

    def label(self, episode: int, length: int, value: float, labeller: str = "person/test") -> None:
        self.labels.publish(TrajectoryReturn(task="key", episode=episode, length=length,
                                             return_value=value, labeller=labeller))

    def compare(self, a: int, b: int, length: int, preference: int, labeller: str = "person/test") -> None:
        self.comparisons.publish(TrajectoryPreference(task="key", episode_a=a, length_a=length, episode_b=b,
                                                      length_b=length, preference=preference, labeller=labeller))

    def _call(self, node: str, request) -> object:
        """The answer of `node`'s parameter service to `request(client)` (a future), as `ros2 param`
        gets it, with one client per node. A reply can be lost when the server has not discovered
        a new client's reply reader yet (two DDS topics; ros2/rcl#1048): after 10 s unanswered the
        request is sent again, 3 times in all (get and set of one value are idempotent)."""
        from rclpy.parameter_client import AsyncParameterClient

        if node not in self.param_clients:
            self.param_clients[node] = AsyncParameterClient(self.node, node)
        client = self.param_clients[node]
        assert self.spin_until(client.services_are_ready, 20)
        for _ in range(3):
            future = request(client)
            if self.spin_until(future.done, 10):
                return future.result()
        raise AssertionError(f"{node}'s parameter service did not answer 3 requests")

    def set_checkpoint(self, node: str, path) -> tuple:
        """(successful, reason) of setting `node`'s checkpoint parameter, as `ros2 param set` does."""
        from rclpy.parameter import Parameter

        result = self._call(node, lambda c: c.set_parameters([Parameter("checkpoint", value=str(path))]))
        return result.results[0].successful, result.results[0].reason

    def get_checkpoint(self, node: str) -> str:
        return self._call(node, lambda c: c.get_parameters(["checkpoint"])).values[0].string_value


def test_reward_model_swaps_a_new_checkpoint_only_at_the_next_episode(ros_domain, tmp_path):
    """Checkpoint B set in the middle of episode 0: the rest of episode 0 is served by A, episode 1
    by B (its rewards are B's). A checkpoint of another hidden size, or a missing one, is refused
    with its reason and serving goes on unchanged."""
    a, _ = _ensemble_checkpoint(tmp_path / "key_a", [0, 1])
    b, ens_b = _ensemble_checkpoint(tmp_path / "key_b", [5, 6])
    c, _ = _ensemble_checkpoint(tmp_path / "key_c", [7, 8], hidden_size=3)
    proc = start("reward_model", task="key", mode="model", checkpoint=a)
    driver = Driver()
    try:
        driver.wait_for_subscribers(observation=1)
        ep0, ep1 = _states(0, 9), _states(1, 9)
        first = driver.play(0, ep0, range(5))
        ok, reason = driver.set_checkpoint("reward_model", c)
        assert not ok and "hidden state has size 6" in reason, reason
        ok, reason = driver.set_checkpoint("reward_model", tmp_path / "missing")
        assert not ok and "checkpoint file missing" in reason, reason
        assert driver.set_checkpoint("reward_model", b) == (True, "")
        rest = driver.play(0, ep0, range(5, 10))
        assert [m.source for m in first + rest] == ["key_a"] * 10
        second = driver.play(1, ep1)
        assert [m.source for m in second] == ["key_b"] * 10
        online = OnlineRewardModel(ens_b)
        want = [online.step(s)[0] for s in ep1]
        np.testing.assert_allclose([m.reward for m in second], want, rtol=1e-5, atol=1e-6)
    finally:
        driver.close()
        proc.terminate()
        code, out = finish(proc)
    assert "refused" in out and "now serving key_b" in out, out


def test_labels_retrain_and_the_reward_model_serves_the_new_version(ros_domain, tmp_path):
    """Two episodes labelled by person/test (and one by the oracle, ignored): the trainer writes
    key_v001 (warm-started from A), tells the reward model, which serves it from the next
    episode; the labelled set is exactly the two person labels."""
    a, _ = _ensemble_checkpoint(tmp_path / "key_a", [0, 1])
    out_dir = tmp_path / "checkpoints"
    reward = start("reward_model", task="key", mode="model", checkpoint=a)
    trainer = start("trainer", task="key", retrain_every=2, members=2, max_epochs=3, checkpoint=a,
                    out_dir=out_dir, labeller_web="''", labeller="[person/test, person/nobody]")
    driver = Driver()
    sources = None
    try:
        driver.wait_for_subscribers(observation=2, labels=1)
        episodes = {e: _states(e, 20) for e in range(3)}
        for e in (0, 1):
            assert {m.source for m in driver.play(e, episodes[e])} == {"key_a"}
        driver.label(0, 20, 3.0, labeller="oracle")
        driver.label(0, 20, 4.0)
        driver.label(1, 20, 6.0)
        new = out_dir / "key_v001.pt"
        if driver.spin_until(lambda: (out_dir / "key_v001.json").is_file(), 120):
            assert driver.spin_until(lambda: driver.get_checkpoint("reward_model") == str(new), 30)
            sources = {m.source for m in driver.play(2, episodes[2])}
    finally:
        driver.close()
        for proc in (trainer, reward):
            proc.terminate()
        _, trainer_out = finish(trainer)
        _, reward_out = finish(reward)
    assert sources == {"key_v001"}, trainer_out + reward_out
    assert "retraining key_v001 on 2 episode(s)" in trainer_out, trainer_out
    assert "warm-started from" in trainer_out and "reward_model loads" in trainer_out, trainer_out
    assert "now serving key_v001" in reward_out, reward_out
    from nmrm_ros.datasets.trajectories import TrajectoryDataset

    ds = TrajectoryDataset.load(out_dir / ".datasets" / "key_v001.npz")
    assert ds.returns.tolist() == [4.0, 6.0] and ds.meta["labellers"] == ["person/test"]
    # provenance: the checkpoint records exactly the labels it was built from
    from nmrm_ros.labelling.label_files import checkpoint_labels

    assert [(r["labeller"], r["source"], r["episode"], r["length"], r["return"])
            for r in checkpoint_labels(out_dir / "key_v001")] == [("person/test", "", 0, 20, 4.0),
                                                                  ("person/test", "", 1, 20, 6.0)]


def test_a_restarted_trainer_starts_from_the_bags_and_the_newest_version(ros_domain, tmp_path):
    """bags:=[recording] of 6 episodes labelled by person/x: the trainer starts with those 6, and
    warm-starts from the newest version in out_dir (not from the `checkpoint` given at first)."""
    from nmrm_ros.bags import write_dataset_bag
    from nmrm_ros.datasets import generate_screened

    bag = write_dataset_bag(generate_screened("key", 6, seed=3), tmp_path / "rec", labeller="person/x")
    out_dir = tmp_path / "checkpoints"
    out_dir.mkdir()
    for name in ("key_v001", "key_v002"):
        _ensemble_checkpoint(out_dir / name, [0, 1])
    a, _ = _ensemble_checkpoint(tmp_path / "key_a", [0, 1])
    proc = start("trainer", task="key", out_dir=out_dir, checkpoint=a, bags=f"[{bag}]")
    line = ""
    for line in proc.stdout:
        if "task key:" in line:
            break
    proc.terminate()
    code, rest = finish(proc)
    assert "6 labelled episode(s) and 0 comparison(s) from bags" in line, line + rest
    assert f"next version key_v003 in {out_dir}, warm-started from {out_dir / 'key_v002.pt'}" in line, line
    assert code == 0, rest


def test_comparisons_retrain_and_the_reward_model_serves_the_new_version(ros_domain, tmp_path):
    """feedback:=preferences: six episodes and ten comparisons by person/test (none has a return
    label) make the trainer write key_v001 from the comparisons alone, and the reward model serves
    it; the training set has the six episodes with return NaN and the ten comparisons."""
    from nmrm_ros.datasets.trajectories import TrajectoryDataset

    out_dir = tmp_path / "checkpoints"
    a, _ = _ensemble_checkpoint(tmp_path / "key_a", [0, 1])
    reward = start("reward_model", task="key", mode="model", checkpoint=a)
    trainer = start("trainer", task="key", retrain_every=10, members=2, max_epochs=3, out_dir=out_dir,
                    labeller_web="''", labeller="[person/test]", feedback="preferences")
    driver = Driver()
    try:
        driver.wait_for_subscribers(observation=2)
        assert driver.spin_until(lambda: driver.comparisons.get_subscription_count() >= 2, 30)
        for e in range(6):
            driver.play(e, _states(e, 20))
        pairs = [(a, b) for a in range(6) for b in range(a + 1, 6)][:10]
        for i, (x, y) in enumerate(pairs):
            driver.compare(x, y, 20, (1, -1, 0)[i % 3])
        written = driver.spin_until(lambda: (out_dir / "key_v001.json").is_file(), 120)
        served = written and driver.spin_until(
            lambda: driver.get_checkpoint("reward_model") == str(out_dir / "key_v001.pt"), 30)
    finally:
        driver.close()
        for proc in (trainer, reward):
            proc.terminate()
        _, trainer_out = finish(trainer)
        _, reward_out = finish(reward)
    assert written and served, trainer_out + reward_out
    assert "retraining key_v001 on 6 episode(s) and 10 comparison(s)" in trainer_out, trainer_out
    assert "0 labels, 10 comparisons, validation preference loss" in trainer_out, trainer_out
    ds = TrajectoryDataset.load(out_dir / ".datasets" / "key_v001.npz")
    assert np.isnan(ds.returns).all() and len(ds) == 6 and len(ds.preferences) == 10
    assert sorted(ds.preferences[:, 2].tolist()) == sorted([(1, 0, 0.5)[i % 3] for i in range(10)])
