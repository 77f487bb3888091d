"""Node tier: the station node with the ROV's command receiver, driven over its WebSocket.

The executor spins on a thread of its own (the station's server has its own too), the test
speaks the page's protocol with aiohttp's client, and a probe watches the receiver's velocity
goal and io requests: what the vessel does, not what the station says it did.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
import json
from typing import Any

import aiohttp
from geometry_msgs.msg import TwistStamped
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.node import Node
from rclpy.parameter import Parameter
from support.station import SpinningExecutor, until

from enbarr_core.control.command_receiver_node import CommandReceiverNode
from enbarr_core.framework.errors import ConfigurationError
from enbarr_interfaces import convert, topics
from enbarr_plugins.station.node import SurfaceStationNode
from enbarr_plugins.station.server import CLOSE_INPUT_TIMEOUT

pytestmark = pytest.mark.node


def station(context: Any, **params: Any) -> SurfaceStationNode:
    values = {'port': 0, **params}
    return SurfaceStationNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in values.items()])


class Rig:
    """Station (twist) + command receiver on a spinning executor, and a probe."""

    def __init__(self, context: Any, executor: Any, *others: Any) -> None:
        self.receiver = CommandReceiverNode(context=context, parameter_overrides=[
            Parameter('timeout', value=0.5)])
        self.station = station(context, command='twist', max_linear=0.4, max_angular=0.3,
                               input_timeout=0.4)
        self.probe = Node('probe', context=context)
        self.goals: list[tuple[float, ...]] = []
        self.io: list[ParameterMsg] = []
        self.sent: list[tuple[float, ...]] = []   # what the station itself published
        self.probe.create_subscription(
            TwistStamped, topics.SURFACE_TWIST.name,
            lambda m: self.sent.append(tuple(convert.twist_to_nu(m.twist))),
            topics.SURFACE_TWIST.qos)
        self.probe.create_subscription(
            TwistStamped, topics.TRAJECTORY_REQUEST.name,
            lambda m: self.goals.append(tuple(convert.twist_to_nu(m.twist))),
            topics.TRAJECTORY_REQUEST.qos)
        self.probe.create_subscription(ParameterMsg, topics.IO_REQUEST.name, self.io.append,
                                       topics.IO_REQUEST.qos)
        for n in (self.receiver, self.station, self.probe, *others):
            executor.add_node(n)
        self.receiver.start()
        self.station.start()
        for n in others:
            n.start()
        self.spinner = SpinningExecutor(executor)

    def close(self) -> None:
        self.spinner.stop()
        self.station.stop()

    @property
    def ws_url(self) -> str:
        return f'http://127.0.0.1:{self.station.server.port}/ws'


@pytest.fixture
def rig(context: Any, executor: Any) -> Iterator[Rig]:
    r = Rig(context, executor)
    try:
        yield r
    finally:
        r.close()


class Page:
    """The page's sending loop: one input every 50 ms (20 Hz) until stopped."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.seq = 0
        self.axes = {'surge': 0.0, 'yaw': 0.0}
        self.lights = False
        self.buttons: list[str] = []
        self.task = asyncio.ensure_future(self._run())

    async def _run(self) -> None:
        while True:
            self.seq += 1
            await self.ws.send_str(json.dumps({
                'type': 'input', 'seq': self.seq, 't': 50.0 * self.seq, 'axes': self.axes,
                'buttons': self.buttons, 'lights': self.lights}))
            await asyncio.sleep(0.05)


