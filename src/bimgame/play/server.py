"""The web server of ``bimgame play`` (aiohttp): the page, its websocket and the game loop.

One :class:`~bimgame.play.session.PlaySession` per server, stepped by one asyncio task at the
session's :attr:`~bimgame.play.session.PlaySession.tick_hz` (30 times a second on the maze, 55 on
the labyrinth; slower when a tick takes longer, e.g. while the MPC expert plans) in the event
loop's thread — the websocket handlers run in the same thread, so the session needs no locks.
Each tick the session's state (JSON) and its frame (a JPEG, encoded only when the board changed)
go to every connected client through a sender task of its own that always sends the
latest tick and skips those it had no time for: a slow or stalled client never delays the game or
the others.

**Several tabs** watch the same game and any of them can control it (the latest pressed key
counts). A closed tab releases its keys. With no client connected the game pauses (nothing is
stepped or recorded) and goes on when a page connects again.

**Robustness.** A message that is not understood is answered with an ``error`` message, logged and
ignored (:mod:`bimgame.play.protocol`); an error inside a tick is logged and the loop goes on.
Websockets from another web site (an ``Origin`` that is not this server) are refused, and a server
bound to a loopback address answers only requests for ``localhost``/``127.0.0.1``/``[::1]`` (no
DNS rebinding), so a page on the internet cannot drive the game or write into a recording through
the person's browser.

**Stopping.** SIGINT (Ctrl-C) or SIGTERM stops the loop, tells the clients (``bye``), closes the
sockets and the HTTP server; the caller then closes the session (which records the person's
unfinished episode, truncated) and the recording (which finishes the Minari build).
"""

from __future__ import annotations

import asyncio
import collections
import importlib.resources
import io
import itertools
import json
import logging
import signal
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web
from PIL import Image

from bimgame.play.controls import KEY_ACTIONS
from bimgame.play.protocol import MAX_MESSAGE_CHARS, apply_message
from bimgame.play.session import PlaySession

__all__ = ["PlayServer", "serve", "encode_jpeg"]

log = logging.getLogger("bimgame.play")

#: Static files of the page, served from the package (``bimgame/play/static``).
STATIC = {"index.html": "text/html", "play.js": "text/javascript", "play.css": "text/css"}
#: Largest websocket message read at all (larger ones close that socket); messages up to this size
#: but over :data:`~bimgame.play.protocol.MAX_MESSAGE_CHARS` are answered with an error.
MAX_FRAME_BYTES = 64 * 1024
#: Replies (errors) waiting for a slow client before the oldest are dropped.
OUTBOX = 16
JPEG_QUALITY = 90
#: Errors logged per client (every one is still answered).
LOGGED_ERRORS = 20
#: Host names that mean this computer.
LOOPBACK_NAMES = {"localhost", "127.0.0.1", "::1"}


def encode_jpeg(rgb, quality: int = JPEG_QUALITY) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="JPEG", quality=quality)
    return buffer.getvalue()


class _Client:
    """One websocket and its sender task: the latest tick, and replies in order."""

    def __init__(self, ident: int, ws: web.WebSocketResponse):
        self.ident, self.ws = ident, ws
        self.latest: tuple[str, bytes] | None = None
        self.outbox: collections.deque[str] = collections.deque(maxlen=OUTBOX)
        self.ready = asyncio.Event()
        self.errors = 0

    def push(self, message: dict[str, Any]) -> None:
        self.outbox.append(json.dumps(message))
        self.ready.set()

    def offer(self, state: str, frame: bytes) -> None:
        self.latest = (state, frame)
        self.ready.set()

    async def send_loop(self) -> None:
        while not self.ws.closed:
            await self.ready.wait()
            self.ready.clear()
            while self.outbox:
                await self.ws.send_str(self.outbox.popleft())
            if self.latest is not None:
                (state, frame), self.latest = self.latest, None
                await self.ws.send_str(state)
                await self.ws.send_bytes(frame)


