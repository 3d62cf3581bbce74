"""labeller_web: a person labels episodes on a web page. The node runs as a real process beside a
real env_sim; requests go over HTTP; the page is checked in a real (headless) Chromium."""

from __future__ import annotations

import io
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from nmrm_ros.testing.graph import Capture, finish, start
from nmrm_ros.bags import iter_decoded
from nmrm_ros.labelling import LabelError, LabelQueue, LabelStore

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARTEFACTS = Path(os.environ.get("NMRM_TEST_ARTEFACTS", Path(__file__).resolve().parents[1] / "build" / "test_artefacts"))


# -- core (no ROS) -------------------------------------------------------------------------------
def test_queue_validates_labels_and_keeps_corrections():
    q = LabelQueue("timer")
    q.add(3, np.zeros((101, 2)))
    q.add(1, np.zeros((101, 2)), finished_at=0.0)
    assert [e.episode for e in q.pending()] == [1, 3]  # oldest first
    for bad in (float("nan"), math.inf, "12", True, None, -50.5, 50.01):
        with pytest.raises(LabelError):
            q.label(3, bad)
    with pytest.raises(LabelError, match="no episode 7"):
        q.label(7, 1.0)
    assert q.label(3, -50)[0].corrections == 0
    assert q.label(3, 12.5)[0].corrections == 1  # a correction: the latest counts
    assert q.label_of(3).value == 12.5 and [e.episode for e in q.pending()] == [1]
    assert not q.add(3, np.zeros((101, 2)))  # labelled: not asked again