def test_the_page_drives_the_receiver_and_closing_it_stops_the_vessel(rig):
    async def body() -> None:
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(rig.ws_url)
            hello = await ws.receive_json()
            assert hello['command'] == 'twist' and hello['lights_executor'] == 'gpio_12'
            page = Page(ws)
            page.axes = {'surge': 0.5, 'yaw': -1.0}
            page.lights = True
            # 0.5 of max_linear 0.4 m/s ahead, full yaw right at max_angular 0.3 rad/s.
            await until(lambda: rig.goals and rig.goals[-1] == pytest.approx(
                (0.2, 0.0, 0.0, 0.0, 0.0, -0.3)))
            await until(lambda: any(m.name == 'gpio_12' and m.value.bool_value
                                    for m in rig.io))
            assert sum(m.name == 'gpio_12' for m in rig.io) == 1   # on change only
            page.lights = False
            await until(lambda: sum(m.name == 'gpio_12' for m in rig.io) == 2)
            assert rig.io[-1].value.bool_value is False
            page.task.cancel()
            await ws.close()
            await until(lambda: rig.station.neutrals_sent == 1)
            # The station's last word is a zero goal, not the held one.
            await until(lambda: rig.sent[-1] == (0.0,) * 6)
            await until(lambda: rig.goals[-1] == (0.0,) * 6)
            assert not rig.station.driving
    asyncio.run(body())


def test_a_page_that_stops_sending_is_cut_off_and_the_goal_falls_to_zero(rig):
    async def body() -> None:
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(rig.ws_url)
            await ws.receive_json()
            page = Page(ws)
            page.axes = {'surge': 1.0}
            await until(lambda: rig.goals and rig.goals[-1][0] == pytest.approx(0.4))
            sent = rig.station.commands_sent
            page.task.cancel()      # frozen: the socket stays open, nothing comes
            while True:
                msg = await ws.receive()
                if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
                    break
            assert msg.data == CLOSE_INPUT_TIMEOUT
            await until(lambda: rig.goals[-1] == (0.0,) * 6)
            assert rig.station.neutrals_sent == 1
            assert rig.station.commands_sent == sent   # the held command was never repeated
            level, message, values = rig.station.diagnostic_status()
            assert (level, message) == (0, 'no page drives')
            assert (values['input_timeouts'], values['neutrals_sent']) == (1, 1)
    asyncio.run(body())


def test_the_tuning_api_sets_a_parameter_through_the_services(rig):
    async def body() -> None:
        base = rig.ws_url[:-len('ws')]
        async with aiohttp.ClientSession() as session:
            async with session.get(base + 'api/params') as r:
                nodes = {n['node']: n for n in (await r.json())['nodes']}
            assert set(nodes) >= {'/command_receiver', '/station', '/probe'}
            timeout = next(p for p in nodes['/command_receiver']['params']
                           if p['name'] == 'timeout')
            assert (timeout['value'], timeout['unit'], timeout['low'], timeout['high'],
                    timeout['type']) == (0.5, 's', 0.01, 60.0, 'double')
            async with session.post(base + 'api/param', json={
                    'node': '/command_receiver', 'name': 'max_linear', 'value': 2}) as r:
                assert await r.json() == {'ok': True, 'reason': ''}
            assert rig.receiver.get_parameter('max_linear').value == 2.0
            async with session.post(base + 'api/param', json={
                    'node': '/command_receiver', 'name': 'max_linear', 'value': 99.0}) as r:
                answer = await r.json()
            assert answer['ok'] is False and 'max_linear' in answer['reason']
            assert rig.receiver.get_parameter('max_linear').value == 2.0
            async with session.post(base + 'api/param', json={
                    'node': '/command_receiver', 'name': 'max_linear', 'value': 'fast'}) as r:
                assert await r.json() == {'ok': False,
                                          'reason': "max_linear: 'fast' is not a double"}
            async with session.post(base + 'api/param', json={
                    'node': '/nobody', 'name': 'x', 'value': 1}) as r:
                assert (await r.json())['ok'] is False
    asyncio.run(body())


def test_off_loopback_the_node_makes_a_token(context):
    node = station(context, host='192.0.2.7')     # constructed only: nothing is bound
    try:
        assert len(node._token) >= 20 and node.settings.token == ''
    finally:
        node.destroy_node()


