"""Wrong invocations of `nmrm` end in a one-line error and exit code 2, before any work is done
and without a traceback: counts out of range, training settings out of range, a file of the
wrong kind, an output that cannot be written, an unknown choice."""

import subprocess

import pytest

from pathlib import Path

from nmrm_ros.testing.graph import executable

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("args,message", [
    ("dataset generate --task key --episodes 0 --out {tmp}/x", "--episodes"),
    ("dataset generate --task key --episodes -3 --out {tmp}/x", "--episodes"),
    ("dataset screen --task key --n 0", "--n"),
    ("train --task key --n 0", "--n"),
    ("train --task key --n 50 --lr -1", "lr must be > 0"),
    ("train --task key --batch-size 0", "--batch-size"),
    ("train --task key --epochs 0", "--epochs"),
    ("train --task key --epochs -1", "--epochs"),
    ("train --task key --split-mode nope", "--split-mode must be one of"),
    ("train --task key --n 50 --label-swap 2", "--label-swap"),
    ("train --task key --n 50 --reward-l1 -1", "--reward-l1"),
    ("train --task key --n 50 --output-activation tanh", "output_activation must be empty"),
    ("train --task key --n 50 --fe-sizes 0,8", "fe_sizes must be one or more layer widths >= 1"),
    ("train --task key --n 50 --head-sizes x", "head_sizes must be a list of layer widths"),
    ("train --task key --n 5 --out {tmp}/m", "5 trajectories cannot be split"),
    ("train --data /etc/passwd --out {tmp}/m", "is not a dataset .npz"),
    ("train --task key --n 50 --out {tmp}/file/m", "cannot write to"),
    ("rl train --task key --reward oracle --episodes 0", "--episodes"),
    ("rl train --task key --reward oracle --observe camera", "unknown --observe"),
    ("rl train --task key --reward oracle --observe privileged", "has no privileged state"),
    ("train --task key_pixels --n 0", "--n"),
    ("check --checkpoint {tmp}/missing", "checkpoint file missing"),
    ("launch {root}/launch_scripts/collect.launch.yaml nope:=1", "unknown launch argument(s) ['nope']"),
    ("launch {root}/launch_scripts/collect.launch.yaml task=key", "launch arguments are NAME:=VALUE"),
    ("launch {tmp}/file", "expected a top-level 'launch:' list"),
    ("dataset screen --task key --n 50 --feedback stars", "--feedback must be returns, preferences or both"),
    ("dataset screen --task key --n 50 --pairs 10", "--pairs needs --feedback preferences or both"),
    ("dataset screen --task key --n 50 --feedback preferences --beta 0", "beta must be > 0"),
    ("dataset screen --task key --n 50 --feedback preferences --beta -1", "--beta"),
    ("dataset generate --task key --episodes 5 --feedback preferences --skip nan --out {tmp}/x", "skip must be a number"),
    ("dataset screen --task key --n 50 --feedback preferences --gamma 0", "gamma must be in (0, 1]"),
    ("dataset screen --task key --n 50 --feedback preferences --pairs 0", "--pairs"),
    ("train --task key --n 50 --feedback stars", "feedback must be returns or preferences or both"),
    ("train --task key --n 50 --feedback preferences --out {tmp}/m", "needs preferences"),
    ("calibrate --checkpoint {tmp}/missing --data {tmp}/file --out {tmp}/m", "checkpoint file missing"),
    ("calibrate --checkpoint {tmp}/missing --data {tmp}/file --labels 1 --out {tmp}/m", "--labels"),
    ("calibrate --checkpoint {tmp}/missing --data {tmp}/file --out {tmp}/file/m", "cannot write to"),
])
def test_a_wrong_invocation_is_a_one_line_error(tmp_path, args, message):
    (tmp_path / "file").write_text("not a directory")
    res = subprocess.run([executable("nmrm"), *args.format(tmp=tmp_path, root=ROOT).split()], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    assert message in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert not (tmp_path / "m.pt").exists()
