"""A Foxglove WebSocket server (protocol `foxglove.websocket.v1`) that only its owner can open.

Foxglove (the web app, the desktop app) shows a live graph through a WebSocket server that
advertises channels (topic, `cdr` encoding, the type's ros2msg schema) and streams each subscribed
channel's serialized messages. foxglove-sdk's server (0.30.3) has no hook to refuse a connection,
and a browser lets *any* web page open ws://127.0.0.1:PORT: so this server is written on aiohttp,
with the labelling page's rules (Jupyter's defaults are the bar):
  - the `Host` header must name this server (`allowed_hosts`; a DNS-rebinding page is refused),
  - the access token must come as the `token` query parameter (compared in constant time),
  - a browser's `Origin` must be one of `allowed_origins` (default: the Foxglove web app); a
    client that sends no Origin (the desktop app, scripts) passes on the token alone.
A refused handshake gets 401/403 with one line and nothing else. Read-only: clients can subscribe
and unsubscribe, nothing more (no client publishing, services or parameters).

    server = FoxgloveServer(token="...")
    web = serve(server.app, "127.0.0.1", 8765); server.attach(web.loop)   # nmrm_ros.web_server
    cid = server.add_channel("/nmrm/viz/pose", "geometry_msgs/msg/PoseStamped", schema_text)
    server.publish(cid, stamp_ns, cdr_bytes)        # from any thread
"""

from __future__ import annotations

import asyncio
import hmac
import json
import struct
import threading
from dataclasses import dataclass, field

from aiohttp import WSMsgType, web

SUBPROTOCOL = "foxglove.websocket.v1"
FOXGLOVE_APP = "https://app.foxglove.dev"
_MESSAGE_DATA = 0x01


def _data_frame(subscription_id: int, stamp_ns: int, payload: bytes) -> bytes:
    """A Message Data frame: opcode 0x01, subscription id (u32), receive time (u64 ns), payload."""
    return struct.pack("<BIQ", _MESSAGE_DATA, subscription_id, stamp_ns) + payload


@dataclass
class Channel:
    id: int
    topic: str
    type_name: str  # pkg/msg/Type
    schema: str     # ros2msg text, dependencies included
    latched: bool = False  # keep the last message and send it to each new subscriber (a map)
    last: tuple | None = None  # (stamp ns, payload) of a latched channel

    def advertisement(self) -> dict:
        return {"id": self.id, "topic": self.topic, "encoding": "cdr", "schemaName": self.type_name,
                "schema": self.schema, "schemaEncoding": "ros2msg"}


@dataclass
class _Client:
    ws: web.WebSocketResponse
    subscriptions: dict = field(default_factory=dict)  # subscription id -> channel id


