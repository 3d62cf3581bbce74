"""Serving an aiohttp app (the labelling page, the Foxglove server) from a thread beside a ROS node.

`serve(app, host, port, certfile, keyfile, trusted_network)` is how a node starts one: TLS when a
certificate is given (HTTPS / WSS only: a plain-HTTP request to the port gets no answer), and no
start beyond loopback without TLS unless the network is trusted (`nmrm_ros.tls`). The server then
knows the `Host` values a browser sends for it (`allowed_hosts`) and its own URL.
"""

from __future__ import annotations

import asyncio
import errno
import ipaddress
import socket
import ssl
import threading

from aiohttp import web

from .tls import LOOPBACK, TLSError, exposure_error, server_context

def is_any_address(host: str) -> bool:
    """True for a host that binds every address ("", 0.0.0.0, ::, written any way)."""
    if host in ("", "0.0.0.0", "::"):
        return True
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return False


def _host_form(name: str) -> str:
    """How a browser writes `name` in a Host header: lower case, an IPv6 address compressed and in
    brackets."""
    try:
        address = ipaddress.ip_address(name)
    except ValueError:
        return name.lower()
    return f"[{address.compressed}]" if address.version == 6 else address.compressed


class WebServer:
    """Serves `app` on (host, port) from a thread with its own event loop, over TLS with
    `ssl_context`. `start()` returns once the socket is bound (`port` then holds the real port,
    e.g. after port 0); `stop()` closes it."""

    def __init__(self, app: web.Application, host: str = "127.0.0.1", port: int = 8080,
                 ssl_context: ssl.SSLContext | None = None) -> None:
        self.app, self.host, self.port, self.ssl_context = app, host, port, ssl_context
        self.loop = asyncio.new_event_loop()
        self.runner: web.AppRunner | None = None
        self.thread = threading.Thread(target=self.loop.run_forever, name="web-server", daemon=True)

    @property
    def scheme(self) -> str:
        """"https" under TLS, else "http" (a WebSocket client uses wss / ws)."""
        return "https" if self.ssl_context is not None else "http"

    def url(self, path: str = "/") -> str:
        """This server's URL (the bound port included); on every address, by this machine's name
        (what people on other machines type, and the name a certificate is made for)."""
        host = socket.gethostname() if is_any_address(self.host) else self.host
        host = f"[{host}]" if ":" in host else host
        return f"{self.scheme}://{host}:{self.port}{path}"

    def allowed_hosts(self) -> set | None:
        """The `Host` header values that name this server ("name:port", lower case); None when it
        listens on every address (any name may reach it; the token guards it)."""
        if is_any_address(self.host):
            return None
        names = LOOPBACK if self.host in LOOPBACK else (self.host,)
        default = 443 if self.ssl_context is not None else 80  # a browser leaves this port out
        ports = ("", f":{self.port}") if self.port == default else (f":{self.port}",)
        return {_host_form(n) + port for n in names for port in ports}

    def start(self, timeout: float = 10.0) -> None:
        """Bind and serve; OSError if it cannot (a port outside 0-65535 included: the socket
        layer raises OverflowError for that, which the nodes' one-line errors would miss)."""
        if not 0 <= int(self.port) <= 65535:
            raise OSError(errno.EINVAL, f"port {self.port} is not one of 0-65535")
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self.loop).result(timeout)

    async def _start(self) -> None:
        self.runner = web.AppRunner(self.app, access_log=None)
        await self.runner.setup()
        site = web.TCPSite(self.runner, self.host, self.port, ssl_context=self.ssl_context)
        await site.start()
        self.port = site._server.sockets[0].getsockname()[1]

    def stop(self, timeout: float = 5.0) -> None:
        if self.runner is not None and self.thread.is_alive():
            try:
                asyncio.run_coroutine_threadsafe(self.runner.cleanup(), self.loop).result(timeout)
            finally:
                self.loop.call_soon_threadsafe(self.loop.stop)
                self.thread.join(timeout)


def serve(app: web.Application, host: str, port: int, certfile: str = "", keyfile: str = "",
          trusted_network: bool = False) -> WebServer:
    """Start `app` on host:port (over TLS with certfile/keyfile); TLSError (a ValueError) for a
    bad certificate or a server beyond loopback without TLS or trust, OSError if it cannot bind."""
    context = server_context(certfile, keyfile)
    error = exposure_error(host, context is not None, trusted_network)
    if error:
        raise TLSError(error)
    server = WebServer(app, host, port, context)
    server.start()
    return server