@pytest.mark.parametrize('params, words', [
    ({'command': 'joy'}, 'joy.layout'),
    ({'command': 'joy', 'joy.layout': 'enbarr_ds4'}, 'joy.surge'),
    ({'command': 'rudder'}, 'command: one of joy, twist'),
    ({'input_rate': 10.0, 'input_timeout': 0.15}, 'two input periods'),
])
def test_bad_settings_are_refused_naming_the_parameter(context, params, words):
    with pytest.raises(ConfigurationError, match=words):
        station(context, **params)


def test_a_port_in_use_is_refused_at_start_naming_it(context, executor):
    import socket
    taken = socket.create_server(('127.0.0.1', 0))
    try:
        port = taken.getsockname()[1]
        node = station(context, port=port)
        executor.add_node(node)
        with pytest.raises(ConfigurationError, match=f'cannot serve on 127.0.0.1:{port}'):
            node.start()
        assert node.server is None and not node.started
    finally:
        taken.close()


def test_the_telemetry_carries_the_latest_of_each_topic(context, executor, spin):
    """What the page shows, from the messages as the vessel's nodes publish them."""
    import math

    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from enbarr_interfaces.links import LinkBus
    from enbarr_interfaces.obstacles import Obstacle, SEGMENT, to_cloud
    from support.nodes import add, probe

    node = add(executor, station(context, command='twist'))
    source = probe(context, executor, 'source')
    pubs = {spec.name: source.create_topic_publisher(spec) for spec in (
        topics.OBSERVER_ODOMETRY, topics.AZIMUTH_COMMANDS, topics.OBSTACLES, topics.MODE)}
    LinkBus.of(context).connect()
    odom = Odometry()
    odom.pose.pose.position.x, odom.pose.pose.position.y = 1.5, -2.0
    convert.yaw_to_quaternion(math.radians(30.0), odom.pose.pose.orientation)
    odom.twist.twist.linear.x, odom.twist.twist.angular.z = 0.25, -0.1
    pubs[topics.OBSERVER_ODOMETRY.name].publish(odom)
    pubs[topics.AZIMUTH_COMMANDS.name].publish(JointState(
        name=['az_bow', 'az_port_aft'], position=[0.5, -1.0], effort=[1.2, -0.3]))
    pubs[topics.OBSTACLES.name].publish(to_cloud(
        [Obstacle(1, SEGMENT, 3.0, 1.0, 0.2, 4.0, 1.5)], 1, topics.WORLD_FRAME))
    pubs[topics.MODE.name].publish(String(data='automatic'))
    assert spin(executor, lambda: 'mode' in node.telemetry())
    t = node.telemetry()
    assert t['estimate'] == pytest.approx(
        {'x': 1.5, 'y': -2.0, 'z': 0.0, 'yaw': math.radians(30.0), 'u': 0.25, 'v': 0.0,
         'w': 0.0, 'r': -0.1})
    assert t['azimuths'] == [{'name': 'az_bow', 'angle': 0.5, 'thrust': 1.2},
                             {'name': 'az_port_aft', 'angle': -1.0, 'thrust': -0.3}]
    assert t['obstacles'] == [pytest.approx([3.0, 1.0, 4.0, 1.5, 0.2])]
    assert t['mode'] == 'automatic' and 'truth' not in t
    json.dumps(t)   # what the server sends: JSON as it is


