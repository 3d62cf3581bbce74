"""The sample bags in bags/ and the bag commands of the `nmrm` CLI, run as a user runs them."""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from nmrm_ros.testing.graph import executable
from nmrm_ros.bags import load_bag_dataset
from nmrm_ros.oracles import make_oracle

BAGS = Path(__file__).resolve().parents[1] / "bags"
SAMPLES = {"key": 200, "timer": 60, "moving": 60, "charger": 60}


def nmrm(*args, timeout=300):
    return subprocess.run([executable("nmrm"), *map(str, args)], capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("task,n", SAMPLES.items())
def test_sample_bag(task, n):
    path = BAGS / f"{task}_screened"
    ds, report = load_bag_dataset([path])
    assert ds.task == task and report.episodes_used == n and report.with_oracle == n
    # labels and ground truth are the oracle's on the recorded states
    labels = make_oracle(task).label(ds.states, lengths=ds.lengths)
    np.testing.assert_allclose(labels.returns, ds.returns, atol=1e-9)
    with AnyReader([path]) as reader:  # an independent reader takes it too
        assert reader.message_count == n * (101 + 100 + 100 + 1)


def test_cli_generate_info_train_evaluate(tmp_path):
    out = tmp_path / "gen"
    r = nmrm("dataset", "generate", "--task", "moving", "--episodes", "50", "--out", out)
    assert r.returncode == 0, r.stderr
    r = nmrm("bag", "info", out)
    assert r.returncode == 0 and "/nmrm/observation" in r.stdout and "50 used" in r.stdout
    r = nmrm("train", "--bag", out, "--bag", BAGS / "moving_screened", "--epochs", "2", "--out", tmp_path / "m")
    assert r.returncode == 0, r.stderr
    assert "110 used" in r.stdout and (tmp_path / "m.pt").is_file() and (tmp_path / "m.json").is_file()
    r = nmrm("evaluate", "--checkpoint", tmp_path / "m", "--bag", BAGS / "moving_screened", "--split", "all")
    assert r.returncode == 0 and "return MSE" in r.stdout, r.stderr
    r = nmrm("train", "--bag", BAGS / "key_screened", "--bag", BAGS / "timer_screened", "--epochs", "1")
    assert r.returncode != 0 and "several tasks" in r.stderr


def test_cli_trains_and_evaluates_an_ensemble(tmp_path):
    """`nmrm train --ensemble 3` on the Key sample bag: per-member report, one checkpoint holding
    all members, and `nmrm evaluate` scores the ensemble mean."""
    r = nmrm("train", "--bag", BAGS / "key_screened", "--epochs", "2", "--ensemble", "3", "--keep-members", "all",
             "--out", tmp_path / "ens")
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("member ") >= 3 and "ensemble mean: test return MSE" in r.stdout
    assert "still improving at the limit" in r.stdout  # 2 epochs: stopped at the limit
    r = nmrm("evaluate", "--checkpoint", tmp_path / "ens")
    assert r.returncode == 0 and "3-member ensemble of csc_lstm" in r.stdout, r.stderr
    r = nmrm("train", "--bag", BAGS / "key_screened", "--ensemble", "2", "--split-mode", "nope",
             "--out", tmp_path / "x")
    assert r.returncode == 2 and "--split-mode must be one of" in r.stderr
    r = nmrm("train", "--bag", BAGS / "key_screened", "--ensemble", "2", "--keep-members", "worst",
             "--out", tmp_path / "x")
    assert r.returncode != 0 and "keep_members" in r.stderr and "fitted or all or best" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "x.pt").exists()


def test_cli_repair(tmp_path):
    bag = tmp_path / "bag"
    shutil.copytree(BAGS / "key_screened", bag)
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    (bag / "metadata.yaml").unlink()
    r = nmrm("train", "--bag", bag, "--epochs", "1")
    assert r.returncode != 0 and "nmrm bag repair" in r.stderr
    r = nmrm("bag", "repair", bag)
    assert r.returncode == 0, r.stderr
    assert "messages recovered" in r.stdout and "used" in r.stdout
    ds, report = load_bag_dataset([bag])
    assert 0 < report.episodes_used < 200


def test_cli_rejects_bad_input(tmp_path):
    r = nmrm("dataset", "generate", "--task", "maze", "--episodes", "5", "--out", tmp_path / "x")
    assert r.returncode != 0 and "unknown task" in r.stderr
    r = nmrm("train", "--task", "key", "--arch", "gru")
    assert r.returncode != 0 and "unknown architecture" in r.stderr
    r = nmrm("evaluate", "--checkpoint", tmp_path / "none")
    assert r.returncode != 0 and "missing" in r.stderr
    r = nmrm("bag", "info", tmp_path / "none")
    assert r.returncode != 0 and "no bag" in r.stderr


def test_cli_trains_the_tasks_default_ensemble(tmp_path):
    """Timer's config says `members: 3` (one model is unreliable there, README *Figures*): plain
    `nmrm train` trains three models in one pass and writes one ensemble checkpoint; `--ensemble 1`
    one model."""
    import json

    r = nmrm("train", "--bag", BAGS / "timer_screened", "--epochs", "1", "--keep-members", "all", "--out", tmp_path / "t")
    assert r.returncode == 0, r.stderr
    assert "3 members in one pass" in r.stdout and "ensemble mean: test return MSE" in r.stdout
    meta = json.loads((tmp_path / "t.json").read_text())
    assert meta["ensemble"]["members"] == 3 and meta["ensemble"]["seeds"] == [0, 1, 2]
    assert meta["train_config"]["reward_l1"] == 0.05
    r = nmrm("train", "--bag", BAGS / "timer_screened", "--epochs", "1", "--ensemble", "1", "--out", tmp_path / "one")
    assert r.returncode == 0 and "members in one pass" not in r.stdout, r.stderr
    assert json.loads((tmp_path / "one.json").read_text())["ensemble"]["members"] == 1  # an ensemble of one
    r = nmrm("train", "--bag", BAGS / "key_screened", "--epochs", "1", "--reward-l1", "-1")
    assert r.returncode != 0 and "--reward-l1" in r.stderr and "Traceback" not in r.stderr
