"""A user's oracle function (nmrm_ros.oracles.function_oracle) on a user's task: named by module or
file, labels whole trajectories and steps online alike, and misbehaviour is a one-line error
naming it; datasets of any task screened by return bins (datasets.return_screening), with
episodes of varying length through generate -> bag -> train."""

import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest

from nmrm_ros.testing.graph import executable
from nmrm_ros.datasets.return_screening import balanced_keep, return_bins, screen_by_return
from nmrm_ros.oracles import OracleError, make_oracle

CARTPOLE = "gym:CartPole-v1"
ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = str(ROOT / "examples" / "cartpole_crossings.py") + ":oracle"


@pytest.fixture
def oracles(tmp_path, monkeypatch):
    """A user's module of oracles, good and broken, importable as `user_oracles`."""
    (tmp_path / "user_oracles.py").write_text(textwrap.dedent('''
        import numpy as np

        def running_max(states, actions):      # rewards only: r_t = max x so far
            return np.maximum.accumulate(states[:, 0])

        def with_hidden(states, actions):      # rewards and the hidden state (T, 1)
            seen = np.maximum.accumulate(states[:, 0] > 0)
            return seen.astype(float), seen[:, None].astype(float)

        def uses_actions(states, actions):
            return actions[:, 0].astype(float)

        def wrong_shape(states, actions):
            return np.zeros(len(states) + 1)

        def nan(states, actions):
            return np.full(len(states), np.nan)

        def raises(states, actions):
            raise KeyError("boom")

        def future(states, actions):           # r_t looks at the end of the trajectory
            return np.full(len(states), float(len(states)))

        def text(states, actions):
            return "no"

        NOT_CALLABLE = 3
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def test_an_oracle_function_labels_and_steps_alike(oracles):
    o = make_oracle(CARTPOLE, "user_oracles:with_hidden")
    assert (o.hidden_size, o.returns_hidden) == (1, True)
    rng = np.random.default_rng(0)
    states = rng.normal(size=(3, 7, 4))
    lengths = np.array([7, 4, 1])
    labels = o.label(states, rng.integers(0, 2, (3, 7, 1)), lengths)
    assert labels.rewards.shape == (3, 7) and labels.hidden.shape == (3, 7, 1)
    assert np.all(labels.rewards[1, 4:] == 0) and np.all(labels.rewards[2, 1:] == 0)
    np.testing.assert_allclose(labels.returns, labels.rewards.sum(axis=1))
    tracker = o.tracker()
    for i, n in enumerate(lengths):
        tracker.reset()
        online = [tracker.step(s) for s in states[i, :n]]
        np.testing.assert_allclose([r for r, _ in online], labels.rewards[i, :n])
        np.testing.assert_allclose([h for _, h in online], labels.hidden[i, :n])
    plain = make_oracle(CARTPOLE, "user_oracles:running_max")
    assert (plain.hidden_size, plain.returns_hidden) == (0, False)
    assert plain.tracker().step(np.ones(4))[1].shape == (0,)


def test_a_file_path_names_an_oracle_too():
    o = make_oracle(CARTPOLE, EXAMPLE)
    x = np.array([0.1, -0.2, 0.3, 0.2, -0.1])  # crosses leftwards at 1, rightwards at 2
    states = np.zeros((1, 5, 4))
    states[0, :, 0] = x
    assert o.label(states).rewards[0].tolist() == [0, 0, 1, 1, 1]


@pytest.mark.parametrize("spec,message", [
    ("user_oracles", "give it as <module>:<function>"),
    ("no_such_module_here:f", "cannot import 'no_such_module_here'"),
    ("/no/such/file.py:f", "no file /no/such/file.py"),
    ("user_oracles:missing", "has no attribute 'missing'"),
    ("user_oracles:NOT_CALLABLE", "is a int, not a function"),
    ("user_oracles:wrong_shape", "rewards of shape (3,) for 2 steps; expected (2,)"),
    ("user_oracles:nan", "rewards contain NaN or inf"),
    ("user_oracles:raises", "raised KeyError: 'boom'"),
    ("user_oracles:text", "rewards is a str, not numbers"),
])
def test_an_unusable_oracle_is_a_one_line_error_naming_it(oracles, spec, message):
    with pytest.raises(OracleError) as info:
        make_oracle(CARTPOLE, spec)
    text = str(info.value)
    assert message in text and spec.split(":")[-1] in text and "\n" not in text, text


def test_an_oracle_that_sees_the_future_is_refused_and_one_needing_actions_says_so(oracles):
    o = make_oracle(CARTPOLE, "user_oracles:future")
    with pytest.raises(OracleError, match="may depend on steps up to its own only"):
        o.label(np.zeros((1, 6, 4)), np.zeros((1, 6, 1)))
    needs = make_oracle(CARTPOLE, "user_oracles:uses_actions")
    with pytest.raises(OracleError, match="actions are None here"):
        needs.tracker().step(np.zeros(4))  # the graph's nodes follow observations only
    assert needs.tracker().step(np.zeros(4), np.array([1]))[0] == 1.0


def test_a_task_of_yours_without_an_oracle_says_how_to_give_one():
    with pytest.raises(OracleError, match="--oracle <module>:<function>"):
        make_oracle(CARTPOLE)


def test_return_bins_and_the_most_even_histogram_the_pool_allows():
    assert return_bins(np.array([0.0, 1.0, 2.0, 10.0]), 5).tolist() == [0, 0, 1, 4]
    assert return_bins(np.array([3.0, 3.0]), 5).tolist() == [0, 0]
    keep, cap = balanced_keep(np.array([0, 0, 0, 0, 1, 2, 0, 2]), 5)
    assert cap == 2 and keep.tolist() == [0, 1, 4, 5, 7]


def test_a_screened_dataset_of_a_gym_task_has_episodes_of_varying_length():
    o = make_oracle(CARTPOLE, EXAMPLE)
    ds = screen_by_return(CARTPOLE, o, 60, seed=3)
    again = screen_by_return(CARTPOLE, make_oracle(CARTPOLE, EXAMPLE), 60, seed=3)
    np.testing.assert_array_equal(ds.states, again.states)
    assert len(ds) == 60 and ds.lengths.min() < ds.lengths.max() == ds.states.shape[1]
    assert ds.meta["pool"] == 240 and ds.meta["cap_per_bin"] >= 6
    assert np.bincount(ds.classes).max() <= ds.meta["cap_per_bin"]
    np.testing.assert_allclose(ds.returns, o.label(ds.states, ds.actions, ds.lengths).returns)
    assert ds.actions.shape[2] == 1 and set(np.unique(ds.actions)) <= {0.0, 1.0}


def _nmrm(*args, timeout=300):
    return subprocess.run([executable("nmrm"), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def test_your_own_task_from_dataset_to_an_agent_learning_through_the_graph(ros_domain, tmp_path, oracles):
    """The README's path for your own task: screened bag -> CSC model -> served through the graph
    (learn.launch.yaml: env_sim, reward_model, the user's oracle labelling, an agent learning, a
    recorder) -> the recorded bag, whose episodes vary in length, trains a model again."""
    from nmrm_ros.bags import load_bag_dataset

    bag = tmp_path / "cartpole_bag"
    res = _nmrm("dataset", "generate", "--task", CARTPOLE, "--oracle", EXAMPLE, "--episodes", 60,
                "--out", bag)
    assert res.returncode == 0, res.stderr
    assert "at most" in res.stdout and "per return bin" in res.stdout, res.stdout
    res = _nmrm("train", "--bag", bag, "--out", tmp_path / "m", "--epochs", 2, "--ensemble", 1)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "training csc_lstm on gym:CartPole-v1: 60 trajectories" in res.stdout, res.stdout
    # nmrm check with the user's oracle: its hidden state is what the served state must separate
    res = _nmrm("check", "--checkpoint", tmp_path / "m", "--oracle", EXAMPLE, "--memory-only")
    assert res.returncode in (0, 1) and "memory: the served state separates" in res.stdout, res.stdout + res.stderr
    res = _nmrm("check", "--checkpoint", tmp_path / "m", "--memory-only")
    assert res.returncode == 2 and "give your own as --oracle" in res.stderr, res.stderr
    res = _nmrm("check", "--checkpoint", tmp_path / "m", "--oracle", f"{oracles}/user_oracles.py:running_max",
                "--memory-only")
    assert res.returncode == 0 and "memory: not checked: the oracle returns no hidden state" in res.stdout, res.stdout
    learn = tmp_path / "learn"
    res = _nmrm("launch", ROOT / "launch_scripts" / "learn.launch.yaml", f"task:={CARTPOLE}", f"oracle:={EXAMPLE}", "mode:=model",
                f"checkpoint:={tmp_path / 'm'}", "episodes:=12", f"out:={learn}", timeout=240)
    assert res.returncode == 0 and "all 5 node(s) exited cleanly" in res.stdout, res.stdout + res.stderr
    assert "labelled 12 episode(s), 0 broken" in res.stdout, res.stdout
    assert (learn / "policy" / "policy.zip").is_file()
    ds, _ = load_bag_dataset([learn / "bag"])
    assert len(ds) == 12 and ds.lengths.min() < ds.lengths.max(), ds.lengths
    np.testing.assert_allclose(ds.returns, make_oracle(CARTPOLE, EXAMPLE).label(ds.states, None, ds.lengths).returns)
    res = _nmrm("train", "--bag", learn / "bag", "--out", tmp_path / "m2", "--epochs", 1, "--ensemble", 1,
                "--split-seed", 1)
    assert res.returncode == 0, res.stdout + res.stderr


def test_a_policy_of_plain_states_can_be_screened(tmp_path):
    """--policy: episodes of a saved policy (here a short oracle-no-hidden agent) instead of random
    ones; a policy of another observation (a reward model's augmented state) is a one-line error."""
    plain, augmented = tmp_path / "plain", tmp_path / "augmented"
    for reward, out in (("oracle-no-hidden", plain), ("oracle", augmented)):
        res = _nmrm("rl", "train", "--task", CARTPOLE, "--reward", reward, "--oracle", EXAMPLE,
                    "--episodes", 3, "--out", out)
        assert res.returncode == 0, res.stdout + res.stderr
    res = _nmrm("dataset", "screen", "--task", CARTPOLE, "--oracle", EXAMPLE, "--n", 20,
                "--policy", plain / "policy.zip")
    assert res.returncode == 0 and "policy.zip policy" in res.stdout, res.stdout + res.stderr
    res = _nmrm("dataset", "screen", "--task", CARTPOLE, "--oracle", EXAMPLE, "--n", 20,
                "--policy", augmented / "policy.zip")
    assert res.returncode == 2 and "observes 6 values and gym:CartPole-v1 states have 4" in res.stderr, res.stderr
    res = _nmrm("dataset", "screen", "--task", "key", "--n", 20, "--policy", plain / "policy.zip")
    assert res.returncode == 2 and "needs your own task or --oracle" in res.stderr, res.stderr


@pytest.mark.parametrize("args,message", [
    (("--task", CARTPOLE), "has no oracle of ours: give your own as --oracle"),
    (("--task", CARTPOLE, "--oracle", "/nope.py:f"), "no file /nope.py"),
    (("--task", CARTPOLE, "--oracle", EXAMPLE, "--pool-size", 2), "a pool of 2 episodes cannot fill 5"),
    (("--task", CARTPOLE, "--oracle", EXAMPLE, "--bins", 0), "--bins"),
])
def test_a_wrong_dataset_invocation_for_your_own_task_is_a_one_line_error(tmp_path, args, message):
    res = _nmrm("dataset", "generate", *args, "--episodes", 5, "--out", tmp_path / "bag", timeout=120)
    assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert not (tmp_path / "bag").exists()
