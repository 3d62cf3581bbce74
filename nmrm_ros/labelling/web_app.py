"""The labelling page's HTTP server (aiohttp), running in a thread of its own beside a ROS node.

Routes (JSON unless said; every one behind the access token when there is one):
  GET  /                      the page (static/page.html, page.js, page.css)
  GET  /api/info              task, labeller, return range ([null, null]: any number), the arena's
                              zones (null: a task of the user's), how the queue is ordered, and
                              what to judge (`info`: the instruction, the zones' legend)
  GET  /api/queue             finished unlabelled episodes, in the order they are asked
  GET  /api/episode/{n}       one episode's states (L + 1, state size; an image task's without
                              its pixels), the steps that have a frame (rendered, or on an
                              image task the image the model sees), and its label if any
  GET  /api/episode/{n}/frame/{t}  the frame of step t (image/jpeg or image/png)
  GET  /api/episode/{n}/frames     the steps that have a frame so far (takes nothing)
  POST /api/label             {"episode": n, "return": x}: label (again: a correction)
  POST /api/skip              {"episode": n}
  GET  /api/labels            this session's labels of the person asking, newest first
  GET  /api/team              who labelled how much, the team's agreement (and gold errors)
  GET  /api/pairs             pairs of episodes to compare, best first, and why
  POST /api/compare           {"a": n, "b": m, "preference": "a" | "b" | "equal"}: a comparison
                              (again: a correction)
  POST /api/cant_tell         {"a": n, "b": m}: not asked again, nothing published
  GET  /api/comparisons       this session's comparisons of the person asking, newest first

A page serves one person or a team: `tokens` maps each person's access token to their name, and
every request is answered for the person whose token it carries (their queue, their labels, their
name on every label they give). With `assignment` "split" (the queue's) an episode one person has
open is not offered to the others; "overlap" asks everyone about everything (for agreement).

Safety (Jupyter's defaults are the bar): the `Host` header must name this server (`allowed_hosts`;
a DNS-rebinding page's host is refused, 403); the token (if any) must come with every request, as
the `X-Token` header, or for a GET as a `token` query parameter or the cookie a GET / with the
right token sets (HttpOnly, SameSite=Strict: never sent by another site's page; Secure under
TLS), compared in
constant time (401); a POST must be `application/json` (415: a cross-site form or no-cors fetch
cannot send that without a CORS preflight, which is never granted) and, if it says where it
comes from, from this server's own origin (403); bodies over `max_body` bytes are refused (413);
labels are validated (a finite number within the task's range, an episode that is here); every
answer is JSON or a static file with a Content-Security-Policy that allows our own scripts only,
and the page writes every value with textContent, never as HTML.
"""

from __future__ import annotations

import hmac
import json
from importlib import resources
from typing import Callable

from aiohttp import web

from ..tasks.arena import arena
from .queue import PREFERENCES, LabelError, LabelQueue

CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; img-src 'self'; "
       "frame-ancestors 'none'; base-uri 'none'; form-action 'none'")
STATIC = {"page.js": "text/javascript", "page.css": "text/css", "page.html": "text/html"}


