"""A fake QTM real-time server on loopback: the real framing, the vessel's pose as 6D data.

``QtmEmulator`` runs an asyncio TCP server on its own thread (127.0.0.1, an ephemeral port)
and speaks the QTM RT protocol as documented by Qualisys ("QTM Real-time Server Protocol
Documentation") and as the ``qtm-rt`` client expects it (``qtm_rt/protocol.py``,
``qtm_rt/receiver.py``, ``qtm_rt/packet.py``), framed by ``qtm_protocol``: every packet is
a little-endian header (u32 size including the header, u32 type) and its body, strings
NUL-terminated. On a connection it sends the command
"QTM RT Interface connected"; it answers

- ``Version 1.xx`` with "Version set to 1.xx" (1.8 to 1.25; an error packet otherwise, and
  for every version under the ``wrong_version`` fault), ``Version`` with "Version is 1.xx";
- ``QTMVersion``, ``ByteOrder`` ("Byte order is little endian"), ``GetState`` (an event
  packet: connected);
- ``GetParameters 6D`` with the XML of the rigid bodies (``<QTM_Parameters_Ver_1.xx><The_6D>
  <Body><Name>...``, the 1.21+ layout);
- ``GetCurrentFrame 6D`` with one data packet, ``StreamFrames AllFrames|Frequency:N|
  FrequencyDivisor:N 6D|6DEuler`` with data packets at that rate until ``StreamFrames Stop``;
- anything else with an error packet "Parse error".

A data packet: i64 timestamp [us since start], u32 frame number (at ``capture_rate``), u32
component count (1), the component (u32 size, u32 type 5 = 6D or 6 = 6D Euler) with i32 body
count, u16 2-D drop rate, u16 out-of-sync rate, then per body x, y, z [mm] and the rotation
matrix as 9 column-major float32 (6D Euler: roll, pitch, yaw [deg] instead).

The tracked body (``tracked``, the first of ``bodies`` by default) carries the vessel pose
``set_pose`` gives (``odom``, usually from ``sim/odometry``), turned into QTM's frame with
the same ``QtmFrame`` the driver uses; the other bodies are at rest.

Faults: ``refuse(True)`` (the server stops listening: connections are refused), ``drop()``
(every connection is closed), ``stall(True)`` (no data packet, the connection open),
``nan(True)`` (the tracked body not tracked: NaN), ``wrong_version`` (every Version refused),
``bodies`` without the driver's body (an unknown body), ``send_old_frame()`` (the next packet
repeats an older frame number), ``refusals`` (a command answered with an error packet).

``QtmEmulatorNode`` wraps it for profiles (``emulator_node.DeviceEmulatorNode``): when
started it listens and registers its (host, port) as the ``tcp`` emulator ``name`` (``host:
emulated`` in the driver); it follows ``sim/odometry`` and reports what it received and sent
on ``/diagnostics``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping
from dataclasses import dataclass
import math
import threading
import time
from typing import Any

import numpy as np

from enbarr_core.framework.params import ParamSpec
from enbarr_plugins.emulator_node import commands_line, describe, DeviceEmulatorNode
from enbarr_plugins.mocap.qtm_frame import QtmFrame
from enbarr_plugins.mocap.qtm_protocol import (
    COMPONENT_6D, COMPONENT_6D_EULER, COMPONENT_HEADER, DATA_HEADER, EVENT_CONNECTED, HEADER,
    packet, PACKET_COMMAND, PACKET_DATA, PACKET_ERROR, PACKET_EVENT, PACKET_XML, SIX_D_BODY,
    SIX_D_EULER_BODY, SIX_D_HEADER, text_packet, WELCOME)

VERSIONS = ((1, 8), (1, 25))  # oldest, newest served


def euler_deg(r: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw [deg] of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -r[2, 0])))
    return (math.degrees(math.atan2(r[2, 1], r[2, 2])), math.degrees(pitch),
            math.degrees(math.atan2(r[1, 0], r[0, 0])))


class QtmEmulator:
    """See the module docstring."""

    def __init__(self, *, bodies: tuple[str, ...] = ('saucer',), tracked: str | None = None,
                 capture_rate: float = 100.0, frame: QtmFrame = QtmFrame(),
                 height: float = 0.0, on_address: Any = None, on_gone: Any = None) -> None:
        self.bodies = tuple(bodies)
        self.tracked = tracked or (bodies[0] if bodies else '')
        self.capture_rate = capture_rate
        self.frame = frame
        self.height = height  # [m] of the body above odom's origin
        self.on_address = on_address
        self.on_gone = on_gone
        self.pose = (0.0, 0.0, 0.0)
        self.address: tuple[str, int] | None = None
        # counters
        self.connections = 0
        self.commands: dict[str, int] = {}
        self.frames_sent = 0
        self.errors_sent = 0
        self.bytes_in = 0
        self.bytes_out = 0
        # faults
        self.wrong_version = False
        #: command name (lower case) -> the error text QTM answers it with instead
        self.refusals: dict[str, str] = {}
        self._stalled = False
        self._nan = False
        self._old_frame = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.AbstractServer | None = None
        self._thread: threading.Thread | None = None
        self._writers: set[asyncio.StreamWriter] = set()
        self._clients: set[asyncio.Task[Any]] = set()
        self._t0 = time.monotonic()
        self._ready = threading.Event()

    # -- lifecycle -----------------------------------------------------------------------------
    def start(self, port: int = 0) -> tuple[str, int]:
        """Serve on 127.0.0.1:``port`` (0: any free port); return the address."""
        if self._thread is None:
            self._ready.clear()
            self._thread = threading.Thread(target=self._run_loop, name='qtm_emulator',
                                            daemon=True)
            self._thread.start()
            self._ready.wait(5.0)
        self._call(self._listen(port or (self.address[1] if self.address else 0)))
        return self.address

    def stop(self) -> None:
        """Close every connection and the server; end the thread."""
        loop, thread = self._loop, self._thread
        if loop is None or thread is None:
            return
        self._call(self._shutdown())
        loop.call_soon_threadsafe(loop.stop)
        thread.join(2.0)
        self._thread = self._loop = None
        if self.address is not None and self.on_gone is not None:
            self.on_gone(self.address)  # QTM is gone; the port is kept for a restart

    def _run_loop(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        self._ready.set()
        loop.run_forever()
        loop.close()

    def _call(self, coro: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(5.0)

    async def _listen(self, port: int) -> None:
        if self._server is not None:
            return
        self._server = await asyncio.start_server(self._client, '127.0.0.1', port,
                                                  reuse_address=True)
        self.address = self._server.sockets[0].getsockname()[:2]
        if self.on_address is not None:
            self.on_address(self.address)

    async def _unlisten(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
            await server.wait_closed()

    async def _drop_all(self) -> None:
        for writer in list(self._writers):
            writer.close()

    async def _shutdown(self) -> None:
        await self._drop_all()
        await self._unlisten()
        if self._clients:  # closed above: each handler ends on its own, its stream with it
            await asyncio.wait(list(self._clients), timeout=1.0)
        streams = [t for t in asyncio.all_tasks()
                   if t is not asyncio.current_task() and t not in self._clients]
        for task in streams:
            task.cancel()
        await asyncio.gather(*streams, return_exceptions=True)

    # -- faults --------------------------------------------------------------------------------
    def refuse(self, on: bool) -> None:
        """Stop listening (connections refused) or listen again on the same port."""
        if on:
            self._call(self._unlisten())
        else:
            self._call(self._listen(self.address[1]))

    def drop(self) -> None:
        """Close every connection (QTM closed, the network cable pulled)."""
        self._call(self._drop_all())

    def stall(self, on: bool) -> None:
        """Stop (or resume) sending data packets; connections stay open."""
        self._stalled = on

    def nan(self, on: bool) -> None:
        """Lose (or find again) the tracked body: NaN in its 6D data."""
        self._nan = on

    def send_old_frame(self) -> None:
        """Send the next data packet with an older frame number (out of order)."""
        self._old_frame = True

    def set_pose(self, x: float, y: float, psi: float) -> None:
        """Set the vessel pose in odom [m, m, rad] (from the simulator)."""
        self.pose = (x, y, psi)

    @property
    def open_connections(self) -> int:
        """Connections open now."""
        return len(self._writers)

    # -- the protocol --------------------------------------------------------------------------
    def _count(self, name: str) -> None:
        self.commands[name] = self.commands.get(name, 0) + 1

    async def _client(self, reader: asyncio.StreamReader,
                      writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        self._writers.add(writer)
        task = asyncio.current_task()
        self._clients.add(task)
        state: dict[str, Any] = {'version': VERSIONS[1], 'stream': None}
        self._write(writer, text_packet(PACKET_COMMAND, WELCOME))
        try:
            while True:
                size, ptype = HEADER.unpack(await reader.readexactly(HEADER.size))
                if size < HEADER.size or size > 1 << 20:
                    break  # not QTM RT framing: hang up as QTM would
                body = await reader.readexactly(size - HEADER.size)
                self.bytes_in += size
                if ptype == PACKET_COMMAND:
                    self._command(body.rstrip(b'\0').decode(errors='replace'), writer, state)
                else:
                    self._error(writer, 'Parse error')
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError, OSError):
            pass
        finally:
            if state['stream'] is not None:
                state['stream'].cancel()
            self._writers.discard(writer)
            self._clients.discard(task)
            writer.close()

    def _write(self, writer: asyncio.StreamWriter, data: bytes) -> None:
        self.bytes_out += len(data)
        writer.write(data)

    def _error(self, writer: asyncio.StreamWriter, text: str) -> None:
        self.errors_sent += 1
        self._write(writer, text_packet(PACKET_ERROR, text))

    def _command(self, text: str, writer: asyncio.StreamWriter, state: dict[str, Any]) -> None:
        words = text.split()
        name = words[0].lower() if words else ''
        self._count(name or '(empty)')
        args = [w.lower() for w in words[1:]]
        if name in self.refusals:
            self._error(writer, self.refusals[name])
        elif name == 'version':
            if not args:
                major, minor = state['version']
                self._write(writer, text_packet(PACKET_COMMAND, f'Version is {major}.{minor}'))
                return
            major, _, minor = args[0].partition('.')
            ok = major.isdigit() and minor.isdigit() and (
                VERSIONS[0] <= (int(major), int(minor)) <= VERSIONS[1])
            if not ok or self.wrong_version:
                self._error(writer, 'Version NOT supported')
                return
            state['version'] = (int(major), int(minor))
            self._write(writer, text_packet(PACKET_COMMAND, f'Version set to {words[1]}'))
        elif name == 'qtmversion':
            self._write(writer, text_packet(PACKET_COMMAND, 'QTM Version is 2024.1 (emulated)'))
        elif name == 'byteorder':
            self._write(writer, text_packet(PACKET_COMMAND, 'Byte order is little endian'))
        elif name == 'getstate':
            self._write(writer, packet(PACKET_EVENT, bytes((EVENT_CONNECTED,))))
        elif name == 'getparameters' and args and set(args) <= {'6d', 'all'}:
            self._write(writer, text_packet(PACKET_XML, self.parameters_xml(state['version'])))
        elif name == 'getcurrentframe' and args and set(args) <= {'6d', '6deuler'}:
            self._write(writer, self.data_packet(COMPONENT_6D_EULER if '6deuler' in args
                                          else COMPONENT_6D))
        elif name == 'streamframes' and args == ['stop']:
            if state['stream'] is not None:
                state['stream'].cancel()
                state['stream'] = None
        elif name == 'streamframes' and len(args) == 2 and args[1] in ('6d', '6deuler'):
            rate = self._stream_rate(args[0])
            if rate is None:
                self._error(writer, f'Parse error: {words[1]}')
                return
            if state['stream'] is not None:
                state['stream'].cancel()
            component = COMPONENT_6D_EULER if args[1] == '6deuler' else COMPONENT_6D
            state['stream'] = asyncio.ensure_future(self._stream(writer, rate, component))
        else:
            self._error(writer, 'Parse error')

    def _stream_rate(self, frames: str) -> float | None:
        kind, _, value = frames.partition(':')
        try:
            if kind == 'allframes':
                return self.capture_rate
            if kind == 'frequency' and float(value) > 0:
                return min(float(value), self.capture_rate)
            if kind == 'frequencydivisor' and int(value) >= 1:
                return self.capture_rate / int(value)
        except ValueError:
            return None
        return None

    async def _stream(self, writer: asyncio.StreamWriter, rate: float, component: int) -> None:
        period = 1.0 / rate
        deadline = time.monotonic()
        while not writer.is_closing():
            if not self._stalled:
                self._write(writer, self.data_packet(component))
                self.frames_sent += 1
            deadline += period
            await asyncio.sleep(max(0.0, deadline - time.monotonic()))

    def parameters_xml(self, version: tuple[int, int] = VERSIONS[1]) -> str:
        """Return the ``GetParameters 6D`` answer (the protocol 1.21+ layout)."""
        tag = f'QTM_Parameters_Ver_{version[0]}.{version[1]}'
        bodies = ''.join(
            f'<Body><Name>{name}</Name><Enabled>true</Enabled><Color R="255" G="0" B="0"/>'
            '<MaximumResidual>10</MaximumResidual><MinimumMarkersInBody>3'
            '</MinimumMarkersInBody><BoneLengthTolerance>5</BoneLengthTolerance>'
            '<Filter Preset="No filter"/><Points>'
            '<Point X="100" Y="0" Z="0" Virtual="0" PhysicalId="0" Name="front"/>'
            '<Point X="-50" Y="80" Z="0" Virtual="0" PhysicalId="0" Name="left"/>'
            '<Point X="-50" Y="-80" Z="0" Virtual="0" PhysicalId="0" Name="right"/>'
            '</Points><Data_origin>0</Data_origin><Data_orientation>0</Data_orientation>'
            '</Body>' for name in self.bodies)
        return (f'<{tag}><The_6D>{bodies}<Euler><First>Z</First><Second>Y</Second>'
                f'<Third>X</Third></Euler></The_6D></{tag}>')

    def frame_number(self) -> int:
        """Return the capture frame number now."""
        return int((time.monotonic() - self._t0) * self.capture_rate)

    def data_packet(self, component: int = COMPONENT_6D) -> bytes:
        """One data packet with every body (the tracked one at the vessel's pose)."""
        x, y, psi = self.pose
        c, s = math.cos(psi), math.sin(psi)
        r_odom = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        pos_mm, r_qtm = self.frame.from_odom([x, y, self.height], r_odom)
        bodies = b''
        for name in self.bodies:
            if name != self.tracked:
                p, r = np.zeros(3), np.eye(3)
            elif self._nan:
                p, r = np.full(3, np.nan), np.full((3, 3), np.nan)
            else:
                p, r = pos_mm, r_qtm
            if component == COMPONENT_6D:
                bodies += SIX_D_BODY.pack(*p, *r.T.reshape(9))  # column-major
            else:
                angles = (math.nan,) * 3 if not np.isfinite(r).all() else euler_deg(r)
                bodies += SIX_D_EULER_BODY.pack(*p, *angles)
        comp = SIX_D_HEADER.pack(len(self.bodies), 0, 0) + bodies
        number = self.frame_number()
        if self._old_frame:
            self._old_frame = False
            number = max(0, number - 10)
        body = (DATA_HEADER.pack(int((time.monotonic() - self._t0) * 1e6), number, 1)
                + COMPONENT_HEADER.pack(COMPONENT_HEADER.size + len(comp), component) + comp)
        return packet(PACKET_DATA, body)


# -- the node ------------------------------------------------------------------------------
SPECS = [
    ParamSpec('name', 'default', "Emulator name: the driver's host emulated:NAME",
              read_only=True),
    ParamSpec('bodies', ['saucer'], 'Rigid bodies in the 6D parameters; the first is the '
              'vessel', read_only=True),
    ParamSpec('capture_rate', 100.0, 'Camera frame rate of the emulated system', 'Hz', 1.0,
              1000.0, read_only=True),
    ParamSpec('frame.yaw', 0.0, "QTM's frame in odom, as the driver's", 'rad', -math.pi,
              math.pi),
    ParamSpec('frame.x', 0.0, "QTM's frame in odom, as the driver's", 'm', -1000.0, 1000.0),
    ParamSpec('frame.y', 0.0, "QTM's frame in odom, as the driver's", 'm', -1000.0, 1000.0),
    ParamSpec('frame.up', 'z', "QTM's up axis, as the driver's: z or y"),
]


@dataclass(frozen=True)
class QtmEmulatorSettings:
    """Settings of ``QtmEmulatorNode`` (see ``SPECS``)."""

    name: str
    bodies: tuple[str, ...]
    capture_rate: float
    frame: QtmFrame

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> QtmEmulatorSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        bodies = tuple(b.strip() for b in v['bodies'])
        if not bodies or not all(bodies):
            raise ValueError('bodies: at least one non-empty rigid body name')
        return cls(v['name'], bodies, v['capture_rate'],
                   QtmFrame(v['frame.yaw'], v['frame.x'], v['frame.y'], v['frame.up']))


class QtmEmulatorNode(DeviceEmulatorNode):
    """See the module docstring."""

    kind = 'tcp'
    device = 'QTM RT'

    def __init__(self, node_name: str = 'qtm_emulator', **kwargs: Any) -> None:
        super().__init__(node_name, SPECS, QtmEmulatorSettings.from_params, **kwargs)

    def make_emulator(self, s: QtmEmulatorSettings, plugged: Callable[[Any], None],
                      unplugged: Callable[[Any], None]) -> QtmEmulator:
        """Build the server on loopback, listening (its address offered) on ``start``."""
        return QtmEmulator(bodies=s.bodies, capture_rate=s.capture_rate, frame=s.frame,
                           on_address=plugged, on_gone=unplugged)

    def apply(self, s: QtmEmulatorSettings) -> None:
        """QTM's frame changes live."""
        self.emulator.frame = s.frame

    def report(self) -> tuple[str, dict[str, Any]]:
        """Report the address and what went through it."""
        e = self.emulator
        return (f'serving {describe(e.address)}' if e.address else 'not started', {
            'connections': e.connections, 'open': e.open_connections,
            'commands': commands_line(e.commands), 'frames_sent': e.frames_sent,
            'errors_sent': e.errors_sent, 'bytes_in': e.bytes_in, 'bytes_out': e.bytes_out})