class PlayServer:
    """Serves ``session`` on ``host``:``port`` (0: any free port) while started, ``hz`` ticks a second
    (None: the session's :attr:`~bimgame.play.session.PlaySession.tick_hz`)."""

    def __init__(self, session: PlaySession, *, host: str = "127.0.0.1", port: int = 8765, hz: float | None = None):
        self.session, self.host, self.port = session, host, port
        self.hz = float(session.tick_hz if hz is None else hz)
        self.clients: dict[int, _Client] = {}
        self._ids = itertools.count(1)
        self._static = {
            name: importlib.resources.files("bimgame.play").joinpath("static", name).read_bytes() for name in STATIC
        }
        self._runner: web.AppRunner | None = None
        self._loop_task: asyncio.Task | None = None
        self._frame_key: tuple | None = None
        self._frame: bytes = b""
        self._tick_times: collections.deque[float] = collections.deque(maxlen=round(self.hz) + 1)
        self.url = ""
        self._loopback_only = _host_name(host) in LOOPBACK_NAMES

    # ----------------------------------------------------------------- life cycle
    async def start(self) -> str:
        """Start serving; returns the page's URL (with the port actually bound)."""
        app = web.Application(middlewares=[self._check_host])
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static_file)
        app.router.add_get("/ws", self._websocket)
        self._runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=5.0)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
        port = self._runner.addresses[0][1]  # the port bound (port 0: a free one)
        host = f"[{self.host}]" if ":" in self.host else self.host
        self.url = f"http://{host}:{port}/"
        self._loop_task = asyncio.create_task(self._game_loop(), name="bimgame-play-loop")
        return self.url

    async def stop(self, message: str = "the server stopped") -> None:
        """Stop the game loop, say goodbye to every client, close the sockets and the server."""
        if self._loop_task is not None:
            self._loop_task.cancel()
            try:
                await self._loop_task
            except asyncio.CancelledError:
                pass
            self._loop_task = None
        for client in list(self.clients.values()):
            try:
                await asyncio.wait_for(client.ws.send_str(json.dumps({"type": "bye", "message": message})), 1.0)
                await asyncio.wait_for(client.ws.close(code=1001, message=b"server stopping"), 2.0)
            except (Exception, asyncio.TimeoutError):  # noqa: BLE001 - a client that is gone already
                pass
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    # ----------------------------------------------------------------- the game loop
    async def _game_loop(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.hz
        deadline = loop.time()
        while True:
            if self.clients:  # nobody watching: the game pauses
                try:
                    self._tick()
                except Exception:  # a bug in a tick must not stop the server; it is logged
                    log.exception("error in the game loop (the game goes on)")
            deadline += period
            delay = deadline - loop.time()
            if delay < -5 * period:  # far behind (a stalled machine): no burst of catch-up ticks
                deadline = loop.time()
            await asyncio.sleep(max(0.0, delay))

    def _tick(self) -> None:
        session = self.session
        session.tick()
        now = time.monotonic()
        self._tick_times.append(now)
        key = (session.episode, session.steps)
        if key != self._frame_key:
            self._frame, self._frame_key = encode_jpeg(session.frame()), key
        state = session.snapshot()
        state["clients"] = len(self.clients)
        state["server_hz"] = self.measured_hz
        text = json.dumps(state)
        for client in self.clients.values():
            client.offer(text, self._frame)

    @property
    def measured_hz(self) -> float:
        """Ticks per second over the last second."""
        times = self._tick_times
        return (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 0.0

    # ----------------------------------------------------------------- HTTP
    async def _index(self, request: web.Request) -> web.Response:
        return web.Response(
            body=self._static["index.html"],
            content_type="text/html",
            charset="utf-8",
            headers={"Cache-Control": "no-store"},
        )

    async def _static_file(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in STATIC:
            raise web.HTTPNotFound(text=f"no such file: {name}")
        return web.Response(
            body=self._static[name], content_type=STATIC[name], charset="utf-8", headers={"Cache-Control": "no-store"}
        )

    @web.middleware
    async def _check_host(self, request: web.Request, handler) -> web.StreamResponse:
        """Bound to a loopback address, answer only requests addressed to one: a web site whose name
        is made to resolve to 127.0.0.1 (DNS rebinding) gets nothing."""
        if self._loopback_only and _host_name(request.host) not in LOOPBACK_NAMES:
            log.warning("refused a request for host %r (this server answers localhost only)", request.host)
            raise web.HTTPForbidden(text="this server answers requests for localhost only")
        return await handler(request)

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        origin = request.headers.get("Origin")
        if origin is not None and urlsplit(origin).netloc != request.host:
            log.warning("refused a websocket from origin %s (this server is %s)", origin, request.host)
            raise web.HTTPForbidden(text="websockets from other sites are refused")
        # no compression: JPEG frames do not compress, deflating them would only cost CPU
        ws = web.WebSocketResponse(max_msg_size=MAX_FRAME_BYTES, heartbeat=20.0, compress=False)
        await ws.prepare(request)
        client = _Client(next(self._ids), ws)
        self.clients[client.ident] = client
        log.info("client %d connected from %s (%d connected)", client.ident, request.remote, len(self.clients))
        client.push(self._hello())
        sender = asyncio.create_task(client.send_loop(), name=f"bimgame-play-send-{client.ident}")
        try:
            async for msg in ws:
                if msg.type in (WSMsgType.TEXT, WSMsgType.BINARY):
                    reply = apply_message(self.session, client.ident, msg.data)
                    if reply is not None:
                        client.errors += 1
                        if client.errors <= LOGGED_ERRORS:  # a flood of bad messages does not flood the log
                            last = client.errors == LOGGED_ERRORS
                            log.warning(
                                "client %d: %s%s",
                                client.ident,
                                reply["message"],
                                " (further errors of this client are not logged)" if last else "",
                            )
                        client.push(reply)
                elif msg.type == WSMsgType.ERROR:
                    log.warning("client %d: websocket error %s", client.ident, ws.exception())
        finally:
            self.clients.pop(client.ident, None)
            self.session.drop_client(client.ident)
            sender.cancel()
            try:
                await sender
            except (asyncio.CancelledError, Exception):  # noqa: BLE001 - the socket is gone: nothing to report
                pass
            log.info("client %d left (%d connected)", client.ident, len(self.clients))
        return ws

    def _hello(self) -> dict[str, Any]:
        s = self.session
        return {
            "type": "hello",
            "task": s.task,
            "puzzle": s.board.puzzle,
            "max_steps": s.max_steps,
            "hz": self.hz,
            "keys": KEY_ACTIONS,
            "agent": None if s.agent is None else s.agent.description,
            "recording": None if s.recording is None else s.recording.status["dir"],
            "clients": len(self.clients),
            "max_message_chars": MAX_MESSAGE_CHARS,
            "tabs": "every tab shows the same game and any tab can control it",
        }


def serve(
    session: PlaySession, *, host: str = "127.0.0.1", port: int = 8765, on_ready: Callable[[str], None] | None = None
) -> None:
    """Serve ``session`` until SIGINT or SIGTERM; ``on_ready(url)`` is called once the server
    listens. Must run in the main thread (signal handlers). Does not close the session."""

    async def main() -> None:
        server = PlayServer(session, host=host, port=port)
        url = await server.start()
        finished = asyncio.Event()
        loop = asyncio.get_running_loop()
        signals = (signal.SIGINT, signal.SIGTERM)
        for sig in signals:
            loop.add_signal_handler(sig, finished.set)
        if on_ready is not None:
            on_ready(url)
        try:
            await finished.wait()
        finally:
            for sig in signals:  # a second Ctrl-C while stopping interrupts at once
                loop.remove_signal_handler(sig)
            await server.stop()

    asyncio.run(main())


def _host_name(host: str) -> str:
    """The name in a ``Host`` header or bind address, without port and brackets (lower case)."""
    host = host.strip().lower()
    if host.startswith("["):  # [::1]:8765
        return host[1:].split("]", 1)[0]
    if host.count(":") == 1:  # name:port
        return host.split(":", 1)[0]
    return host  # a name, or a bare IPv6 address
