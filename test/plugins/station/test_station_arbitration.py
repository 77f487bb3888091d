"""Node tier: a scripted autonomy beside a live station, arbitrated by the command receiver.

The receiver names two sources (as ``docs/profiles.md``, Command sources, shows): the station
on ``surface_command/twist`` at priority 10 and a scripted autonomy (``scripted_commands``
remapped to ``autonomy/twist``) at priority 1. The test speaks the page's protocol: the
autonomy drives while no page does; a page that drives takes over at once; when the page
closes, the station's neutral ends its lease and the autonomy drives again after the
station's timeout; the page's surface stop holds the goal at zero whatever the autonomy sends,
until released.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
import json
from typing import Any

import aiohttp
from geometry_msgs.msg import TwistStamped
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from support.station import SpinningExecutor, until
from std_msgs.msg import String

from enbarr_core.control.command_receiver_node import CommandReceiverNode
from enbarr_interfaces import convert, topics
from enbarr_plugins.operator.scripted_commands import ScriptedCommandsNode
from enbarr_plugins.station.node import SurfaceStationNode

pytestmark = pytest.mark.node

AUTONOMY = (0.1, 0.0, 0.0, 0.0, 0.0, 0.05)   # the script's goal, sent at 10 Hz


class Rig:
    def __init__(self, context: Any, executor: Any) -> None:
        self.receiver = CommandReceiverNode(context=context, parameter_overrides=[
            Parameter('sources.names', value=['station', 'autonomy']),
            Parameter('sources.topics', value=['surface_command/twist', 'autonomy/twist']),
            Parameter('sources.priorities', value=[10, 1]),
            Parameter('sources.timeouts', value=[0.5, 1.0])])
        self.station = SurfaceStationNode(context=context, parameter_overrides=[
            Parameter('port', value=0), Parameter('command', value='twist'),
            Parameter('max_linear', value=0.4), Parameter('input_timeout', value=0.4)])
        self.autonomy = ScriptedCommandsNode(
            node_name='autonomy', context=context,
            cli_args=['--ros-args', '-r', 'surface_command/twist:=autonomy/twist',
                      '-r', 'surface_command/io:=autonomy/io'],
            parameter_overrides=[Parameter('script', value=[
                '0.0 twist ' + ' '.join(str(v) for v in AUTONOMY)])])
        self.probe = Node('probe', context=context)
        self.goals: list[tuple[float, ...]] = []
        self.active: list[str] = []
        self.probe.create_subscription(
            TwistStamped, topics.TRAJECTORY_REQUEST.name,
            lambda m: self.goals.append(tuple(convert.twist_to_nu(m.twist))),
            topics.TRAJECTORY_REQUEST.qos)
        self.probe.create_subscription(String, topics.SURFACE_ACTIVE_SOURCE.name,
                                       lambda m: self.active.append(m.data),
                                       topics.SURFACE_ACTIVE_SOURCE.qos)
        for n in (self.receiver, self.station, self.autonomy, self.probe):
            executor.add_node(n)
        for n in (self.receiver, self.station, self.autonomy):
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


async def drive(ws: aiohttp.ClientWebSocketResponse, surge: float, done: asyncio.Event) -> None:
    """The page's input at 20 Hz until ``done``."""
    seq = 0
    while not done.is_set():
        seq += 1
        await ws.send_str(json.dumps({'type': 'input', 'seq': seq, 't': 50.0 * seq,
                                      'axes': {'surge': surge}, 'buttons': [],
                                      'lights': False}))
        await asyncio.sleep(0.05)


def test_the_station_takes_over_from_the_autonomy_and_gives_it_back(rig):
    async def body() -> None:
        await until(lambda: rig.active and rig.active[-1] == 'autonomy')
        await until(lambda: rig.goals and rig.goals[-1] == pytest.approx(AUTONOMY))
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(rig.ws_url)
            await ws.receive_json()
            done = asyncio.Event()
            page = asyncio.ensure_future(drive(ws, 0.5, done))
            # the operator's page drives at once: 0.5 of 0.4 m/s, nothing of the autonomy
            await until(lambda: rig.active[-1] == 'station')
            await until(lambda: rig.goals[-1] == pytest.approx((0.2, 0.0, 0.0, 0.0, 0.0, 0.0)))
            done.set()
            await page
            await ws.close()
        # the station's neutral, then silence: the autonomy drives again after the timeout
        await until(lambda: rig.active[-1] == 'autonomy')
        await until(lambda: rig.goals[-1] == pytest.approx(AUTONOMY))
        assert rig.active.count('station') == 1
    asyncio.run(body())


def test_a_stop_from_the_station_wins_over_the_autonomy_until_released(rig):
    async def body() -> None:
        await until(lambda: rig.goals and rig.goals[-1] == pytest.approx(AUTONOMY))
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(rig.ws_url)
            hello = await ws.receive_json()
            assert hello['surface_stop'] is True
            # a page that only watches may stop the vessel
            await ws.send_str(json.dumps({'type': 'surface_stop', 'stop': True}))
            await until(lambda: rig.active[-1] == 'stop')
            await until(lambda: rig.goals[-1] == (0.0,) * 6)
            n = len(rig.goals)
            await until(lambda: len(rig.goals) > n + 5)   # the autonomy keeps sending
            assert all(g == (0.0,) * 6 for g in rig.goals[n:])
            assert rig.station.surface_stopped
            await ws.send_str(json.dumps({'type': 'surface_stop', 'stop': False}))
            await until(lambda: rig.active[-1] == 'autonomy')
            await until(lambda: rig.goals[-1] == pytest.approx(AUTONOMY))
            await ws.send_str(json.dumps({'type': 'surface_stop', 'stop': 'yes'}))
            err = await ws.receive_json()
            while err['type'] != 'error':
                err = await ws.receive_json()
            assert 'surface_stop needs' in err['reason']
            await ws.close()
    asyncio.run(body())