def test_label_store_keeps_labels_of_a_killed_session(tmp_path):
    """Three labels written, then the process is killed (-9) before closing its bag: the next
    session repairs that bag and reads all three."""
    code = ("import os, signal; from nmrm_ros.labelling import LabelStore\n"
            f"s = LabelStore({str(tmp_path)!r}, 'person/bob')\n"
            "for e in range(3): s.append('key', e, 100, float(e))\n"
            "os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    store = LabelStore(tmp_path, "person/bob")
    store.close()
    assert len(store.repaired) == 1
    assert [(s.episode, s.value) for s in store.earlier] == [(0, 0.0), (1, 1.0), (2, 2.0)]
    assert store.labelled_episodes("key") == {0, 1, 2} and store.labelled_episodes("timer") == set()


def test_waiting_episodes_survive_a_restart_and_are_pruned(tmp_path):
    """Kept episodes are read back oldest first; labelled ones and those beyond max_episodes are
    removed; an unreadable file is reported and left; other tasks' files are not touched."""
    from nmrm_ros.labelling import WaitingEpisodes

    store = WaitingEpisodes(tmp_path, "key")
    for episode, at in ((3, 30.0), (1, 10.0), (2, 20.0), (4, 40.0)):
        store.save(episode, np.full((5, 2), episode, np.float32), finished_at=at)
    WaitingEpisodes(tmp_path, "timer").save(1, np.zeros((3, 2)), finished_at=1.0)
    (tmp_path / "key_9.npz").write_bytes(b"not a npz")
    assert not list(tmp_path.glob("*.tmp"))
    kept, errors = WaitingEpisodes(tmp_path, "key").load(skip={4}, max_episodes=2)
    assert [(e.episode, e.finished_at) for e in kept] == [(2, 20.0), (3, 30.0)]
    np.testing.assert_array_equal(kept[0].states, np.full((5, 2), 2, np.float32))
    assert len(errors) == 1 and "key_9.npz" in errors[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["key_2.npz", "key_3.npz", "key_9.npz", "timer_1.npz"]


# -- the node ------------------------------------------------------------------------------------
class WebNode:
    """labeller_web as a process (port 0), its output collected, its URL read from its log."""

    def __init__(self, labels_dir: Path, **params) -> None:
        self.proc = start("labeller_web", port=0, labels_dir=labels_dir, person="alice", **params)
        self.lines: list = []
        self.url = None
        deadline = time.monotonic() + 60
        for line in self.proc.stdout:
            self.lines.append(line)
            if "labelling page: " in line:
                self.url = line.split("labelling page: ")[1].split()[0]
                break
            assert time.monotonic() < deadline, "".join(self.lines)
        assert self.url, "".join(self.lines)
        self.base = self.url.split("?")[0].rstrip("/")
        self.token = self.url.split("token=")[1] if "token=" in self.url else ""
        self.reader = threading.Thread(target=lambda: self.lines.extend(self.proc.stdout), daemon=True)
        self.reader.start()

    def request(self, path: str, body=None, token: str | None = None, raw: bytes | None = None,
                content_type: str = "application/json", headers: dict | None = None) -> tuple:
        """(status, decoded JSON or text, headers) of GET `path` (POST with `body` or `raw`)."""
        data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
        req = urllib.request.Request(self.base + path, data=data, method="POST" if data is not None else "GET")
        tok = self.token if token is None else token
        if tok:
            req.add_header("X-Token", tok)
        if data is not None:
            req.add_header("Content-Type", content_type)
        for name, value in (headers or {}).items():
            req.add_header(name, value)
        try:
            with urllib.request.urlopen(req, timeout=10) as r:
                status, text, headers = r.status, r.read().decode(), r.headers
        except urllib.error.HTTPError as exc:
            status, text, headers = exc.code, exc.read().decode(), exc.headers
        is_json = headers.get("Content-Type", "").startswith("application/json")
        return status, json.loads(text) if is_json else text, headers

    def wait_for_queue(self, n: int, timeout: float = 60.0) -> list:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            episodes = self.request("/api/queue")[1]["episodes"]
            if len(episodes) >= n:
                return episodes
            time.sleep(0.2)
        raise AssertionError(f"queue has {episodes}, expected {n} episodes\n{''.join(self.lines)}")

    def stop(self, sig=signal.SIGINT) -> str:
        self.proc.send_signal(sig)
        self.proc.wait(timeout=30)
        self.reader.join(timeout=5)
        return "".join(self.lines)


def play_episodes(n: int, seed: int = 0, task: str = "key", **sim_params) -> None:
    """env_sim plays n episodes of `task` (a random agent) once labeller_web subscribes."""
    agent = start("agent", task=task, observe="observation", exit_with_upstream=True)
    sim = start("env_sim", task=task, episodes=n, seed=seed, wait_for_nodes="[labeller_web]", **sim_params)
    for proc in (sim, agent):
        code, out = finish(proc, timeout=60)
        assert code == 0, out


def test_page_refuses_bad_requests(ros_domain, tmp_path):
    """With a token required: no token and a wrong one are refused (401, also for the page);
    malformed labels, a script-injection string, an unknown episode (400) and an oversized body
    (413) are refused cleanly, as JSON; nothing of it is labelled."""
    node = WebNode(tmp_path / "labels", require_token=True)
    try:
        assert len(node.token) >= 20
        play_episodes(1)
        node.wait_for_queue(1)
        for path in ("/", "/api/queue"):
            assert node.request(path, token="")[0] == 401
            assert node.request(path, token="wrong")[0] == 401
        status, page, headers = node.request("/")
        assert status == 200 and "script-src 'self'" in headers["Content-Security-Policy"]
        cases = [({"episode": 0, "return": "<script>alert(1)</script>"}, 400),
                 ({"episode": 0, "return": None}, 400), ({"episode": 0}, 400),
                 ({"episode": "0", "return": 1.0}, 400), ({"episode": 0, "return": 1e9}, 400),
                 ({"episode": 99, "return": 1.0}, 400), ([0, 1], 400)]
        for body, want in cases:
            status, answer, headers = node.request("/api/label", body)
            assert status == want and "error" in answer, (body, status, answer)
            assert headers["Content-Type"].startswith("application/json")
        assert node.request("/api/label", raw=b"{not json")[0] == 400
        assert node.request("/api/label", raw=b'{"episode": 0, "return": NaN}')[0] == 400
        big = json.dumps({"episode": 0, "return": 1.0, "pad": "x" * 10_000}).encode()
        assert node.request("/api/label", raw=big)[0] == 413
        assert node.request("/api/labels")[1]["labels"] == []
    finally:
        out = node.stop()
    assert "0 label(s) this session" in out, out


def test_the_page_is_safe_by_default(ros_domain, tmp_path):
    """With the defaults (127.0.0.1): the token is on and printed in the URL; a request without it
    is refused; a Host that is not this server's (DNS rebinding) is refused even with the token; a
    POST that is not JSON (what a cross-site form or no-cors fetch can send), or that comes from
    another origin, is refused; nothing of it is labelled. GET / with the token sets an HttpOnly,
    SameSite=Strict cookie that the page's reads use."""
    node = WebNode(tmp_path / "labels")
    try:
        assert len(node.token) >= 20
        play_episodes(1)
        node.wait_for_queue(1)
        port = node.base.rsplit(":", 1)[1]
        for path in ("/", "/api/queue", "/static/page.js"):
            assert node.request(path, token="")[0] == 401
        assert node.request("/api/queue", headers={"Host": f"attacker.example:{port}"})[0] == 403
        assert node.request("/api/queue", headers={"Host": f"localhost:{port}"})[0] == 200
        label = {"episode": 0, "return": 42.5}
        status, answer, _ = node.request("/api/label", label, content_type="text/plain")
        assert status == 415 and "application/json" in answer["error"], answer
        status, answer, _ = node.request("/api/label", label, headers={"Origin": "http://127.0.0.2:9099"})
        assert status == 403 and "cross-origin" in answer["error"], answer
        status, _, headers = node.request(f"/?token={node.token}", token="")
        cookie = headers["Set-Cookie"]
        assert status == 200 and "HttpOnly" in cookie and "SameSite=Strict" in cookie, cookie
        assert node.request("/api/labels")[1]["labels"] == []
    finally:
        out = node.stop()
    assert "0 label(s) this session" in out, out


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium")
@pytest.mark.parametrize("require_token", [True, False])
def test_another_web_page_can_neither_label_nor_read(ros_domain, tmp_path, require_token):
    """In the real browser, the labeller has the page open (its token cookie set); a page of another
    origin (http://127.0.0.2:...) posts a label with fetch(no-cors, text/plain) and a form, and tries
    to read the queue: nothing is labelled, nothing is read. Also with require_token:=false, where
    only the Host, content-type and origin checks stand."""
    import http.server

    from playwright.sync_api import sync_playwright

    node = WebNode(tmp_path / "labels", require_token=require_token)
    attacker = http.server.ThreadingHTTPServer(("127.0.0.2", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=attacker.serve_forever, daemon=True).start()
    try:
        play_episodes(1)
        node.wait_for_queue(1)
        target = node.base
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            context = browser.new_context()
            page = context.new_page()
            page.goto(node.url)
            page.wait_for_selector("#queue li")
            evil = context.new_page()
            evil.goto(f"http://127.0.0.2:{attacker.server_address[1]}/")
            read = evil.evaluate("""async (target) => {
                await fetch(target + '/api/label', {method: 'POST', mode: 'no-cors', credentials: 'include',
                    headers: {'Content-Type': 'text/plain'}, body: '{"episode": 0, "return": 42.5}'});
                try {
                    await fetch(target + '/api/label', {method: 'POST', credentials: 'include',
                        headers: {'Content-Type': 'application/json'}, body: '{"episode": 0, "return": 43.5}'});
                } catch (e) {}
                try { const r = await fetch(target + '/api/queue', {credentials: 'include'}); return await r.text(); }
                catch (e) { return 'refused: ' + e; }
            }""", target)
            assert read.startswith("refused"), read
            evil.set_content(f'<form method="post" action="{target}/api/label" enctype="text/plain">'
                             '<input name=\'{"episode": 0, "return": 44.5, "x": "\' value=\'"}\'></form>')
            evil.evaluate("document.forms[0].submit()")
            evil.wait_for_load_state()
            browser.close()
        assert node.request("/api/labels")[1]["labels"] == []
    finally:
        attacker.shutdown()
        out = node.stop()
    assert "0 label(s) this session" in out, out


def test_labels_reach_the_topic_and_the_bag_and_a_restart_asks_nothing_twice(ros_domain, tmp_path):
    """Label episodes 0 and 1 of three (and correct 1): the labels are on the topic and in the
    labels bag at once; kill -9; a restarted node offers the unlabelled episode 2 at once and,
    offered the same three episodes again, asks only for episode 2; the first session's labels
    (correction last) are all in its repaired bag."""
    labels_dir = tmp_path / "labels"
    capture = Capture()
    try:
        node = WebNode(labels_dir)
        capture.wait_for_publishers({"label": 1})
        play_episodes(3)
        assert [e["episode"] for e in node.wait_for_queue(3)] == [0, 1, 2]
        for episode, value in ((0, 10.0), (1, 20.0), (1, 21.5)):
            status, answer, _ = node.request("/api/label", {"episode": episode, "return": value})
            assert status == 200, answer
        assert capture.spin_until(lambda: len(capture.msgs["label"]) == 3, 20)
        got = [(m.episode, m.return_value, m.labeller, m.length) for m in capture.msgs["label"]]
        assert got == [(0, 10.0, "person/alice", 100), (1, 20.0, "person/alice", 100),
                       (1, 21.5, "person/alice", 100)]
        assert node.request("/api/labels")[1]["labels"][0] == {
            "episode": 1, "return": 21.5, "at": pytest.approx(time.time(), abs=60), "corrections": 1}
        node.stop(signal.SIGKILL)

        node = WebNode(labels_dir)
        # the unlabelled episode 2 of the killed run waits again, before any episode is played
        assert [e["episode"] for e in node.wait_for_queue(1)] == [2]
        play_episodes(3)
        time.sleep(1.0)
        assert [e["episode"] for e in node.wait_for_queue(1)] == [2]
        assert node.request("/api/label", {"episode": 2, "return": 5.0})[0] == 200
        out = node.stop()
        assert not list((labels_dir / ".waiting_episodes").iterdir())  # labelled: no longer kept
    finally:
        capture.close()
    assert "repaired the labels bag of an interrupted session" in out, out
    assert "1 unlabelled episode(s) from before wait for a label" in out, out
    first = sorted(p for p in labels_dir.iterdir() if p.is_dir() and not p.name.startswith("."))[0]
    stored = [(m.episode, m.return_value) for _, _, _, m in iter_decoded(first)]
    assert stored == [(0, 10.0), (1, 20.0), (1, 21.5)]


# -- a real browser -------------------------------------------------------------------------------


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (scripts/test.sh installs it with "
                                             "apt when run as root)")
def test_a_person_labels_an_episode_in_the_browser(ros_domain, tmp_path):
    """Headless Chromium opens the page: the queue lists the episodes, the first one is drawn
    (an SVG path of its 101 states over the arena's zones), plays and scrubs; a label typed into
    the form reaches the topic and the labels bag. The page runs under its strict
    Content-Security-Policy (no eval, so waits use selectors). A screenshot goes to
    build/test_artefacts/."""
    import re

    from playwright.sync_api import expect, sync_playwright

    labels_dir = tmp_path / "labels"
    capture = Capture()
    node = WebNode(labels_dir)
    try:
        capture.wait_for_publishers({"label": 1})
        play_episodes(2)
        node.wait_for_queue(2)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1200, "height": 700})
            errors: list = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(node.url)
            page.wait_for_selector("#queue li")
            assert page.locator("#queue li").count() == 2
            page.wait_for_selector("#arena polyline")
            points = page.get_attribute("#arena polyline", "points").split()
            assert len(points) == 101
            assert page.locator("#arena rect.zone-key").count() == 1
            assert page.locator("#arena rect.zone-treasure").count() == 1
            assert page.text_content("#range") == "between 0 and 100"
            page.click("#play")
            expect(page.locator("#step")).to_have_text(re.compile(r"step [1-9]\d* / 100"), timeout=5000)
            page.fill("#scrub", "50")
            page.dispatch_event("#scrub", "input")
            assert page.text_content("#step") == "step 50 / 100"
            ARTEFACTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(ARTEFACTS / "labelling_page.png"))
            page.fill("#return", "7.25")
            page.click("#submit")
            page.wait_for_selector("#history tr")
            assert page.text_content("#history tr td:nth-child(2)") == "7.25"
            assert errors == []
            browser.close()
        assert capture.spin_until(lambda: len(capture.msgs["label"]) == 1, 20)
        label = capture.msgs["label"][0]
        assert (label.episode, label.return_value, label.labeller) == (0, 7.25, "person/alice")
    finally:
        node.stop()
        capture.close()
    session = next(p for p in labels_dir.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert [(m.episode, m.return_value) for _, _, _, m in iter_decoded(session)] == [(0, 7.25)]


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (scripts/test.sh installs it with "
                                             "apt when run as root)")
def test_a_pixel_task_is_played_from_the_frames_the_model_sees(ros_domain, tmp_path):
    """key_pixels through the graph, env_sim not rendering: the page's episodes carry no pixel
    numbers (no plot, no arena: the frames are the view) and their frames are the observed image
    (from nmrm/observation_image), each pixel drawn 4x4, shown in a real browser; a label is taken
    as for any task. Every episode is gold (gold_every 1): the oracle judges it by its privileged
    state (the positions), not the pixels."""
    from PIL import Image
    from playwright.sync_api import sync_playwright

    node = WebNode(tmp_path / "labels", task="key_pixels", gold_every=1)
    try:
        play_episodes(1, task="key_pixels")
        queue = node.wait_for_queue(1)
        episode = queue[0]["episode"]
        status, info, _ = node.request("/api/info")
        assert status == 200 and info["arena"] is None
        status, body, _ = node.request(f"/api/episode/{episode}")
        assert status == 200 and body["states"][0] == [] and len(body["states"]) == queue[0]["length"] + 1
        assert body["frames"] == list(range(queue[0]["length"] + 1))
        raw = urllib.request.urlopen(urllib.request.Request(f"{node.base}/api/episode/{episode}/frame/0",
                                                            headers={"X-Token": node.token} if node.token else {}),
                                     timeout=10)
        frame = np.asarray(Image.open(io.BytesIO(raw.read())).convert("RGB"))
        assert frame.shape == (128, 128, 3)
        assert len(np.unique(frame[::4, ::4].reshape(-1, 3), axis=0)) > 2  # zones and the agent's blob
        np.testing.assert_array_equal(frame[::4, ::4], frame[3::4, 3::4])  # 4x4 blocks of one colour
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1200, "height": 700})
            page.goto(node.url)
            page.wait_for_function("() => { const f = document.querySelector('img.frame');"
                                   " return f && !f.hidden && f.complete && f.naturalWidth === 128; }", timeout=20000)
            browser.close()
        status, answer, _ = node.request("/api/label", {"episode": episode, "return": 3.0},
                                         headers={"Origin": node.base})
        assert status == 200 and answer["return"] == 3.0, answer
        status, team, _ = node.request("/api/team")
        assert status == 200 and team["gold_episodes"] == 1, team
    finally:
        out = node.stop()
    assert "is not a gold episode" not in out, out


