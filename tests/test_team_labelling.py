"""A team labels on one page: each person by their own token, two at once in two browser contexts,
split or overlapping episodes, gold episodes and agreement; label files and provenance."""

from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from nmrm_ros.testing.graph import Capture, executable, start
from nmrm_ros.bags import iter_decoded
from nmrm_ros.labelling import LabelError, LabelQueue
from nmrm_ros.labelling.agreement import label_report
from nmrm_ros.labelling.label_files import (checkpoint_labels, latest, read_bag_labels, read_labels,
                                            write_labels, write_labels_bag)
from test_labeller_web import CHROMIUM, WebNode, play_episodes


def _nmrm(*args, timeout=300):
    return subprocess.run([executable("nmrm"), *map(str, args)], capture_output=True, text=True, timeout=timeout)


# -- core (no ROS) -------------------------------------------------------------------------------
def test_split_gives_each_episode_to_one_person_and_overlap_to_everyone():
    q = LabelQueue("key", people=("alice", "bob"), take_s=60.0)
    for e in range(3):
        q.add(e, np.zeros((11, 2)), finished_at=float(e))
    q.take(0, "alice")                                  # alice has it open: not offered to bob
    assert [e.episode for e in q.pending("bob")] == [1, 2]
    assert [e.episode for e in q.pending("alice")] == [0, 1, 2]
    q.label(1, 5.0, "bob")                              # labelled by bob: nobody else is asked
    assert [e.episode for e in q.pending("alice")] == [0, 2]
    q.gold.add(2)                                       # gold: asked of everyone
    q.label(2, 1.0, "alice")
    assert [e.episode for e in q.pending("bob")] == [2]
    with pytest.raises(LabelError, match="not one of this page's people"):
        q.label(0, 1.0, "mallory")
    both = LabelQueue("key", people=("alice", "bob"), assignment="overlap")
    both.add(0, np.zeros((11, 2)))
    both.take(0, "alice")
    both.label(0, 3.0, "alice")
    assert [e.episode for e in both.pending("bob")] == [0] and both.pending("alice") == []
    assert not both.done(0)
    both.label(0, 4.0, "bob")
    assert both.done(0) and not both.add(0, np.zeros((11, 2)))
    with pytest.raises(ValueError, match="assignment must be one of"):
        LabelQueue("key", assignment="random")


def _rec(labeller, episode, value, stamp=0, source=""):
    return {"task": "key", "source": source, "episode": episode, "length": 100, "return": value,
            "labeller": labeller, "stamp_ns": stamp}


def test_the_report_gives_gold_errors_and_agreement_of_the_latest_labels():
    records = [_rec("oracle/key", 0, 10.0), _rec("oracle/key", 1, 20.0),
               _rec("person/a", 0, 12.0, 1), _rec("person/a", 0, 11.0, 2),  # a correction: 11 counts
               _rec("person/b", 0, 8.0), _rec("person/a", 1, 20.0), _rec("person/b", 1, 26.0),
               _rec("person/a", 2, 5.0), _rec("person/b", 2, 5.0), _rec("person/b", 0, 1.0, source="/r2")]
    report = label_report(records)
    a, b = report["labellers"]["person/a"], report["labellers"]["person/b"]
    assert (a["labels"], a["gold_n"], a["gold_mae"], a["gold_max"]) == (3, 2, 0.5, 1.0)
    assert (b["labels"], b["gold_n"], b["gold_mae"]) == (4, 2, 4.0)
    agree = report["agreement"]
    assert agree["episodes"] == 3 and agree["mean_abs_diff"] == pytest.approx((3 + 6 + 0) / 3)
    pair = agree["people"][0]
    assert (pair["a"], pair["b"], pair["episodes"]) == ("person/a", "person/b", 3)
    assert pair["correlation"] == pytest.approx(float(np.corrcoef([11, 20, 5], [8, 26, 5])[0, 1]))


@pytest.mark.parametrize("suffix", [".jsonl", ".csv"])
def test_labels_files_and_bags_round_trip(tmp_path, suffix):
    records = [_rec("person/a", 3, 1.5, 10**18), _rec("person/b", 4, -2.0, 10**18 + 5, "/robot1")]
    path = write_labels(records, tmp_path / f"labels{suffix}")
    assert read_labels(path) == records
    bag = write_labels_bag(records, tmp_path / "bag")
    assert read_bag_labels([bag]) == records


