"""Every path option of every `nmrm` command refuses a wrong path in one line with exit code 2
before any work starts: an input that is missing, a text file, or an empty directory where a
checkpoint, bag, dataset, policy, config or launch file is expected; an output under a regular
file or where nothing can be created. A path option that this test does not know fails it."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest

from cli_tree import leaf_commands
from nmrm_ros.cli import app
from test_cli_properties import run_nmrm

IN, OUT = "input", "output"
# (command path, option) -> (kind, argv with {P} for the path and {T} for the test's directory)
CASES = {
    (("launch",), "file"): (IN, "launch {P}"),
    (("fleet",), "--checkpoint"): (IN, "fleet --robots 1 --mode model --checkpoint {P} --out {T}/f"),
    (("fleet",), "--out"): (OUT, "fleet --robots 1 --episodes 1 --out {P}"),
    (("demo",), "--out"): (OUT, "demo --out {P}"),
    (("train",), "--data"): (IN, "train --data {P} --out {T}/m"),
    (("train",), "--bag"): (IN, "train --bag {P} --out {T}/m"),
    (("train",), "--config"): (IN, "train --task key --n 50 --config {P} --out {T}/m"),
    (("train",), "--out"): (OUT, "train --task key --n 50 --epochs 1 --out {P}"),
    (("evaluate",), "--checkpoint"): (IN, "evaluate --checkpoint {P}"),
    (("evaluate",), "--data"): (IN, "evaluate --checkpoint {C} --data {P}"),
    (("evaluate",), "--bag"): (IN, "evaluate --checkpoint {C} --bag {P}"),
    (("calibrate",), "--checkpoint"): (IN, "calibrate --checkpoint {P} --data {T}/d.npz --out {T}/m"),
    (("calibrate",), "--data"): (IN, "calibrate --checkpoint {C} --data {P} --out {T}/m"),
    (("calibrate",), "--bag"): (IN, "calibrate --checkpoint {C} --bag {P} --out {T}/m"),
    (("calibrate",), "--out"): (OUT, "calibrate --checkpoint {C} --data {T}/d.npz --out {P}"),
    (("explain",), "--checkpoint"): (IN, "explain --checkpoint {P} --task key --out {T}/x"),
    (("explain",), "--bag"): (IN, "explain --checkpoint {C} --bag {P} --out {T}/x"),
    (("explain",), "--out"): (OUT, "explain --checkpoint {C} --task key --out {P}"),
    (("check",), "--checkpoint"): (IN, "check --checkpoint {P}"),
    (("dataset", "screen"), "--out"): (OUT, "dataset screen --task key --n 20 --out {P}"),
    (("dataset", "screen"), "--policy"): (IN, "dataset screen --task key --n 20 --policy {P}"),
    (("dataset", "generate"), "--out"): (OUT, "dataset generate --task key --episodes 5 --out {P}"),
    (("dataset", "generate"), "--policy"): (IN, "dataset generate --task key --episodes 5 --policy {P} --out {T}/b"),
    (("dataset", "toy"), "--out"): (OUT, "dataset toy --name dial --n 20 --out {P}"),
    (("bag", "info"), "path"): (IN, "bag info {P}"),
    (("bag", "repair"), "path"): (IN, "bag repair {P}"),
    (("rl", "train"), "--checkpoint"): (IN, "rl train --task key --reward model --checkpoint {P} --episodes 1 --out {T}/a"),
    (("rl", "train"), "--config"): (IN, "rl train --task key --reward oracle --episodes 1 --config {P} --out {T}/a"),
    (("rl", "train"), "--out"): (OUT, "rl train --task key --reward oracle --episodes 1 --out {P}"),
    (("loop",), "--out"): (OUT, "loop --task key --rounds 1 --labels-per-round 10 --episodes 1 --out {P}"),
    (("rl", "evaluate"), "--policy"): (IN, "rl evaluate --policy {P} --task key"),
    (("rl", "evaluate"), "--checkpoint"): (IN, "rl evaluate --policy {Z} --task key --checkpoint {P}"),
    (("labels", "report"), "--bag"): (IN, "labels report --bag {P}"),
    (("labels", "report"), "--checkpoint"): (IN, "labels report --checkpoint {P}"),
    (("labels", "report"), "--file"): (IN, "labels report --file {P}"),
    (("labels", "export"), "--bag"): (IN, "labels export --bag {P} --out {T}/l.jsonl"),
    (("labels", "export"), "--checkpoint"): (IN, "labels export --checkpoint {P} --out {T}/l.jsonl"),
    (("labels", "export"), "--out"): (OUT, "labels export --checkpoint {C} --out {P}"),
    (("labels", "import"), "--file"): (IN, "labels import --file {P} --out {T}/b"),
    (("labels", "import"), "--out"): (OUT, "labels import --file {L} --out {P}"),
    (("tls", "cert"), "--out"): (OUT, "tls cert --host lab-pc --out {P}"),
    (("export", "lerobot"), "--bag"): (IN, "export lerobot --bag {P} --out {T}/b"),
    (("export", "lerobot"), "--checkpoint"): (IN, "export lerobot --bag {B} --checkpoint {P} --out {T}/b"),
    (("export", "lerobot"), "--out"): (OUT, "export lerobot --bag {B} --out {P}"),
    (("import", "lerobot"), "dataset"): (IN, "import lerobot {P} --out {T}/b"),
    (("import", "lerobot"), "--out"): (OUT, "import lerobot {D} --task key --out {P}"),
}
BAD_INPUTS = ("missing", "text file", "empty directory")
BAD_OUTPUTS = ("under a file", "not creatable")


def path_options() -> set:
    return {(path, p.opts[0] if p.opts else p.name) for path, command in leaf_commands(app) for p in command.params
            if p.type_descriptor.annotation is Path or p.type_descriptor.annotation == list[Path]}


def test_every_path_option_is_covered():
    missing = sorted(path_options() - set(CASES))
    assert not missing, f"path options this test does not try (add them to CASES): {missing}"


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A small checkpoint and a policy to pair with the wrong path."""
    d = tmp_path_factory.mktemp("good")
    code, err = run_nmrm(["train", "--task", "key", "--n", "50", "--epochs", "1", "--ensemble", "1",
                          "--redraws", "0", "--out", str(d / "m")])
    assert code == 0, err
    assert json.loads((d / "m.json").read_text())["train_config"]["redraws"] == 0  # the option reaches the run
    code, err = run_nmrm(["rl", "train", "--task", "key", "--reward", "oracle", "--episodes", "1",
                          "--out", str(d / "agent")])
    assert code == 0, err
    (d / "labels.jsonl").write_text('{"task": "key", "source": "", "episode": 0, "length": 100, "return": 1.0, '
                                    '"labeller": "person/a", "stamp_ns": 1}\n')
    return d


