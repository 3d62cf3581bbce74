"""The labelling page's HTTP API under generated wrong requests (property-based, with Hypothesis),
served by the real server (`WebServer`, aiohttp on a loopback port): any JSON body, any path under
/api/, any content type gets an answer below 500 with a JSON error, and nothing is labelled unless
the request was a valid label. (The browser tests in tests/test_labeller_web.py drive the page.)"""

from __future__ import annotations

import json
import math
import urllib.error
import urllib.request

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nmrm_ros.labelling.queue import LabelQueue
from nmrm_ros.labelling.web_app import make_app
from nmrm_ros.web_server import WebServer

TOKEN = "t" * 32
EPISODES = (3, 4)

JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=10)
LABEL_LIKE = st.fixed_dictionaries(
    {}, optional={"episode": st.sampled_from([*EPISODES, 99, -1, "3", True, None, 3.0, 2**80]) | JSON,
                  "return": st.floats() | st.integers(-10**6, 10**6) | JSON, "extra": JSON})


@pytest.fixture(scope="module")
def server():
    queue = LabelQueue("key")
    for e in EPISODES:
        queue.add(e, np.zeros((101, 2), np.float32))
    labelled = []
    srv = WebServer(make_app(queue, lambda label, ep: labelled.append((label.episode, label.value)),
                             {"labeller": "person/test"}, token=TOKEN, feedback="both",
                             on_compare=lambda c, a, b: labelled.append((c.a, c.b, c.p))), port=0)
    srv.start()
    yield srv, queue, labelled
    srv.stop()


def request(srv, path: str, body: bytes | None = None, content_type: str = "application/json"):
    """(status, decoded JSON answer or None, content type)."""
    req = urllib.request.Request(f"http://127.0.0.1:{srv.port}{path}", data=body,
                                 method="POST" if body is not None else "GET")
    req.add_header("X-Token", TOKEN)
    if body is not None:
        req.add_header("Content-Type", content_type)
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            status, raw, kind = r.status, r.read(), r.headers.get("Content-Type", "")
    except urllib.error.HTTPError as exc:
        status, raw, kind = exc.code, exc.read(), exc.headers.get("Content-Type", "")
    answer = json.loads(raw) if kind.startswith("application/json") else None
    return status, answer, kind


COMPARE_LIKE = st.fixed_dictionaries(
    {}, optional={"a": st.sampled_from([*EPISODES, 99, -1, "3", True, None, 3.0]) | JSON,
                  "b": st.sampled_from([*EPISODES, 99, "4", False]) | JSON,
                  "preference": st.sampled_from(["a", "b", "equal", "A", "left", "", 1, None]) | JSON})


def valid_comparison(body) -> bool:
    if not isinstance(body, dict):
        return False
    a, b = body.get("a"), body.get("b")
    return (type(a) is int and type(b) is int and a in EPISODES and b in EPISODES and a != b
            and body.get("preference") in ("a", "b", "equal"))


def valid_label(body) -> bool:
    if not isinstance(body, dict):
        return False
    e, r = body.get("episode"), body.get("return")
    return (type(e) is int and e in EPISODES and type(r) in (int, float) and math.isfinite(r)
            and 0 <= r <= 90)  # Key's return range


SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@SETTINGS
@given(body=st.one_of(LABEL_LIKE, JSON), path=st.sampled_from(["/api/label", "/api/skip"]))
def test_any_json_body_gets_a_clean_answer_and_labels_only_when_valid(server, body, path):
    srv, queue, labelled = server
    before = len(labelled)
    status, answer, kind = request(srv, path, json.dumps(body, allow_nan=True).encode())
    assert status < 500 and kind.startswith("application/json"), (body, status)
    if path == "/api/label":
        assert (status == 200) == valid_label(body), (body, status, answer)
        assert len(labelled) == before + (status == 200)
    else:
        assert len(labelled) == before
    if status != 200:
        assert isinstance(answer.get("error"), str) and "\n" not in answer["error"], answer


@SETTINGS
@given(body=st.one_of(COMPARE_LIKE, JSON), path=st.sampled_from(["/api/compare", "/api/cant_tell"]))
def test_any_json_body_gets_a_clean_answer_and_compares_only_when_valid(server, body, path):
    srv, _, labelled = server
    before = len(labelled)
    status, answer, kind = request(srv, path, json.dumps(body, allow_nan=True).encode())
    assert status < 500 and kind.startswith("application/json"), (body, status)
    if path == "/api/compare":
        assert (status == 200) == valid_comparison(body), (body, status, answer)
        assert len(labelled) == before + (status == 200)
    else:
        assert len(labelled) == before
    if status != 200:
        assert isinstance(answer.get("error"), str) and "\n" not in answer["error"], answer


@SETTINGS
@given(raw=st.binary(max_size=300), kind=st.sampled_from(["application/json", "text/plain", "",
                                                          "application/x-www-form-urlencoded"]))
def test_any_bytes_of_any_content_type_label_nothing(server, raw, kind):
    srv, _, labelled = server
    before = len(labelled)
    try:
        body = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        body = None
    status, answer, _ = request(srv, "/api/label", raw, content_type=kind)
    assert status < 500, (raw, kind, status)
    if kind != "application/json" or not valid_label(body):
        assert status >= 400 and len(labelled) == before, (raw, kind, status, answer)


@SETTINGS
@given(segments=st.lists(st.one_of(st.sampled_from(["episode", "frame", "3", "4", "99", "0",
                                                    "label", "queue", "info", "labels", "pairs",
                                                    "comparisons", "compare", ".."]),
                                   st.from_regex(r"[0-9]{1,25}", fullmatch=True),
                                   st.text(st.characters(codec="ascii", categories=("L", "N")), max_size=6)),
                         max_size=5))
def test_any_path_under_the_api_gets_an_answer_below_500(server, segments):
    srv, _, _ = server
    status, _, _ = request(srv, "/api/" + "/".join(segments))
    assert status < 500, (segments, status)