def test_the_telemetry_carries_the_rovs_pilot_mode_refusal_and_failsafes(context, executor,
                                                                         spin):
    from std_msgs.msg import String

    from enbarr_interfaces.links import LinkBus
    from support.nodes import add, probe

    node = add(executor, station(context, command='twist'))
    source = probe(context, executor, 'source')
    specs = (topics.PILOT_MODE, topics.PILOT_MODE_REASON, topics.FAILSAFE_ACTIVE)
    pubs = {spec.name: source.create_topic_publisher(spec) for spec in specs}
    LinkBus.of(context).connect()
    pubs[topics.PILOT_MODE.name].publish(String(data='stabilize'))
    pubs[topics.PILOT_MODE_REASON.name].publish(String(
        data='depth_hold refused: no depth sensor heard'))
    pubs[topics.FAILSAFE_ACTIVE.name].publish(String(data='leak: surface since 12.0 s'))
    assert spin(executor, lambda: 'failsafe' in node.telemetry()
                and 'pilot_reason' in node.telemetry() and 'pilot_mode' in node.telemetry())
    t = node.telemetry()
    assert (t['pilot_mode'], t['pilot_reason'], t['failsafe']) == (
        'stabilize', 'depth_hold refused: no depth sensor heard', 'leak: surface since 12.0 s')


def test_the_token_is_printed_but_never_logged(context, executor, capsys):
    node = station(context, token='s3cret-token')
    executor.add_node(node)
    logged: list[str] = []
    node.get_logger().info = logged.append   # type: ignore[method-assign]
    node.start()
    try:
        url = f'http://127.0.0.1:{node.server.port}/?token=s3cret-token'
        assert f'surface station: open {url}' in capsys.readouterr().out
        assert logged and not any('s3cret' in line for line in logged)
    finally:
        node.stop()


def test_the_driving_page_moves_the_manipulator_through_the_receiver(rig):
    async def body() -> None:
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(rig.ws_url)
            hello = await ws.receive_json()
            assert hello['manipulator_executor'] == 'manipulator'
            page = Page(ws)
            await until(lambda: rig.station.driving)
            await ws.send_str(json.dumps({'type': 'manipulator', 'direction': -1}))
            # manipulator_step 50 steps, closing: the keyboard teleop's int32 request
            await until(lambda: any(m.name == 'manipulator' for m in rig.io))
            (request,) = [m for m in rig.io if m.name == 'manipulator']
            assert convert.parameter_value_to_python(request.value) == -50
            page.task.cancel()
            await ws.close()
    asyncio.run(body())


def test_a_gamepad_button_on_the_rov_is_the_pilots_pad_one_request_a_press(rig):
    async def body() -> None:
        def requests(name: str) -> list[Any]:
            return [convert.parameter_value_to_python(m.value) for m in rig.io
                    if m.name == name]

        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(rig.ws_url)
            await ws.receive_json()
            page = Page(ws)
            page.buttons = ['cross']           # held from the first input: arms, no request
            await until(lambda: rig.station.commands_sent >= 3)
            assert requests('pilot_mode') == []
            page.buttons = []
            await until(lambda: rig.station.commands_sent >= 6)
            page.buttons = ['cross']           # docs/rov_gamepad.png: cross is depth hold
            await until(lambda: requests('pilot_mode') == ['depth_hold'])
            page.buttons = ['cross', 'r1', 'dpad_up']   # cross still held: no second request
            await until(lambda: requests('manipulator') == [50]
                        and requests('camera_tilt') == [10.0])
            page.buttons = ['triangle', 'options']      # options: the page's own lights
            await until(lambda: requests('pilot_mode') == ['depth_hold', 'stabilize'])
            n = rig.station.commands_sent
            await until(lambda: rig.station.commands_sent >= n + 3)
            assert requests('pilot_mode') == ['depth_hold', 'stabilize']
            # the lights stay the page's switch (its first input's state, off): the pad's
            # options toggles that switch in the page, the station sends no lights of its own
            assert requests('gpio_12') == [False] and requests('lights') == []
            page.task.cancel()
            await ws.close()
    asyncio.run(body())