def _error(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


TOKEN_COOKIE = "nmrm_token"
PERSON = web.RequestKey("person", str)  # who the request is from (by its token)


def make_app(queue: LabelQueue, on_label: Callable, info: dict, token: str | None = None,
             max_body: int = 4096, frames=None, allowed_hosts: set | None = None,
             tokens: dict | None = None, team: Callable | None = None,
             on_compare: Callable | None = None, feedback: str = "returns") -> web.Application:
    """The page's application. `on_label(label, episode)` is called (in the server's thread) for
    every accepted label (`label.person` gave it), before the answer is sent: it publishes and
    stores it; `on_compare(comparison, episode_a, episode_b)` likewise for every comparison.
    `feedback`: what the page asks for (returns | preferences | both; the comparison routes
    answer 404 with returns). `tokens`: access token -> person (a team; or `token` for the queue's one person;
    neither: no token, the queue's first person); `info`: extra fields of /api/info;
    `team()`: extra fields of /api/team (e.g. gold errors); `frames`: a FrameStore of rendered
    frames; `allowed_hosts`: the `Host` values ("name:port", lower case) this server answers to
    (None: any; the set may be filled once the port is known)."""
    from ..tasks import task_info

    image_shape = task_info(queue.task).image_shape
    image_values = task_info(queue.task).image_values  # an image state's pixels: not sent as numbers

    def frame_steps(ep) -> list:
        """The steps of `ep` with a frame: those rendered (env_sim render:=true), else on an image
        task every step, its frame drawn from the image the model sees (`image_state_frame`)."""
        rendered = frames.steps(ep.episode) if frames is not None else []
        return rendered or (list(range(len(ep.states))) if image_shape else [])

    def frame_of(episode: int, step: int) -> tuple | None:
        """(format, bytes) of the frame of (episode, step): the rendered one, else the image of an
        image task's state there (PNG, each pixel a block), else None."""
        rendered = frames.get(episode, step) if frames is not None else None
        if rendered is not None or not image_shape:
            return rendered
        from ..tasks.frames import encode_frame, image_state_frame

        try:
            states = queue.get(episode).states
        except LabelError:
            return None
        if not 0 <= step < len(states):
            return None
        shown = image_state_frame(states[step], image_shape)
        return "png", encode_frame(shown, width=shown.shape[1], fmt="png")
    if tokens is None and token:
        tokens = {token: queue.people[0]}
    if tokens is not None and not set(tokens.values()) <= set(queue.people):
        raise ValueError("every token must belong to one of the queue's people")

    def _person(given: str) -> str | None:
        """The person whose token `given` is (compared in constant time), or None."""
        found = None
        for known, person in tokens.items():
            if given and hmac.compare_digest(given.encode(), known.encode()):
                found = person
        return found

    def _valid(given: str) -> bool:
        return _person(given) is not None

    async def _refused(request: web.Request) -> web.Response | None:
        host = request.headers.get("Host", "").lower()
        if allowed_hosts is not None and host not in allowed_hosts:
            return _error(403, f"Host {host!r} is not this server's")
        if tokens:
            given = request.headers.get("X-Token", "")
            if not given:
                given = request.cookies.get(TOKEN_COOKIE, "")
                if request.method == "GET" and not _valid(given):
                    given = request.query.get("token", "")
            if not _valid(given):
                return _error(401, "missing or wrong access token")
            request[PERSON] = _person(given)
        else:
            request[PERSON] = queue.people[0]
        if request.method not in ("GET", "HEAD"):
            if request.content_type != "application/json":
                return _error(415, "a request that changes anything must be application/json")
            origin = request.headers.get("Origin")
            if origin is not None and origin.lower() != f"{request.scheme}://{host}":
                return _error(403, f"cross-origin request from {origin!r} refused")
        return None

    @web.middleware
    async def guard(request: web.Request, handler):
        refused = await _refused(request)
        if refused is not None:
            refused.headers["Content-Security-Policy"] = CSP
            refused.headers["Cache-Control"] = "no-store"
            return refused
        try:
            response = await handler(request)
        except web.HTTPRequestEntityTooLarge:
            response = _error(413, f"request body over {max_body} bytes")
        except web.HTTPException as exc:
            response = _error(exc.status, exc.reason)
        response.headers["Content-Security-Policy"] = CSP
        response.headers["X-Content-Type-Options"] = "nosniff"
        response.headers["Referrer-Policy"] = "no-referrer"
        response.headers["Cache-Control"] = "no-store"
        given = request.query.get("token", "")
        if tokens and request.path == "/" and _valid(given):
            response.set_cookie(TOKEN_COOKIE, given, httponly=True, samesite="Strict", path="/",
                                secure=request.secure)  # under TLS: never sent over plain HTTP
        return response

    async def static(request: web.Request) -> web.Response:
        name = request.match_info.get("name", "page.html")
        if name not in STATIC:
            return _error(404, "no such file")
        body = resources.files(__package__).joinpath("static", name).read_text()
        return web.Response(text=body, content_type=STATIC[name])

    async def api_info(request: web.Request) -> web.Response:
        person = request[PERSON]
        return web.json_response({"task": queue.task, "range": [queue.low, queue.high],
                                  "arena": arena(queue.task), "ordering": queue.ordering, **info,
                                  "person": person, "labeller": f"person/{person}",
                                  "team": list(queue.people), "assignment": queue.assignment,
                                  "feedback": feedback, "pair_ordering": queue.pair_ordering})

    async def api_queue(request: web.Request) -> web.Response:
        return web.json_response({"episodes": [
            {"episode": e.episode, "length": e.length, "finished_at": e.finished_at,
             "why": e.why, "spread": e.spread, "predicted": e.predicted}
            for e in queue.pending(request[PERSON])]})

    async def api_episode(request: web.Request) -> web.Response:
        try:
            ep = queue.take(int(request.match_info["episode"]), request[PERSON])
        except LabelError as exc:
            return _error(404, str(exc))
        label = queue.label_of(ep.episode, request[PERSON])
        return web.json_response({"episode": ep.episode, "length": ep.length,
                                  # an image state's pixels are seen as its frames, not plotted
                                  "states": ep.states[:, image_values:].astype(float).round(5).tolist(),
                                  "frames": frame_steps(ep),
                                  "frames_expected": bool(image_shape) or (frames is not None and frames.any()),
                                  "label": None if label is None else label.value})

    async def api_frames(request: web.Request) -> web.Response:
        """The steps of an episode that have a frame so far (the page asks again while frames are
        still arriving; unlike /api/episode/{n}, this takes nothing)."""
        try:
            ep = queue.get(int(request.match_info["episode"]))
        except LabelError as exc:
            return _error(404, str(exc))
        return web.json_response({"episode": ep.episode, "frames": frame_steps(ep)})

    async def api_frame(request: web.Request) -> web.Response:
        episode, step = int(request.match_info["episode"]), int(request.match_info["step"])
        frame = frame_of(episode, step)
        if frame is None:
            return _error(404, f"no frame of episode {episode} step {step}")
        return web.Response(body=frame[1], content_type=f"image/{frame[0]}")

    async def _body(request: web.Request, fields: tuple = ("episode",)) -> dict:
        if request.content_length is not None and request.content_length > max_body:
            raise web.HTTPRequestEntityTooLarge(max_size=max_body, actual_size=request.content_length)
        raw = await request.read()  # also refused past client_max_size
        try:
            body = json.loads(raw)
        except (ValueError, UnicodeDecodeError):
            raise LabelError("the body is not JSON") from None
        if not isinstance(body, dict):
            raise LabelError("the body must be a JSON object")
        for name in fields:
            value = body.get(name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise LabelError(f"'{name}' must be an integer, got {value!r}")
        return body

    async def api_label(request: web.Request) -> web.Response:
        try:
            body = await _body(request)
            if "return" not in body:
                raise LabelError("missing 'return'")
            label, episode = queue.label(body["episode"], body["return"], request[PERSON])
        except LabelError as exc:
            return _error(400, str(exc))
        on_label(label, episode)
        return web.json_response({"episode": label.episode, "return": label.value,
                                  "corrections": label.corrections})

    async def api_skip(request: web.Request) -> web.Response:
        try:
            body = await _body(request)
            queue.skip(body["episode"], request[PERSON])
        except LabelError as exc:
            return _error(400, str(exc))
        return web.json_response({"episode": body["episode"], "skipped": True})

    async def api_labels(request: web.Request) -> web.Response:
        return web.json_response({"labels": [
            {"episode": r.episode, "return": r.value, "at": r.at, "corrections": r.corrections}
            for r in queue.history(request[PERSON])]})

    async def api_team(request: web.Request) -> web.Response:
        from .agreement import label_report

        records = [{"task": queue.task, "source": "", "episode": r.episode, "length": 1,
                    "return": r.value, "labeller": f"person/{r.person}", "stamp_ns": int(r.at * 1e9)}
                   for r in queue.history()]
        report = label_report(records)
        people = [{"person": p, "labels": report["labellers"].get(f"person/{p}", {}).get("labels", 0)}
                  for p in queue.people]
        return web.json_response({"people": people, "assignment": queue.assignment,
                                  "agreement": report["agreement"], **(team() if team else {})})

    def _asks_comparisons() -> None:
        if feedback == "returns":
            raise web.HTTPNotFound(reason="this page asks for returns only (labeller_web feedback:=preferences or both compares)")

    async def api_pairs(request: web.Request) -> web.Response:
        _asks_comparisons()
        pairs = queue.pending_pairs(request[PERSON])
        return web.json_response({"ordering": queue.pair_ordering, "pairs": [
            {"a": a, "b": b, "disagreement": score,
             "why": "" if score is None else f"models disagree: P(left better) spread {score:.2f}"}
            for a, b, score in pairs]})

    async def api_compare(request: web.Request) -> web.Response:
        _asks_comparisons()
        try:
            body = await _body(request, ("a", "b"))
            if "preference" not in body:
                raise LabelError("missing 'preference'")
            record, ep_a, ep_b = queue.compare(body["a"], body["b"], body["preference"], request[PERSON])
        except LabelError as exc:
            return _error(400, str(exc))
        if on_compare is not None:
            on_compare(record, ep_a, ep_b)
        return web.json_response({"a": record.a, "b": record.b, "preference": body["preference"],
                                  "corrections": record.corrections})

    async def api_cant_tell(request: web.Request) -> web.Response:
        _asks_comparisons()
        try:
            body = await _body(request, ("a", "b"))
            queue.cant_tell(body["a"], body["b"], request[PERSON])
        except LabelError as exc:
            return _error(400, str(exc))
        return web.json_response({"a": body["a"], "b": body["b"], "cant_tell": True})

    async def api_comparisons(request: web.Request) -> web.Response:
        _asks_comparisons()
        names = {v: k for k, v in PREFERENCES.items()}
        return web.json_response({"comparisons": [
            {"a": c.a, "b": c.b, "preference": names[c.p], "at": c.at, "corrections": c.corrections}
            for c in queue.comparison_history(request[PERSON])]})

    app = web.Application(middlewares=[guard], client_max_size=max_body)
    app.add_routes([web.get("/", static), web.get("/static/{name}", static),
                    web.get("/api/info", api_info), web.get("/api/queue", api_queue),
                    web.get(r"/api/episode/{episode:\d+}", api_episode),
                    web.get(r"/api/episode/{episode:\d+}/frame/{step:\d+}", api_frame),
                    web.get(r"/api/episode/{episode:\d+}/frames", api_frames),
                    web.post("/api/label", api_label), web.post("/api/skip", api_skip),
                    web.get("/api/labels", api_labels), web.get("/api/team", api_team),
                    web.get("/api/pairs", api_pairs), web.post("/api/compare", api_compare),
                    web.post("/api/cant_tell", api_cant_tell), web.get("/api/comparisons", api_comparisons)])
    return app
