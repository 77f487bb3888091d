"""The station's web server: the page's assets, its WebSocket and the tuning API (aiohttp).

It runs on an asyncio loop of its own thread (``StationServer.start``), never on the ROS
executor: nothing the browser does (a slow network, a page that sends too much) can delay a
callback of the control chain. It knows nothing of ROS either: what it shows and what it
commands go through a ``StationBackend`` (the node, or a fake in the tests).

Routes: ``/`` (the page), ``/static/<asset>`` (only the files of ``ASSETS``, looked up by name,
so no request can reach another file), ``/ws`` (telemetry out, input in; see
``station.protocol``), ``/camera`` (the camera's frames and detections, binary and text
WebSocket messages; the backend subscribes to the camera only while a page watches),
``GET /api/params`` and ``POST /api/param`` (tuning).

Security: bound to loopback by default. On any other address a token is required (the node
makes one when none is given): on every request, as ``?token=`` (the URL printed at start),
an ``Authorization: Bearer`` header, or the cookie the page gets when it is loaded with the
token. A cross-site request is refused whatever the address (``Origin`` not this server's): a
web page the operator happens to open elsewhere must not drive the vessel through a station on
127.0.0.1.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
import hmac
import ipaddress
import json
import socket
from pathlib import Path
import threading
import time
from typing import Any, Protocol
from urllib.parse import urlsplit

from aiohttp import web, WSMsgType

from enbarr_plugins.station.protocol import (
    boxes_message, Boxes, CameraFrame, DriveInput, DriveLease, frame_message, InputError,
    parse_input, Verdict)

STATIC_DIR = Path(__file__).with_name('static')
#: Every file the server hands out: name -> content type. Nothing else is served.
ASSETS = {
    'index.html': 'text/html',
    'station.js': 'text/javascript',
    'station.css': 'text/css',
}
TOKEN_COOKIE = 'enbarr_station_token'
#: WebSocket close code when the page's input stopped for longer than input_timeout.
CLOSE_INPUT_TIMEOUT = 4000
_WATCH = web.AppKey('watch', asyncio.Task)
#: How long a close waits for the page's answer [s].
CLOSE_WAIT = 1.0


class StationBackend(Protocol):
    """What the server needs of the vessel (the node implements it)."""

    def hello(self) -> dict[str, Any]:
        """Return static facts for the page: vessel kind, command kind, rates, button names."""

    def telemetry(self) -> dict[str, Any]:
        """Return a snapshot of the latest state, JSON-ready (called at the telemetry rate)."""

    def command(self, inp: DriveInput | None) -> None:
        """Publish the command of ``inp``; None: publish the neutral command once."""

    def surface_stop(self, stop: bool) -> str:
        """Set or release the vessel's surface stop; '' when done, else why not."""

    def manipulator(self, direction: int) -> str:
        """Move the manipulator one step amount in ``direction`` (1, -1); '' or why not."""

    def record(self, action: str) -> str:
        """Ask the recorder to ``start`` or ``stop``; '' when asked, else why not."""

    def camera_watch(self, watch: bool) -> None:
        """Take that a page started (True) or the last one stopped (False) watching."""

    def camera(self) -> tuple[CameraFrame | None, list[Boxes]]:
        """Return the latest camera frame and the latest detections (oldest first)."""

    async def list_params(self) -> list[dict[str, Any]]:
        """Every declared parameter of every node of the process."""

    async def set_param(self, node: str, name: str, value: Any) -> dict[str, Any]:
        """Set one parameter; ``{'ok': bool, 'reason': str}``."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address (or ``localhost``)."""
    if host == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class StationServer:
    """The aiohttp application on its own thread (see the module docstring)."""

    def __init__(self, backend: StationBackend, host: str, port: int, token: str,
                 telemetry_rate: float, input_timeout: float, camera_rate: float = 5.0,
                 clock: Callable[[], float] = time.monotonic,
                 log: Callable[[str], None] = print) -> None:
        if not is_loopback(host) and not token:
            raise ValueError(f'host {host!r} is not loopback: a token is required')
        self.backend = backend
        self.host, self.port, self.token = host, port, token
        self.period = 1.0 / telemetry_rate
        self.camera_period = 1.0 / camera_rate
        self._watchers: set[web.WebSocketResponse] = set()   # pages on /camera
        self.frames_sent = 0
        self.lease = DriveLease(input_timeout)
        self.clock = clock
        self.log = log
        self.bad_inputs = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._sockets: set[web.WebSocketResponse] = set()
        self._closing: set[asyncio.Future[bool]] = set()
        self._told: set[web.WebSocketResponse] = set()   # watchers told who drives

    @property
    def pages(self) -> int:
        """Return how many pages are connected (driving or watching)."""
        return len(self._sockets)

    # -- the application ---------------------------------------------------------------------
    def app(self) -> web.Application:
        """Build the aiohttp application (the tests run it on their own loop too)."""
        app = web.Application(middlewares=[self._guard])
        app.router.add_get('/', self._index)
        app.router.add_get('/static/{name}', self._static)
        app.router.add_get('/ws', self._ws)
        app.router.add_get('/camera', self._camera)
        app.router.add_get('/api/params', self._params)
        app.router.add_post('/api/param', self._set_param)
        app.on_startup.append(self._on_startup)
        app.on_shutdown.append(self._on_shutdown)
        return app

    def _token_ok(self, request: web.Request) -> bool:
        if not self.token:
            return True
        auth = request.headers.get('Authorization', '')
        given = (request.query.get('token') or request.cookies.get(TOKEN_COOKIE)
                 or (auth[7:] if auth.startswith('Bearer ') else ''))
        return hmac.compare_digest(given.encode(), self.token.encode())

    @web.middleware
    async def _guard(self, request: web.Request,
                     handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
                     ) -> web.StreamResponse:
        if not self._token_ok(request):
            return web.Response(status=401, text='token required (see the URL the station '
                                'printed at start)\n')
        origin = request.headers.get('Origin')
        if origin is not None and urlsplit(origin).netloc != request.host:
            return web.Response(status=403, text='cross-site request refused\n')
        response = await handler(request)
        if self.token and request.query.get('token'):
            response.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite='Strict')
        response.headers['Cache-Control'] = 'no-store'
        return response

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return self._asset('index.html')

    async def _static(self, request: web.Request) -> web.StreamResponse:
        return self._asset(request.match_info['name'])

    def _asset(self, name: str) -> web.StreamResponse:
        kind = ASSETS.get(name)  # a name of the table, never a path built from the request
        if kind is None:
            raise web.HTTPNotFound(text=f'no asset {name!r}\n')
        return web.Response(body=(STATIC_DIR / name).read_bytes(), content_type=kind,
                            charset='utf-8')

    async def _params(self, request: web.Request) -> web.StreamResponse:
        return web.json_response({'nodes': await self.backend.list_params()})

    async def _set_param(self, request: web.Request) -> web.StreamResponse:
        try:
            body = await request.json()
            node, name, value = body['node'], body['name'], body['value']
            if not isinstance(node, str) or not isinstance(name, str):
                raise TypeError('node and name must be strings')
        except (ValueError, KeyError, TypeError) as err:
            return web.json_response({'ok': False, 'reason': f'bad request: {err}'},
                                     status=400)
        return web.json_response(await self.backend.set_param(node, name, value))

    async def _ws(self, request: web.Request) -> web.StreamResponse:
        # A page on a lost network never answers a close: wait for it a second, not ten.
        ws = web.WebSocketResponse(timeout=CLOSE_WAIT, heartbeat=None, max_msg_size=64 * 1024)
        await ws.prepare(request)
        self._sockets.add(ws)
        sender = asyncio.ensure_future(self._send_telemetry(ws))
        try:
            await ws.send_json({'type': 'hello', **self.backend.hello()})
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                await self._on_message(ws, msg.data)
        finally:
            sender.cancel()
            self._sockets.discard(ws)
            self._told.discard(ws)
            if self.lease.close(ws):
                self.log('station: the driving page closed: neutral sent, commands stop')
                self.backend.command(None)
        return ws

    async def _on_message(self, ws: web.WebSocketResponse, text: str) -> None:
        try:
            msg = json.loads(text)
            if isinstance(msg, dict) and msg.get('type') == 'surface_stop':
                # From any page, driving or watching: whoever sees trouble may stop the vessel
                if not isinstance(msg.get('stop'), bool):
                    raise InputError('surface_stop needs "stop": true or false')
                reason = self.backend.surface_stop(msg['stop'])
                if reason:
                    await ws.send_json({'type': 'error', 'reason': reason})
                else:
                    self.log(f'station: surface stop {"set" if msg["stop"] else "released"} '
                             'from a page')
                return
            if isinstance(msg, dict) and msg.get('type') == 'record':
                # From any page: recording commands nothing on the vessel
                if msg.get('action') not in ('start', 'stop'):
                    raise InputError('record needs "action": "start" or "stop"')
                reason = self.backend.record(msg['action'])
                if reason:
                    await ws.send_json({'type': 'error', 'reason': f'record: {reason}'})
                return
            if isinstance(msg, dict) and msg.get('type') == 'manipulator':
                direction = msg.get('direction')
                if direction not in (1, -1) or isinstance(direction, bool):
                    raise InputError('manipulator needs "direction": 1 or -1')
                if self.lease.holder is not ws:
                    # An actuator: only the page that drives moves it
                    reason = 'only the driving page moves the manipulator'
                else:
                    reason = self.backend.manipulator(direction)
                if reason:
                    await ws.send_json({'type': 'error', 'reason': reason})
                return
            if not isinstance(msg, dict) or msg.get('type') != 'input':
                raise InputError(f'unknown message {str(msg)[:80]!r}')
            inp = parse_input(msg)
        except ValueError as err:   # json.JSONDecodeError and InputError are ValueErrors
            self.bad_inputs += 1
            await ws.send_json({'type': 'error', 'reason': str(err)})
            return
        verdict = self.lease.offer(ws, inp, self.clock())
        if verdict == Verdict.TAKEN:
            self._told.discard(ws)
            self.backend.command(inp)
        elif verdict == Verdict.NOT_HOLDER and ws not in self._told:
            # Once per page, not at its input rate: the telemetry shows who drives.
            self._told.add(ws)
            await ws.send_json({'type': 'error', 'reason': 'another page drives: this one '
                                'only watches'})

    async def _send_telemetry(self, ws: web.WebSocketResponse) -> None:
        while not ws.closed:
            now = self.clock()
            data = self.backend.telemetry()
            last = self.lease.last if self.lease.holder is ws else None
            data['drive'] = {
                'holder': self.lease.holder is ws, 'taken': self.lease.holder is not None,
                'ack_seq': last.seq if last else None, 'ack_t': last.page_time if last else None,
                'age': self.lease.age(now) if self.lease.holder is ws else None,
                'ended': self.lease.ended, 'timeouts': self.lease.timeouts}
            await ws.send_json({'type': 'telemetry', **data})
            await asyncio.sleep(self.period)

    async def _camera(self, request: web.Request) -> web.StreamResponse:
        ws = web.WebSocketResponse(timeout=CLOSE_WAIT, heartbeat=None, max_msg_size=4096)
        await ws.prepare(request)
        self._watchers.add(ws)
        if len(self._watchers) == 1:
            self.backend.camera_watch(True)
        sender = asyncio.ensure_future(self._send_camera(ws))
        try:
            async for _ in ws:   # the page only watches: what it says is ignored
                pass
        finally:
            sender.cancel()
            self._watchers.discard(ws)
            if not self._watchers:
                self.backend.camera_watch(False)
        return ws

    async def _send_camera(self, ws: web.WebSocketResponse) -> None:
        """At ``camera_period``: the latest frame if new, and detections not sent yet."""
        last: tuple[int, int] | None = None
        told: set[tuple[int, int]] = set()
        while not ws.closed:
            frame, detections = self.backend.camera()
            if frame is not None and (frame.sec, frame.nanosec) != last:
                last = (frame.sec, frame.nanosec)
                await ws.send_bytes(frame_message(frame))
                self.frames_sent += 1
            stamps = set()
            for boxes in detections:
                stamp = (boxes.sec, boxes.nanosec)
                stamps.add(stamp)
                if stamp not in told:
                    await ws.send_json(boxes_message(boxes))
            told = stamps   # only those the backend still keeps can come again
            await asyncio.sleep(self.camera_period)

    async def _watch(self) -> None:
        """End the lease of a page whose inputs stopped: neutral once, then silence."""
        period = min(0.05, self.lease.timeout / 4.0)
        while True:
            holder = self.lease.holder
            if self.lease.check(self.clock()):
                self.log(f'station: no input for {self.lease.timeout:g} s: neutral sent, '
                         'commands stop')
                self.backend.command(None)
                if isinstance(holder, web.WebSocketResponse):
                    # Not awaited here: the next page's lease is watched meanwhile.
                    task = asyncio.ensure_future(
                        holder.close(code=CLOSE_INPUT_TIMEOUT, message=b'input timeout'))
                    self._closing.add(task)
                    task.add_done_callback(self._closing.discard)
            await asyncio.sleep(period)

    async def _on_startup(self, app: web.Application) -> None:
        app[_WATCH] = asyncio.ensure_future(self._watch())

    async def _on_shutdown(self, app: web.Application) -> None:
        app[_WATCH].cancel()
        await asyncio.gather(*(ws.close(code=1001, message=b'station stopped')
                               for ws in list(self._sockets)), return_exceptions=True)

    # -- the thread ------------------------------------------------------------------------
    def start(self, timeout: float = 10.0) -> None:
        """Serve on a thread of its own; return once the socket is bound (or raise)."""
        self._thread = threading.Thread(target=self._run, name='station_http', daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError('the station server did not start in time')
        if self._error is not None:
            raise self._error

    def _run(self) -> None:
        loop = self._loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        try:
            # A socket of our own, bound before the application starts (a port in use is
            # refused with nothing to undo): port 0 picks a free one, which is then known.
            family = socket.AF_INET6 if ':' in self.host else socket.AF_INET
            sock = socket.create_server((self.host, self.port), family=family)
            self.port = sock.getsockname()[1]
            self._runner = web.AppRunner(self.app(), handle_signals=False, access_log=None)
            loop.run_until_complete(self._runner.setup())
            loop.run_until_complete(web.SockSite(self._runner, sock).start())
        except BaseException as err:  # noqa: BLE001 - handed to start()'s caller
            self._error = err
            if self._runner is not None:
                loop.run_until_complete(self._runner.cleanup())
            loop.close()
            self._ready.set()
            return
        self._ready.set()
        loop.run_forever()
        loop.run_until_complete(self._runner.cleanup())
        loop.close()

    def stop(self, timeout: float = 5.0) -> None:
        """Close every page, stop the loop and wait for the thread."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None or not thread.is_alive():
            return
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout)

    @property
    def url(self) -> str:
        """The URL to open (with the token when there is one)."""
        host = f'[{self.host}]' if ':' in self.host else self.host
        return f'http://{host}:{self.port}/' + (f'?token={self.token}' if self.token else '')
