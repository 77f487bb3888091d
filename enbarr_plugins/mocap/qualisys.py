"""Qualisys motion capture (QTM real-time protocol): the vessel's pose on ``mocap/pose``.

Through the maintained ``qtm-rt`` package (Qualisys' Python SDK, asyncio), whose loop runs on
a thread of this driver; nothing of it touches the executor. The driver connects to QTM's RT
server (``host``:``port``, 22223 the little-endian port), negotiates ``protocol_version``,
reads the 6D parameters (the rigid bodies' names, in the order of the data packets: the
``*/Body/Name`` elements of ``GetParameters 6D``), and streams ``6D`` frames at ``rate``
(``StreamFrames Frequency:N 6D``). The protocol's layout and its sources are in
``qtm_protocol``; qtm-rt's own parser reads the packets here. The rotation matrix is
column-major as in the Qualisys C++ SDK's users (``Get6DOFBody`` read into a column-major
Eigen matrix).

Frames: ``frame.up``, ``frame.yaw``, ``frame.x`` and ``frame.y`` place QTM's global frame in
``odom`` (``qtm_frame.QtmFrame``). The rigid body's own axes must be defined in QTM as
``base_link`` (x forward, y left, z up).

Time (``docs/architecture.md``, Time): a pose is stamped with this node's clock when its
packet is read (QTM's timestamps count from its capture start on another computer's clock),
kept strictly increasing; like the simulated motion capture it publishes the full pose
(the observer takes x, y and yaw).

Faults: a body QTM does not track (NaN) is counted (``lost``) and not published, WARN on
``/diagnostics`` (the observer dead-reckons through gaps); frames that do not advance the
frame number are dropped and counted (``out_of_order``); a refused connection, a refused
version, a lost connection or no frame for ``stall_timeout`` are device faults (reconnect
with backoff); a ``body`` missing from QTM's 6D parameters is a fault that names it and
lists the known bodies. Starting the session thread proves nothing: QTM is back, and the
retry delay starts over, when its first data packet arrives.
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from dataclasses import dataclass
import logging
import math
import time
from typing import Any
import xml.etree.ElementTree as ET

from geometry_msgs.msg import PoseStamped
import numpy as np

from enbarr_core.framework.driver import SensorDriver, WARN
from enbarr_core.framework.errors import DeviceError
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics
from enbarr_plugins import emulation
from enbarr_plugins.mocap.qtm_frame import QtmFrame
from enbarr_plugins.mocap.qtm_protocol import (
    body_names, DEFAULT_PORT, matrix_from_column_major)
from enbarr_plugins.transport.reader import DeviceThread


def rotmat_to_quat(r: np.ndarray) -> np.ndarray:
    """Return the unit quaternion ``[x, y, z, w]`` (w >= 0) of a rotation matrix (Shepperd)."""
    t = np.trace(r)
    if t > 0.0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = np.array([(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s,
                      (r[1, 0] - r[0, 1]) / s, 0.25 * s])
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1e-300, 1.0 + r[i, i] - r[j, j] - r[k, k]))
        q = np.zeros(4)
        q[i] = 0.25 * s
        q[j] = (r[j, i] + r[i, j]) / s
        q[k] = (r[k, i] + r[i, k]) / s
        q[3] = (r[k, j] - r[j, k]) / s
    q /= np.linalg.norm(q)
    return -q if q[3] < 0.0 else q


def parse_host(text: str) -> tuple[str, int | None]:
    """``HOST`` or ``HOST:PORT`` (``emulated`` and ``emulated:NAME`` stay whole)."""
    if emulation.is_emulated(text):
        return text, None
    host, sep, port = text.rpartition(':')
    if sep and port.isdigit():
        return host, int(port)
    return text, None


class _LastQtmError(logging.Handler):
    """Keeps the last error qtm-rt logged.

    qtm-rt logs a refused connection or version and returns None from ``connect``; the
    fault then says which it was.
    """

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.last = ''

    def emit(self, record: logging.LogRecord) -> None:
        """Keep the message."""
        self.last = record.getMessage()


def qtm_said(err: BaseException) -> str:
    """Return QTM's words of an error packet (qtm-rt's ``QRTCommandException`` holds bytes)."""
    value = getattr(err, 'value', None)
    if isinstance(value, bytes):
        return value.rstrip(b'\0').decode(errors='replace')
    return str(value if value is not None else err)


def tcp_address(host: str, port: int) -> str:
    """``tcp://HOST:PORT``: how faults name the QTM server."""
    return f'tcp://{host}:{port}'


async def open_session(host: str, port: int, version: str, timeout: float,
                       on_disconnect: Any = None) -> Any:
    """Connect and negotiate the version; ``DeviceError`` saying why when QTM refuses."""
    import qtm_rt
    catcher = _LastQtmError()
    log = logging.getLogger('qtm_rt')
    log.addHandler(catcher)
    try:
        conn = await asyncio.wait_for(qtm_rt.connect(
            host, port, version=version, timeout=timeout, on_disconnect=on_disconnect),
            timeout)
    except asyncio.TimeoutError as err:
        raise DeviceError(f'{tcp_address(host, port)}: no answer to the connection and Version '
                          f'{version} within {timeout} s') from err
    finally:
        log.removeHandler(catcher)
    if conn is None:
        raise DeviceError(f'{tcp_address(host, port)}: cannot connect or protocol version '
                          f'{version} refused: {catcher.last or "no reason given"}')
    return conn


