"""The station's web server without a browser or ROS: assets, token, WebSocket, failsafe.

A real loopback socket and aiohttp's client; the backend is a fake that records what the
server asks it to publish, and the clock is injected, so the input timeout is judged on a
clock the test moves.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
import json
from typing import Any

import aiohttp
from aiohttp.test_utils import TestClient, TestServer
import pytest

from enbarr_plugins.station.protocol import Boxes, CameraFrame, DriveInput
from enbarr_plugins.station.server import CLOSE_INPUT_TIMEOUT, StationServer

pytestmark = pytest.mark.unit

TIMEOUT = 0.5


class FakeBackend:
    def __init__(self) -> None:
        self.commands: list[DriveInput | None] = []
        self.set_calls: list[tuple[str, str, Any]] = []
        self.manipulator_calls: list[int] = []
        self.record_calls: list[str] = []
        self.record_reason = ''
        self.watching: list[bool] = []
        self.frame: CameraFrame | None = None
        self.boxes: list[Boxes] = []
        self.camera_calls = 0

    def hello(self) -> dict[str, Any]:
        return {'command': 'joy', 'input_rate': 20.0, 'input_timeout': TIMEOUT, 'modes': []}

    def telemetry(self) -> dict[str, Any]:
        return {'mode': 'manual'}

    def command(self, inp: DriveInput | None) -> None:
        self.commands.append(inp)

    def manipulator(self, direction: int) -> str:
        self.manipulator_calls.append(direction)
        return ''

    def record(self, action: str) -> str:
        self.record_calls.append(action)
        return self.record_reason

    def camera_watch(self, watch: bool) -> None:
        self.watching.append(watch)

    def camera(self) -> tuple[CameraFrame | None, list[Boxes]]:
        self.camera_calls += 1
        return self.frame, list(self.boxes)

    async def list_params(self) -> list[dict[str, Any]]:
        return [{'node': '/dp_control', 'params': [{'name': 'kp', 'value': [1.0, 2.0, 3.0]}]}]

    async def set_param(self, node: str, name: str, value: Any) -> dict[str, Any]:
        self.set_calls.append((node, name, value))
        return {'ok': False, 'reason': 'kp[0] = -1.0 is outside [0.0, 10000.0]'}


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def run(body: Callable[[TestClient, FakeBackend, Clock], Awaitable[None]],
        token: str = '') -> FakeBackend:
    backend, clock = FakeBackend(), Clock()
    station = StationServer(backend, '127.0.0.1', 0, token, telemetry_rate=20.0,
                            input_timeout=TIMEOUT, clock=clock, log=lambda _: None)

    async def main() -> None:
        client = TestClient(TestServer(station.app(), host='127.0.0.1'))
        await client.start_server()
        try:
            await asyncio.wait_for(body(client, backend, clock), 30.0)
        finally:
            await client.close()
    asyncio.run(main())
    return backend


def send(seq: int, surge: float = 0.0, t: float | None = None) -> str:
    return json.dumps({'type': 'input', 'seq': seq, 't': 50.0 * seq if t is None else t,
                       'axes': {'surge': surge}, 'buttons': []})


async def until(condition: Callable[[], bool], timeout: float = 10.0) -> None:
    """Wait for ``condition`` on the loop, bounded."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        assert loop.time() < deadline, 'condition not met in time'
        await asyncio.sleep(0.01)


async def next_of(ws: aiohttp.ClientWebSocketResponse, kind: str) -> dict[str, Any]:
    while True:
        msg = await ws.receive_json()
        if msg['type'] == kind:
            return msg


def test_the_page_and_its_assets_are_served():
    async def body(client: TestClient, *_: Any) -> None:
        page = await client.get('/')
        assert page.status == 200 and '<canvas id="map"' in await page.text()
        for name, kind in (('station.js', 'text/javascript'), ('station.css', 'text/css')):
            r = await client.get(f'/static/{name}')
            assert r.status == 200 and r.content_type == kind
        assert (await client.get('/static/nothing.js')).status == 404
    run(body)


@pytest.mark.parametrize('path', [
    '/static/..%2fserver.py', '/static/%2e%2e%2fserver.py', '/static/../server.py',
    '/static/..%2f..%2fprotocol.py', '/static/station.js%2f..%2f..%2fnode.py',
    '/static/%2e%2e/%2e%2e/__init__.py', '/static/..%5cserver.py', '/static//etc/passwd',
    '/static/%2fetc%2fpasswd', '/../../etc/passwd',
])
def test_no_path_reaches_a_file_outside_the_assets(path):
    async def body(client: TestClient, *_: Any) -> None:
        r = await client.get(path, allow_redirects=False)
        text = await r.text()
        assert r.status in (400, 403, 404), (path, r.status)
        assert 'import' not in text and 'root:' not in text
    run(body)


