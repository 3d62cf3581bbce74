"""Every numeric option of every `nmrm` command is validated at the boundary (property-based, with
Hypothesis): a value out of its range, or text that is not a number, ends in a one-line error on
stderr naming the option and exit code 2 — never a traceback, never a run. Also: a numeric option
without a range fails here unless it is listed with the place that checks it."""

from __future__ import annotations

import contextlib
import io
import signal
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cli_tree import leaf_commands
from nmrm_ros.cli import app, main

# numeric options checked after parsing, and by what
CHECKED_ELSEWHERE = {("train", "--lr"): "TrainConfig.check (lr > 0, exit 2)",
                     # any number is a threshold; NaN is refused by SimulatedTeacher.check (exit 2)
                     ("screen", "--skip"): "SimulatedTeacher.check", ("generate", "--skip"): "SimulatedTeacher.check",
                     ("loop", "--skip"): "SimulatedTeacher.check"}


def numeric_options() -> list[tuple[tuple[str, ...], str, type, float | None, float | None]]:
    """(command path, option, int | float, min, max) of every numeric option of the app."""
    return [(path, p.opts[0], p.type_descriptor.annotation, p.min, p.max) for path, command in leaf_commands(app)
            for p in command.params if p.type_descriptor.annotation in (int, float) and p.opts]


OPTIONS = numeric_options()
RANGED = [o for o in OPTIONS if o[3] is not None or o[4] is not None]


def run_nmrm(argv: list[str]) -> tuple[int, str]:
    """Run the console entry point in this process; (exit code, stderr)."""
    err, old_argv = io.StringIO(), sys.argv
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    sys.argv = ["nmrm", *argv]
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                main()
                code = 0
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 1
    finally:
        sys.argv = old_argv
        for s, h in handlers.items():
            signal.signal(s, h)
    return code, err.getvalue()


def test_every_numeric_option_has_a_range():
    assert len(OPTIONS) > 30
    unchecked = [f"nmrm {' '.join(path)} {opt}" for path, opt, _, lo, hi in OPTIONS
                 if lo is None and hi is None and (path[-1], opt) not in CHECKED_ELSEWHERE]
    assert not unchecked, f"numeric options without a range (give typer.Option min=/max=): {unchecked}"


@st.composite
def out_of_range(draw):
    """(argv, option) with one option out of its range or not a number."""
    path, opt, kind, lo, hi = draw(st.sampled_from(RANGED))
    choices = []
    if lo is not None:
        choices.append(st.integers(1, 10**9).map(lambda d: lo - d) if kind is int
                       else st.floats(1e-3, 1e9).map(lambda d: lo - d))
    if hi is not None:
        choices.append(st.integers(1, 10**9).map(lambda d: hi + d) if kind is int
                       else st.floats(1e-3, 1e9).map(lambda d: hi + d))
    choices.append(st.sampled_from(["abc", "", "1e", "--", "nan-", "0x", "½"]))
    if kind is int:
        choices.append(st.sampled_from(["1.5", "2e3"]))
    value = draw(st.one_of(*choices))
    return [*path, f"{opt}={value}"], opt


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(out_of_range())
def test_an_out_of_range_value_is_a_one_line_error(case):
    argv, opt = case
    code, err = run_nmrm(argv)
    assert code == 2, (argv, code, err)
    assert "Traceback" not in err and opt in err and len(err.strip().splitlines()) == 1, (argv, err)


@pytest.mark.parametrize("value", ["0", "-1", "-1e-9", "abc"])
def test_a_wrong_learning_rate_is_a_one_line_error(value):
    code, err = run_nmrm(["train", "--task", "key", "--n", "50", f"--lr={value}"])
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