def test_an_episode_of_your_own_task_is_plotted_and_played_as_video(ros_domain, tmp_path):
    """A Gymnasium task (CartPole, episodes of varying length) has no arena: the page plots each of
    its 4 state dimensions over the episode's steps with a cursor at the step shown, plays the
    frames env_sim rendered (render:=true, every 2nd step) as a video under the same controls,
    and takes any number as its return. A screenshot goes to build/test_artefacts/."""
    from playwright.sync_api import sync_playwright

    task = "gym:CartPole-v1,xy=0/2"  # the page also draws the cart's x against the pole's angle
    node = WebNode(tmp_path / "labels", task=task)
    try:
        play_episodes(3, task=task, render=True, render_every=2)
        queue = node.wait_for_queue(3)
        lengths = {e["length"] for e in queue}
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1200, "height": 700})
            errors: list = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(node.url)
            page.wait_for_selector("#dims polyline.dim")
            assert page.locator("#dims polyline.dim").count() == 4
            first = queue[0]["length"]
            assert len(page.get_attribute("#dims polyline.dim", "points").split()) == first + 1
            assert page.text_content("#range") == "any number"
            page.fill("#scrub", "3")
            page.dispatch_event("#scrub", "input")
            assert page.text_content("#step") == f"step 3 / {first}"
            assert float(page.get_attribute("#dims line.cursor", "x1")) == pytest.approx(100 * 3 / first)
            assert len(page.get_attribute("#arena polyline.path", "points").split()) == 4  # xy: steps 0..3
            frame = page.locator("#frame")
            assert frame.is_visible() and frame.get_attribute("data-step") == "2"  # frames at 0, 2, 4, ...
            # not page.wait_for_function: when its first check fails it polls by evaluating the
            # string in the page, which the page's CSP refuses (a flaky failure on a loaded machine)
            deadline = time.monotonic() + 10
            while not page.evaluate("document.getElementById('frame').complete") and time.monotonic() < deadline:
                time.sleep(0.05)
            assert page.evaluate("document.getElementById('frame').naturalWidth") == 240
            status, body, headers = node.request(f"/api/episode/{queue[0]['episode']}")
            assert body["frames"] == sorted(set(range(0, first + 1, 2)) | {first}), body["frames"]
            ARTEFACTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(ARTEFACTS / "labelling_page_your_own_task.png"))
            page.fill("#return", "-1234.5")
            page.click("#submit")
            page.wait_for_selector("#history tr")
            assert page.text_content("#history tr td:nth-child(2)") == "-1234.5"
            assert errors == []
            browser.close()
    finally:
        out = node.stop()
    assert "labelled episode" in out, out
    assert len(lengths) > 1, lengths  # CartPole's random episodes (seed 0) vary in length


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (scripts/test.sh installs it with "
                                             "apt when run as root)")