def test_the_telemetry_shows_the_lights_and_the_manipulator_state(context, executor, spin):
    from support.nodes import add, probe

    from enbarr_interfaces.links import LinkBus

    node = add(executor, station(context, command='twist'))
    source = probe(context, executor, 'stepper')
    pub = source.create_topic_publisher(topics.IO_STATE)
    LinkBus.of(context).connect()
    assert node.telemetry()['io'] == {'lights': None, 'manipulator': None}
    for name, value in (('manipulator', 120), ('gpio_12', True), ('gpio_13', False)):
        pub.publish(ParameterMsg(name=name, value=convert.python_to_parameter_value(value)))
    assert spin(executor, lambda: node.telemetry()['io'] == {'lights': True,
                                                             'manipulator': 120})


def test_the_record_buttons_start_and_stop_the_recorder(context, executor, tmp_path):
    from enbarr_core.recording.recorder_node import RecorderNode

    rec = RecorderNode(context=context, parameter_overrides=[
        Parameter('path', value=str(tmp_path / 'bag'))])
    r = Rig(context, executor, rec)
    try:
        async def body() -> None:
            async with aiohttp.ClientSession() as session:
                ws = await session.ws_connect(r.ws_url)
                await ws.receive_json()
                await until(lambda: r.station.record('stop') == '')
                await until(lambda: rec.paused)
                await ws.send_str(json.dumps({'type': 'record', 'action': 'start'}))
                await until(lambda: not rec.paused and rec.bag == tmp_path / 'bag_1')
                # The page sees the recorder's own state in the telemetry.
                while True:
                    msg = await ws.receive_json()
                    values = msg.get('diagnostics', {}).get('/recorder', {}).get('values', {})
                    if values.get('bag') == str(tmp_path / 'bag_1'):
                        break
                assert values['recording'] == 'true' and int(values['free_bytes']) > 0
                await ws.close()
        asyncio.run(body())
    finally:
        r.close()


def test_without_a_recorder_the_record_button_says_so(context):
    node = station(context)
    try:
        assert node.record('start') == ('no recorder runs (bringup --record, or a profile with '
                                        'record:)')
    finally:
        node.destroy_node()


def test_the_camera_is_subscribed_while_a_page_watches(rig):
    from sensor_msgs.msg import CompressedImage

    from enbarr_interfaces import detections

    image_pub = rig.probe.create_publisher(CompressedImage, topics.CAMERA_COMPRESSED.name,
                                           topics.CAMERA_COMPRESSED.qos)
    boxes_pub = rig.probe.create_publisher(detections.PointCloud2, topics.DETECTIONS.name,
                                           topics.DETECTIONS.qos)
    stamp_ns = 5 * 10**9 + 6
    image = CompressedImage(format='jpeg', data=b'\xff\xd8 a jpeg')
    convert.ns_to_stamp(stamp_ns, image.header.stamp)
    cloud = detections.to_cloud([(3, 0.75, 10.0, 20.0, 50.0, 60.0)], stamp_ns,
                                topics.CAMERA_OPTICAL_FRAME)

    async def body() -> None:
        assert not rig.station._camera_subs     # nobody watches: no subscription
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(rig.ws_url[:-len('ws')] + 'camera')
            await until(lambda: len(rig.station._camera_subs) == 2)
            got: dict[str, Any] = {}

            async def receive() -> None:
                while len(got) < 2:
                    msg = await ws.receive()
                    key = 'frame' if msg.type == aiohttp.WSMsgType.BINARY else 'boxes'
                    got[key] = msg.data
            reader = asyncio.ensure_future(receive())
            await until(lambda: (image_pub.publish(image), boxes_pub.publish(cloud),
                                 reader.done())[2])
            assert got['frame'] == bytes([0, 0, 0, 5, 0, 0, 0, 6]) + b'\xff\xd8 a jpeg'
            assert json.loads(got['boxes']) == {
                'type': 'detections', 'stamp': [5, 6],
                'boxes': [[3, 0.75, 10.0, 20.0, 50.0, 60.0]]}
            await ws.close()
            await until(lambda: not rig.station._camera_subs)
    asyncio.run(body())