@pytest.mark.parametrize("text,message", [
    ('{"task": "key"}\n', "missing field(s) source"),
    ('[1, 2]\n', "not a JSON object"),
    ('{not json\n', "not a JSON object"),
    ('{"task": "key", "source": "", "episode": "x", "length": 1, "return": 1, "labeller": "a", "stamp_ns": 0}\n',
     "must be integers"),
    ('{"task": "key", "source": "", "episode": 1, "length": 1, "return": NaN, "labeller": "a", "stamp_ns": 0}\n',
     "finite return"),
])
def test_a_bad_labels_file_is_refused_naming_its_line(tmp_path, text, message):
    (tmp_path / "l.jsonl").write_text(text)
    with pytest.raises(ValueError, match=r"l.jsonl:1: .*" + message.replace("(", r"\(").replace(")", r"\)")):
        read_labels(tmp_path / "l.jsonl")


def test_a_checkpoint_trained_from_bags_records_exactly_its_labels(tmp_path):
    """`nmrm train --bag RECORDING --bag LABELS --labeller person/x`: the checkpoint's provenance
    is the labels of person/x (the imported file), and `nmrm labels report --checkpoint` lists them."""
    from nmrm_ros.bags import write_dataset_bag
    from nmrm_ros.datasets import generate_screened

    rec = write_dataset_bag(generate_screened("key", 30, seed=5), tmp_path / "rec", labeller="oracle/key")
    truth = {r["episode"]: r for r in latest(read_bag_labels([rec]))}
    given = [dict(truth[e], labeller="person/x", **{"return": float(e)}, stamp_ns=10**18 + e) for e in sorted(truth)]
    write_labels(given, tmp_path / "x.csv")
    res = _nmrm("labels", "import", "--file", tmp_path / "x.csv", "--out", tmp_path / "x_bag")
    assert res.returncode == 0 and "wrote 30 label(s)" in res.stdout, res.stderr
    res = _nmrm("train", "--bag", rec, "--bag", tmp_path / "x_bag", "--labeller", "person/x", "--epochs", 1,
                "--ensemble", 1, "--out", tmp_path / "m")
    assert res.returncode == 0, res.stdout + res.stderr
    stored = checkpoint_labels(tmp_path / "m")
    assert sorted((r["labeller"], r["episode"], r["return"], r["stamp_ns"]) for r in stored) == \
        sorted(("person/x", r["episode"], r["return"], r["stamp_ns"]) for r in given)
    res = _nmrm("labels", "report", "--checkpoint", tmp_path / "m", "--show")
    assert res.returncode == 0 and "person/x" in res.stdout and len(res.stdout.splitlines()) == 4 + 30, res.stdout  # 3 report lines, a header, 30 labels
    res = _nmrm("labels", "report", "--bag", rec, "--bag", tmp_path / "x_bag")
    assert "person/x" in res.stdout and "30, " in res.stdout, res.stdout  # 30 gold episodes (the oracle's)
    for args, message in ((["report"], "give labels bags"), (["report", "--file", rec], "is .jsonl or .csv"),
                          (["export", "--bag", rec, "--out", tmp_path / "o.txt"], "must end in .jsonl or .csv"),
                          (["import", "--file", tmp_path / "x.csv", "--out", tmp_path / "x_bag"], "is not empty"),
                          (["report", "--checkpoint", tmp_path / "nope"], "checkpoint file missing")):
        res = _nmrm("labels", *args)
        assert res.returncode == 2 and message in res.stderr and "Traceback" not in res.stderr, (args, res.stderr)