async def read_bodies(conn: Any, where: str) -> list[str]:
    """Return the 6D bodies QTM knows, in data order (``DeviceError``: no answer)."""
    import qtm_rt
    try:
        xml_text = await conn.get_parameters(['6d'])
    except asyncio.TimeoutError as err:
        raise DeviceError(f'{where}: no answer to GetParameters 6D') from err
    except qtm_rt.QRTCommandException as err:
        raise DeviceError(f'{where}: GetParameters 6D refused: {qtm_said(err)}') from err
    try:
        return body_names(xml_text)
    except ET.ParseError as err:
        raise DeviceError(f'{where}: GetParameters 6D: not XML ({err}): '
                          f'{bytes(xml_text)[:60]!r}') from err


def body_index(names: list[str], body: str, where: str) -> int:
    """Index of ``body`` among ``names``; a ``DeviceError`` naming it and the known ones."""
    if body not in names:
        raise DeviceError(f'{where}: rigid body {body!r} is not in the 6D parameters of QTM '
                          f'(known: {", ".join(repr(n) for n in names) or "none"})')
    return names.index(body)


def pose_of(packet: Any, index: int) -> tuple[np.ndarray, np.ndarray] | None:
    """QTM position [mm] and rotation of body ``index`` in a 6D packet (None: not tracked)."""
    got = packet.get_6d()
    if got is None:
        return None
    _, bodies = got
    if index >= len(bodies):
        return None
    position, rotation = bodies[index]
    p = np.array(position, dtype=float)
    r = matrix_from_column_major(rotation.matrix)
    if not (np.isfinite(p).all() and np.isfinite(r).all()):
        return None
    return p, r


# -- the node ------------------------------------------------------------------------------
SPECS = [
    ParamSpec('host', '', "QTM computer's address (HOST or HOST:PORT), or emulated[:NAME]",
              read_only=True),
    ParamSpec('port', DEFAULT_PORT, "QTM's RT port for little-endian clients", '', 1, 65535,
              read_only=True),
    ParamSpec('body', '', 'Name of the rigid body in QTM that is this vessel', read_only=True),
    ParamSpec('rate', 50.0, 'Frames per second asked of QTM (StreamFrames Frequency)', 'Hz',
              1.0, 1000.0, read_only=True),
    ParamSpec('protocol_version', '1.25', 'QTM RT protocol version to negotiate (>= 1.8)',
              read_only=True),
    ParamSpec('frame.yaw', 0.0, "Yaw of QTM's global frame in odom", 'rad', -math.pi, math.pi),
    ParamSpec('frame.x', 0.0, "QTM's origin in odom, x", 'm', -1000.0, 1000.0),
    ParamSpec('frame.y', 0.0, "QTM's origin in odom, y", 'm', -1000.0, 1000.0),
    ParamSpec('frame.up', 'z', "QTM's axis that points up: z or y"),
    ParamSpec('timeout', 2.0, 'Longest wait for an answer of QTM', 's', 0.05, 60.0),
    ParamSpec('stall_timeout', 0.5, 'No frame for this long is a fault (reconnect)', 's',
              0.02, 60.0),
]


@dataclass(frozen=True)
class QualisysSettings:
    """Settings of ``QualisysNode`` (see ``SPECS``)."""

    host: str
    port: int
    body: str
    rate: float
    protocol_version: str
    frame: QtmFrame
    timeout: float
    stall_timeout: float

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> QualisysSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        if not v['host'].strip():
            raise ValueError("host: empty; the QTM computer's address, or emulated")
        if not v['body'].strip():
            raise ValueError('body: empty; the name of the rigid body in QTM')
        major, _, minor = v['protocol_version'].partition('.')
        if not (major.isdigit() and minor.isdigit() and (int(major), int(minor)) >= (1, 8)):
            raise ValueError(f"protocol_version: 'MAJOR.MINOR', at least 1.8, got "
                             f"{v['protocol_version']!r}")
        host, port = parse_host(v['host'].strip())
        return cls(host, port or int(v['port']), v['body'].strip(), v['rate'],
                   v['protocol_version'],
                   QtmFrame(v['frame.yaw'], v['frame.x'], v['frame.y'], v['frame.up']),
                   v['timeout'], v['stall_timeout'])