def bad_path(tmp: Path, what: str) -> str:
    (tmp / "notes.txt").write_text("not what you think\n")
    (tmp / "empty").mkdir(exist_ok=True)
    return {"missing": tmp / "missing", "text file": tmp / "notes.txt", "empty directory": tmp / "empty",
            "under a file": tmp / "notes.txt" / "x", "not creatable": Path("/proc/nmrm_nowhere/x")}[what]


class Hang(Exception):
    pass


def _alarm(*_):
    raise Hang()


@pytest.mark.parametrize("key,what", [(k, w) for k, (kind, _) in CASES.items()
                                      for w in (BAD_INPUTS if kind == IN else BAD_OUTPUTS)],
                         ids=lambda x: " ".join(x[0]) + " " + x[1] if isinstance(x, tuple) else x)
def test_a_wrong_path_is_a_one_line_error_before_any_work(tmp_path, good, key, what):
    _, template = CASES[key]
    path = bad_path(tmp_path, what)
    root = Path(__file__).resolve().parents[1]
    argv = template.format(P=path, T=tmp_path, C=good / "m", Z=good / "agent" / "policy.zip",
                           L=good / "labels.jsonl", B=root / "bags" / "key_screened",
                           D=root / "tests" / "fixtures" / "lerobot_v30_small").split()
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(60)
    try:
        code, err = run_nmrm(argv)
    except Hang:
        pytest.fail(f"nmrm {' '.join(argv)} ran for 60 s instead of refusing the path")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    lines = err.strip().splitlines()
    assert code == 2 and "Traceback" not in err and len(lines) == 1, (argv, code, err)
    assert not list(tmp_path.glob("m.*")) and not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert not (tmp_path / "l.jsonl").exists()