# -- the page, as a process, in a real browser --------------------------------------------------
class TeamNode(WebNode):
    """labeller_web with `people`: one URL per person, read from its log."""

    def __init__(self, labels_dir: Path, people: list, **params) -> None:
        self.proc = start("labeller_web", port=0, labels_dir=labels_dir, people=f"[{', '.join(people)}]", **params)
        self.lines, self.urls = [], {}
        deadline = time.monotonic() + 60
        for line in self.proc.stdout:
            self.lines.append(line)
            if "labelling page: " in line:
                person = line.split("labeller person/")[1].split(",")[0]
                self.urls[person] = line.split("labelling page: ")[1].split()[0]
                if len(self.urls) == len(people):
                    break
            assert time.monotonic() < deadline, "".join(self.lines)
        self.url = self.urls[people[0]]
        self.base = self.url.split("?")[0].rstrip("/")
        self.token = self.url.split("token=")[1]
        self.reader = threading.Thread(target=lambda: self.lines.extend(self.proc.stdout), daemon=True)
        self.reader.start()

    def token_of(self, person: str) -> str:
        return self.urls[person].split("token=")[1]


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium")
def test_two_people_label_at_once_each_as_themselves(ros_domain, tmp_path):
    """alice and bob, each in a browser context of their own (own token, own cookie): bob is not
    offered the episode alice has open; each label reaches the topic as its giver's; gold episode
    2 (every 3rd: the Key oracle knows its return) is asked of both, and the team panel shows
    their counts, agreement and gold errors; `nmrm labels report` on the labels directory says
    the same; a restarted page keeps both URLs."""
    from playwright.sync_api import expect, sync_playwright

    labels_dir = tmp_path / "labels"
    capture = Capture()
    node = TeamNode(labels_dir, ["alice", "bob"], gold_every=3)
    try:
        assert node.token_of("alice") != node.token_of("bob")
        capture.wait_for_publishers({"label": 1})
        play_episodes(3)
        node.wait_for_queue(3)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            pages = {}
            for person in ("alice", "bob"):
                page = browser.new_context(viewport={"width": 1200, "height": 800}).new_page()
                page.goto(node.urls[person])
                expect(page.locator("#title")).to_have_text("Episode 0 (100 steps)" if person == "alice"
                                                            else "Episode 1 (100 steps)", timeout=10000)
                assert page.text_content("#who").startswith(f"person/{person}")
                pages[person] = page
            assert "0" not in [li.get_attribute("data-episode") for li in pages["bob"].locator("#queue li").all()]
            for person, value in (("alice", "10"), ("bob", "20")):
                pages[person].fill("#return", value)
                pages[person].click("#submit")
            # each then gets the gold episode 2
            for person, value in (("alice", "5"), ("bob", "7")):
                expect(pages[person].locator("#title")).to_have_text("Episode 2 (100 steps)", timeout=10000)
                pages[person].fill("#return", value)
                pages[person].click("#submit")
            expect(pages["alice"].locator("#agreement")).to_contain_text("1 episode(s) labelled by two or more",
                                                                         timeout=10000)
            expect(pages["alice"].locator("#team tr")).to_have_count(2)
            assert pages["alice"].text_content("#team tr:nth-child(1) td:nth-child(1)") == "alice (you)"
            assert pages["alice"].text_content("#team tr:nth-child(1) td:nth-child(2)") == "2"
            browser.close()
        assert capture.spin_until(lambda: len(capture.msgs["label"]) == 4, 20)
        got = sorted((m.episode, m.return_value, m.labeller) for m in capture.msgs["label"])
        assert got == [(0, 10.0, "person/alice"), (1, 20.0, "person/bob"), (2, 5.0, "person/alice"),
                       (2, 7.0, "person/bob")]
        status, team, _ = node.request("/api/team")
        assert status == 200 and team["gold_episodes"] == 1 and team["gold"]["alice"]["n"] == 1
        assert team["agreement"]["episodes"] == 1 and team["agreement"]["mean_abs_diff"] == 2.0
        # bob's token is bob's: his labels list has his labels only
        assert {r["episode"] for r in node.request("/api/labels", token=node.token_of("bob"))[1]["labels"]} == {1, 2}
    finally:
        out = node.stop()
        capture.close()
    sessions = sorted(p for p in labels_dir.iterdir() if p.is_dir() and not p.name.startswith("."))
    gold_bag = next(p for p in sessions if p.name.startswith("gold_oracle"))
    (gold,) = [m.return_value for _, _, _, m in iter_decoded(gold_bag)]
    assert team["gold"]["alice"]["mae"] == pytest.approx(abs(5.0 - gold), abs=1e-4)
    res = _nmrm("labels", "report", *[a for s in sessions for a in ("--bag", s)])
    assert res.returncode == 0, res.stderr
    assert f"person/alice                       2  1, {abs(5.0 - gold):.3g}" in res.stdout, res.stdout
    assert "agreement: 1 episode(s) labelled by two or more people; mean abs difference 2" in res.stdout
    assert "0 label(s)" not in out and "2 label(s) this session" in out, out
    again = TeamNode(labels_dir, ["alice", "bob"])
    try:
        assert {p: again.token_of(p) for p in ("alice", "bob")} == \
            {p: node.token_of(p) for p in ("alice", "bob")}  # the team's tokens are kept (port 0 differs)
    finally:
        again.stop()
    mode = (labels_dir / ".team_tokens.json").stat().st_mode & 0o777
    assert mode == 0o600, oct(mode)