def test_a_token_is_required_on_every_request_and_the_websocket():
    async def body(client: TestClient, *_: Any) -> None:
        for path in ('/', '/static/station.js', '/api/params', '/ws', '/camera'):
            assert (await client.get(path)).status == 401, path
            assert (await client.get(path + '?token=wrong')).status == 401, path
        assert (await client.post('/api/param', json={})).status == 401
        r = await client.get('/?token=s3cret')
        assert r.status == 200
        # The page, loaded with the token, gets it as a cookie for its assets and socket.
        assert (await client.get('/static/station.js')).status == 200
        client.session.cookie_jar.clear()
        assert (await client.get('/static/station.js')).status == 401
        assert (await client.get('/api/params',
                                 headers={'Authorization': 'Bearer s3cret'})).status == 200
        ws = await client.ws_connect('/ws?token=s3cret')
        assert (await ws.receive_json())['type'] == 'hello'
        await ws.close()
    run(body, token='s3cret')


def test_a_non_loopback_address_needs_a_token():
    with pytest.raises(ValueError, match='token is required'):
        StationServer(FakeBackend(), '192.168.1.10', 0, '', 10.0, 0.5)
    StationServer(FakeBackend(), '192.168.1.10', 0, 'x', 10.0, 0.5)   # constructs, binds nothing


def test_a_cross_site_page_is_refused():
    async def body(client: TestClient, *_: Any) -> None:
        evil = {'Origin': 'http://evil.example'}
        assert (await client.get('/ws', headers=evil)).status == 403
        assert (await client.post('/api/param', json={'node': '/a', 'name': 'b', 'value': 1},
                                  headers=evil)).status == 403
        own = {'Origin': f'http://{client.host}:{client.port}'}
        assert (await client.get('/', headers=own)).status == 200
    run(body)


def test_inputs_are_published_and_acknowledged_in_the_telemetry():
    async def body(client: TestClient, backend: FakeBackend, clock: Clock) -> None:
        ws = await client.ws_connect('/ws')
        hello = await ws.receive_json()
        assert hello['type'] == 'hello' and hello['input_timeout'] == TIMEOUT
        await ws.send_str(send(1, surge=0.5))
        await until(lambda: len(backend.commands) == 1)
        assert backend.commands[0].axes[0] == 0.5
        while True:
            t = await next_of(ws, 'telemetry')
            if t['drive']['ack_seq'] == 1:
                break
        assert t['mode'] == 'manual' and t['drive']['holder'] and t['drive']['ack_t'] == 50.0
        await ws.send_str('{not json')
        assert 'Expecting' in (await next_of(ws, 'error'))['reason']
        await ws.send_str(json.dumps({'type': 'input', 'seq': 2, 't': 1.0, 'axes': {'surge': 3}}))
        assert 'axes.surge' in (await next_of(ws, 'error'))['reason']
        await ws.send_str(send(1))   # replayed
        await ws.send_str(send(2, surge=0.1))
        await until(lambda: len(backend.commands) == 2)
        assert backend.commands[1].seq == 2
        await ws.close()
    run(body)


def test_closing_the_driving_page_sends_one_neutral_then_nothing():
    async def body(client: TestClient, backend: FakeBackend, clock: Clock) -> None:
        ws = await client.ws_connect('/ws')
        await ws.receive_json()
        for k in range(1, 4):
            await ws.send_str(send(k, surge=0.8))
        await until(lambda: len(backend.commands) == 3)
        await ws.close()
        await until(lambda: len(backend.commands) == 4)
        assert backend.commands[-1] is None
        clock.now += 10.0       # the watchdog has nothing left to end
        await asyncio.sleep(0.3)
        assert backend.commands.count(None) == 1
    run(body)


def test_a_silent_page_trips_the_failsafe_and_is_closed():
    async def body(client: TestClient, backend: FakeBackend, clock: Clock) -> None:
        ws = await client.ws_connect('/ws')
        await ws.receive_json()
        await ws.send_str(send(1, surge=0.8))
        await until(lambda: len(backend.commands) == 1)
        clock.now += TIMEOUT            # exactly the timeout: still driving
        await asyncio.sleep(0.2)
        assert backend.commands == backend.commands[:1]
        clock.now += 0.1                # now silent for longer than the timeout
        await until(lambda: len(backend.commands) == 2)
        assert backend.commands[-1] is None
        while True:
            msg = await ws.receive()
            if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
                break
        assert (msg.data, msg.extra) == (CLOSE_INPUT_TIMEOUT, 'input timeout')
        await asyncio.sleep(0.2)
        assert backend.commands.count(None) == 1
    run(body)


