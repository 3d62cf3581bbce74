"""A client of the labelling page's JSON API (scripts, benchmarks, tests): what a browser tab of
the page does, with the access token of the page's URL."""

from __future__ import annotations

import json
import urllib.error
import urllib.parse
import urllib.request


class PageClient:
    """`PageClient("http://127.0.0.1:8080/?token=...")`; `get(path)` and `post(path, body)` return
    the decoded JSON answer and raise urllib.error.HTTPError on a refusal."""

    def __init__(self, url: str, timeout: float = 10.0) -> None:
        parts = urllib.parse.urlsplit(url)
        self.base = f"{parts.scheme}://{parts.netloc}"
        self.token = urllib.parse.parse_qs(parts.query).get("token", [""])[0]
        self.timeout = timeout

    def _send(self, path: str, data: bytes | None) -> dict:
        req = urllib.request.Request(self.base + path, data=data, method="POST" if data is not None else "GET")
        if self.token:
            req.add_header("X-Token", self.token)
        if data is not None:
            req.add_header("Content-Type", "application/json")
        with urllib.request.urlopen(req, timeout=self.timeout) as r:
            return json.loads(r.read())

    def get(self, path: str) -> dict:
        return self._send(path, None)

    def post(self, path: str, body) -> dict:
        return self._send(path, json.dumps(body).encode())