class FoxgloveServer:
    """The protocol over an aiohttp app (`self.app`); channels and messages may be added from any
    thread once `attach(loop)` named the loop the app runs on."""

    def __init__(self, token: str, allowed_origins: tuple = (FOXGLOVE_APP,), allowed_hosts: set | None = None,
                 name: str = "nmrm_ros") -> None:
        if not token:
            raise ValueError("a Foxglove server needs an access token")
        self.token, self.allowed_origins, self.allowed_hosts = token, tuple(allowed_origins), allowed_hosts
        self.name = name
        self.channels: dict = {}  # id -> Channel
        self.clients: list = []
        self.loop: asyncio.AbstractEventLoop | None = None
        self.lock = threading.Lock()
        self.refused = 0
        self.app = web.Application()
        self.app.router.add_get("/", self._handle)

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    # -- the owner's side (any thread) --------------------------------------------------------
    def add_channel(self, topic: str, type_name: str, schema: str, latched: bool = False) -> int:
        """Advertise a channel (to clients connected now and later); returns its id. A latched
        channel's last message goes to each new subscriber at once (as transient local topics do)."""
        with self.lock:
            cid = len(self.channels) + 1
            channel = self.channels[cid] = Channel(cid, topic, type_name, schema, latched)
        self._soon(self._broadcast({"op": "advertise", "channels": [channel.advertisement()]}))
        return cid

    def publish(self, channel_id: int, stamp_ns: int, payload: bytes) -> None:
        """Send one serialized message to every client subscribed to the channel."""
        channel = self.channels.get(channel_id)
        if channel is not None and channel.latched:
            channel.last = (stamp_ns, payload)
        self._soon(self._send_data(channel_id, stamp_ns, payload))

    def _soon(self, coro) -> None:
        if self.loop is None or self.loop.is_closed():
            coro.close()
            return
        asyncio.run_coroutine_threadsafe(coro, self.loop)

    # -- the clients' side (the app's loop) ---------------------------------------------------
    def _refusal(self, request: web.Request) -> web.Response | None:
        host = request.headers.get("Host", "").lower()
        if self.allowed_hosts is not None and host not in self.allowed_hosts:
            return web.Response(status=403, text=f"Host {host!r} is not this server's\n")
        if not hmac.compare_digest(request.query.get("token", "").encode(), self.token.encode()):
            return web.Response(status=401, text="missing or wrong access token (?token=...)\n")
        origin = request.headers.get("Origin")
        if origin is not None and origin not in self.allowed_origins:
            return web.Response(status=403, text=f"Origin {origin!r} is not allowed\n")
        return None

    async def _handle(self, request: web.Request) -> web.StreamResponse:
        refusal = self._refusal(request)
        if refusal is not None:
            self.refused += 1
            return refusal
        ws = web.WebSocketResponse(protocols=(SUBPROTOCOL,), max_msg_size=1 << 16)
        if not ws.can_prepare(request).ok:
            return web.Response(status=400, text=f"a WebSocket with subprotocol {SUBPROTOCOL} only\n")
        await ws.prepare(request)
        if ws.ws_protocol != SUBPROTOCOL:
            await ws.close(code=1002, message=f"subprotocol {SUBPROTOCOL} only".encode())
            return ws
        client = _Client(ws)
        await ws.send_json({"op": "serverInfo", "name": self.name, "capabilities": [], "metadata": {}})
        self.clients.append(client)  # before the advertisement: a channel added meanwhile is not missed
        with self.lock:
            channels = [c.advertisement() for c in self.channels.values()]
        await ws.send_json({"op": "advertise", "channels": channels})
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    await self._on_text(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    await self._status(ws, 1, "this server takes no client messages")
        finally:
            self.clients.remove(client)
        return ws

    async def _on_text(self, client: _Client, text: str) -> None:
        try:
            msg = json.loads(text)
            op = msg["op"]
            if op == "subscribe":
                for sub in msg["subscriptions"]:
                    sid, cid = int(sub["id"]), int(sub["channelId"])
                    if cid not in self.channels:
                        await self._status(client.ws, 1, f"no channel {cid}")
                    elif sid in client.subscriptions:
                        await self._status(client.ws, 1, f"subscription id {sid} is in use")
                    else:
                        client.subscriptions[sid] = cid
                        last = self.channels[cid].last
                        if last is not None:
                            await client.ws.send_bytes(_data_frame(sid, *last))
            elif op == "unsubscribe":
                for sid in msg["subscriptionIds"]:
                    client.subscriptions.pop(int(sid), None)
            else:
                await self._status(client.ws, 1, f"unsupported op {op!r} (read-only server)")
        except (ValueError, KeyError, TypeError) as exc:
            await self._status(client.ws, 2, f"bad request: {exc!r}"[:200])

    @staticmethod
    async def _status(ws: web.WebSocketResponse, level: int, message: str) -> None:
        if not ws.closed:
            await ws.send_json({"op": "status", "level": level, "message": message})

    async def _broadcast(self, payload: dict) -> None:
        for client in list(self.clients):
            if not client.ws.closed:
                await client.ws.send_json(payload)

    async def _send_data(self, channel_id: int, stamp_ns: int, payload: bytes) -> None:
        for client in list(self.clients):
            for sid, cid in list(client.subscriptions.items()):
                if cid == channel_id and not client.ws.closed:
                    await client.ws.send_bytes(_data_frame(sid, stamp_ns, payload))