def test_a_second_page_only_watches():
    async def body(client: TestClient, backend: FakeBackend, clock: Clock) -> None:
        a = await client.ws_connect('/ws')
        b = await client.ws_connect('/ws')
        await a.receive_json()
        await b.receive_json()
        await a.send_str(send(1, surge=0.3))
        await until(lambda: len(backend.commands) == 1)
        await b.send_str(send(1, surge=-1.0))
        assert 'another page drives' in (await next_of(b, 'error'))['reason']
        await b.send_str(send(2, surge=-1.0))
        await b.send_str('{}')            # an error of its own: the one after the refusal
        assert 'unknown message' in (await next_of(b, 'error'))['reason']
        assert len(backend.commands) == 1
        await b.close()                      # a watcher leaving sends no neutral
        await asyncio.sleep(0.1)
        assert None not in backend.commands
        await a.close()
        await until(lambda: backend.commands[-1:] == [None])
    run(body)


def test_the_tuning_api_passes_through_to_the_backend():
    async def body(client: TestClient, backend: FakeBackend, clock: Clock) -> None:
        listed = await (await client.get('/api/params')).json()
        assert listed['nodes'][0]['params'][0]['name'] == 'kp'
        r = await client.post('/api/param', json={'node': '/dp_control', 'name': 'kp',
                                                  'value': [-1.0, 2.0, 3.0]})
        assert r.status == 200
        assert await r.json() == {'ok': False,
                                  'reason': 'kp[0] = -1.0 is outside [0.0, 10000.0]'}
        assert backend.set_calls == [('/dp_control', 'kp', [-1.0, 2.0, 3.0])]
        assert (await client.post('/api/param', data='nope')).status == 400
        assert (await client.post('/api/param', json={'node': 1, 'name': 'kp',
                                                      'value': 1})).status == 400
    run(body)


def test_only_the_driving_page_moves_the_manipulator():
    async def body(client: TestClient, backend: FakeBackend, clock: Clock) -> None:
        a = await client.ws_connect('/ws')
        b = await client.ws_connect('/ws')
        await a.receive_json()
        await b.receive_json()
        await a.send_str(send(1))
        await until(lambda: len(backend.commands) == 1)
        await a.send_str(json.dumps({'type': 'manipulator', 'direction': -1}))
        await until(lambda: backend.manipulator_calls == [-1])
        await b.send_str(json.dumps({'type': 'manipulator', 'direction': 1}))
        assert (await next_of(b, 'error'))['reason'] == ('only the driving page moves the '
                                                         'manipulator')
        for bad in (2, True, '1', None):
            await a.send_str(json.dumps({'type': 'manipulator', 'direction': bad}))
            assert 'direction' in (await next_of(a, 'error'))['reason']
        assert backend.manipulator_calls == [-1]
        await a.close()
        await b.close()
    run(body)


def test_any_page_starts_and_stops_the_recorder_and_sees_why_not():
    async def body(client: TestClient, backend: FakeBackend, clock: Clock) -> None:
        ws = await client.ws_connect('/ws')
        await ws.receive_json()
        await ws.send_str(json.dumps({'type': 'record', 'action': 'stop'}))
        await ws.send_str(json.dumps({'type': 'record', 'action': 'start'}))
        await until(lambda: backend.record_calls == ['stop', 'start'])
        await ws.send_str(json.dumps({'type': 'record', 'action': 'pause'}))
        assert 'start' in (await next_of(ws, 'error'))['reason']
        backend.record_reason = 'no recorder runs'
        await ws.send_str(json.dumps({'type': 'record', 'action': 'start'}))
        assert (await next_of(ws, 'error'))['reason'] == 'record: no recorder runs'
        assert backend.commands == []     # recording commands nothing on the vessel
        await ws.close()
    run(body)


def test_the_camera_is_watched_only_while_a_page_is_on_it():
    async def body(client: TestClient, backend: FakeBackend, clock: Clock) -> None:
        backend.frame = CameraFrame(7, 9, b'\xff\xd8jpeg')
        backend.boxes = [Boxes(7, 9, ((2, 0.5, 10.0, 20.0, 30.0, 40.0),))]
        a = await client.ws_connect('/camera')
        b = await client.ws_connect('/camera')
        await until(lambda: backend.watching == [True])   # once, for the first page
        frame = await a.receive_bytes()
        # sec 7 and nanosec 9 as big-endian uint32, then the JPEG as it came
        assert frame == bytes([0, 0, 0, 7, 0, 0, 0, 9]) + b'\xff\xd8jpeg'
        assert await a.receive_json() == {'type': 'detections', 'stamp': [7, 9],
                                          'boxes': [[2, 0.5, 10.0, 20.0, 30.0, 40.0]]}
        # Neither is sent again while it is the latest: after a few more rounds of the two
        # senders, the next message is the next image.
        calls = backend.camera_calls
        await until(lambda: backend.camera_calls >= calls + 4)
        backend.frame = CameraFrame(8, 0, b'next')
        assert await a.receive_bytes() == bytes([0, 0, 0, 8, 0, 0, 0, 0]) + b'next'
        await a.close()
        await asyncio.sleep(0.1)
        assert backend.watching == [True]                 # b still watches
        await b.close()
        await until(lambda: backend.watching == [True, False])
    run(body)