class QualisysNode(SensorDriver):
    """See the module docstring."""

    #: Opening only starts the session thread: QTM is back when its first data packet comes.
    confirmed_by_open = False

    def __init__(self, node_name: str = 'mocap', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: QualisysSettings
        self.bind_settings(SPECS, QualisysSettings.from_params, self._apply)
        s = self.settings
        self.device = f'{s.host}' if emulation.is_emulated(s.host) else tcp_address(s.host, s.port)
        self.bodies: list[str] = []
        self.state = 'closed'
        self.lost = 0
        self.out_of_order = 0
        self._lost_reported = 0
        self._index = 0
        self._last_frame: int | None = None
        self._last_stamp = 0
        self._last_packet = 0.0
        self._disconnected: BaseException | bool = False
        self._session_thread = DeviceThread(f'{self.get_name()}_qtm')
        self._pub = self.create_topic_publisher(topics.MOCAP_POSE)

    def _apply(self, settings: QualisysSettings) -> None:
        self.settings = settings

    # -- device ------------------------------------------------------------------------------
    def open_device(self) -> None:
        """Find the server (the emulator looked up again) and start the session thread."""
        s = self.settings
        if emulation.is_emulated(s.host):
            host, port = emulation.lookup('tcp', s.host)
            self.device = f'{s.host} ({tcp_address(host, port)})'
        else:
            host, port = s.host, s.port
        self._disconnected = False
        self._last_frame = None
        self.state = 'connecting'
        self._session_thread.start(tcp_address(host, port), self._run, host, port)

    def close_device(self) -> None:
        """End the session (the thread disconnects) and wait for its thread."""
        self._session_thread.stop(2.0 + self.settings.timeout)
        self.state = 'closed'

    def supervise(self) -> None:
        """Hand a failure of the session thread to ``device_fault`` (executor thread)."""
        if self.connected:
            err = self._session_thread.failure()
            if err is not None:
                self.device_fault(err)

    def _run(self, host: str, port: int) -> None:
        """Run one session on qtm-rt's asyncio loop (the session thread)."""
        asyncio.run(self._session(host, port))

    def _on_disconnect(self, exc: BaseException | None) -> None:
        self._disconnected = exc or True

    async def _session(self, host: str, port: int) -> None:
        import qtm_rt
        s = self.settings
        where = tcp_address(host, port)
        conn = await open_session(host, port, s.protocol_version, s.timeout,
                                  self._on_disconnect)
        try:
            self.bodies = await read_bodies(conn, where)
            self._index = body_index(self.bodies, s.body, where)
            self._last_packet = time.monotonic()
            try:
                await conn.stream_frames(frames=f'frequency:{s.rate:g}', components=['6d'],
                                         on_packet=self._on_packet)
            except asyncio.TimeoutError as err:
                raise DeviceError(f'{where}: no frame within {s.timeout} s of StreamFrames '
                                  '(is QTM measuring?)') from err
            except qtm_rt.QRTCommandException as err:
                raise DeviceError(f'{where}: StreamFrames refused: {qtm_said(err)}') from err
            self.state = 'streaming'
            self.get_logger().info(f'{where}: streaming {s.body!r} (6D bodies: '
                                   f'{", ".join(self.bodies)})')
            while not self._session_thread.stopping:
                await asyncio.sleep(0.05)
                if self._disconnected:
                    reason = self._disconnected
                    raise DeviceError(f'{where}: connection lost'
                                      + (f': {reason}' if reason is not True else ''))
                quiet = time.monotonic() - self._last_packet
                if quiet > s.stall_timeout:
                    raise DeviceError(f'{where}: no frame for {quiet:.2g} s (stalled; is QTM '
                                      'measuring?)')
        finally:
            try:
                conn.disconnect()
            except Exception:  # noqa: BLE001 - already gone
                pass

    def _on_packet(self, packet: Any) -> None:
        """One data packet (on the session thread): publish the body's pose."""
        stamp = self.now_ns()
        self._last_packet = time.monotonic()
        self.device_confirmed()  # QTM streams (tracking the body or not): it is back
        number = packet.framenumber
        if self._last_frame is not None and number <= self._last_frame:
            self.out_of_order += 1
            return
        self._last_frame = number
        pose = pose_of(packet, self._index)
        if pose is None:
            self.lost += 1
            return
        if not self.started:  # the chain's source: silent before start and after stop
            return
        p, r = self.settings.frame.to_odom(*pose)
        stamp = max(stamp, self._last_stamp + 1)
        self._last_stamp = stamp
        msg = PoseStamped()
        convert.ns_to_stamp(stamp, msg.header.stamp)
        msg.header.frame_id = topics.MOCAP_POSE.frame
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (
            float(p[0]), float(p[1]), float(p[2]))
        convert.set_quaternion(msg.pose.orientation, rotmat_to_quat(r))
        self._pub.publish(msg)
        self.sample_received()

    # -- diagnostics -------------------------------------------------------------------------
    def status(self) -> tuple[int, str]:
        """ERROR while faulted, WARN while the body is lost or samples are late, else OK."""
        level, message = super().status()
        new, self._lost_reported = self.lost - self._lost_reported, self.lost
        if level < WARN and new > 0:
            return WARN, (f'body {self.settings.body!r} not tracked in {new} frames '
                          'of the last report period (NaN from QTM)')
        return level, message

    def status_values(self) -> dict[str, Any]:
        """Body, the bodies QTM knows and the frame counters."""
        return {**super().status_values(), 'state': self.state, 'body': self.settings.body,
                'bodies': ', '.join(self.bodies), 'lost': self.lost,
                'out_of_order': self.out_of_order}