def test_a_person_compares_two_episodes_in_the_browser(ros_domain, tmp_path):
    """feedback:=preferences: the page draws two episodes side by side (an SVG path each) and
    plays them; a click on "left", the → key and "can't tell" give two TrajectoryPreference
    messages (Space after a click, and Ctrl+=, answer nothing) on the topic and in the labels bag (can't tell: none), and a restarted page does not
    offer the compared pairs again."""
    import re

    from playwright.sync_api import expect, sync_playwright

    labels_dir = tmp_path / "labels"
    capture = Capture()
    node = WebNode(labels_dir, feedback="preferences")
    try:
        capture.wait_for_publishers({"preference": 1})
        play_episodes(3)
        deadline = time.monotonic() + 60
        while len(node.request("/api/pairs")[1]["pairs"]) < 3:
            assert time.monotonic() < deadline, "".join(node.lines)
            time.sleep(0.2)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1400, "height": 800})
            errors: list = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(node.url)
            page.wait_for_selector("#view-a svg.arena polyline")
            assert page.is_hidden("#viewer") and page.is_visible("#compare")
            for side in ("a", "b"):
                assert len(page.get_attribute(f"#view-{side} svg.arena polyline", "points").split()) >= 1
                assert page.locator(f"#view-{side} svg.arena rect.zone-key").count() == 1
            page.click("#pair-play")
            expect(page.locator("#pair-step")).to_have_text(re.compile(r"step [1-9]\d* / 100"), timeout=5000)
            first = page.text_content("#pair-title")
            page.click("#left")
            page.wait_for_selector("#comparisons tr")
            expect(page.locator("#pair-title")).not_to_have_text(first)
            second = page.text_content("#pair-title")
            assert "Space: play / pause both" in page.text_content("#shortcuts")
            page.keyboard.press(" ")  # plays / pauses: never presses the focused "left" button again
            page.keyboard.press("Control+=")  # the browser's zoom, not "equal"
            page.wait_for_timeout(500)
            assert page.locator("#comparisons tr").count() == 1 and page.text_content("#pair-title") == second
            page.keyboard.press("ArrowRight")
            page.wait_for_selector("#comparisons tr:nth-child(2)")
            third = page.text_content("#pair-title")
            page.keyboard.press("s")
            expect(page.locator("#pair-title")).not_to_have_text(third)
            ARTEFACTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(ARTEFACTS / "comparison_page.png"))
            rows = [page.text_content(f"#comparisons tr:nth-child({i}) td:nth-child(3)") for i in (1, 2)]
            assert sorted(rows) == ["left", "right"]
            assert errors == []
            browser.close()
        assert capture.spin_until(lambda: len(capture.msgs["preference"]) == 2, 20)
        got = sorted((m.episode_a, m.episode_b, m.preference, m.labeller) for m in capture.msgs["preference"])
        assert {g[2] for g in got} == {1, -1} and all(g[3] == "person/alice" and g[0] != g[1] for g in got)
    finally:
        node.stop()
        capture.close()
    session = next(p for p in labels_dir.iterdir() if p.is_dir() and not p.name.startswith("."))
    stored = sorted((m.episode_a, m.episode_b, m.preference, m.labeller) for _, _, _, m in iter_decoded(session))
    assert stored == got
    again = WebNode(labels_dir, feedback="preferences")
    try:
        deadline = time.monotonic() + 30
        while not again.request("/api/pairs")[1]["pairs"]:
            assert time.monotonic() < deadline, "".join(again.lines)
            time.sleep(0.2)
        offered = {(p["a"], p["b"]) for p in again.request("/api/pairs")[1]["pairs"]}
        compared = {(min(a, b), max(a, b)) for a, b, _, _ in got}
        assert offered and not offered & compared, (offered, compared)
        assert again.request("/api/comparisons")[1]["comparisons"] == []
    finally:
        again.stop()
