"""Qualisys motion capture (QTM real-time protocol): the vessel's pose on ``mocap/pose``.

Through the maintained ``qtm-rt`` package (Qualisys' Python SDK, asyncio), whose loop runs on
a thread of this driver; nothing of it touches the executor. The driver connects to QTM's RT
server (``host``:``port``, 22223 the little-endian port), negotiates ``protocol_version``,
reads the 6D parameters (the rigid bodies' names, in the order of the data packets: the
``*/Body/Name`` elements of ``GetParameters 6D``), and streams ``6D`` frames at ``rate``
(``StreamFrames Frequency:N 6D``). Protocol references: Qualisys, "QTM Real-time Server
Protocol Documentation" (docs.qualisys.com/qtm-rt-protocol: packet header = little-endian
u32 size including the 8-byte header and u32 type; data packet = i64 timestamp [us], u32
frame number, u32 component count, components of u32 size, u32 type; 6D component = i32 body
count, u16 2-D drop rate, u16 out-of-sync rate, then per body x, y, z [mm] and the 3x3
rotation matrix as 9 float32 in column-major order, NaN while the body is not tracked) and
``qtm_rt/packet.py``, ``qtm_rt/protocol.py`` of the package (its parser is what runs here).
Column-major as in the Qualisys C++ SDK's users (``Get6DOFBody`` read into a column-major
Eigen matrix).

Frames: QTM's global frame is whatever its calibration (the L-frame) made it; ``frame.up``
says which of its axes points up (``z``, QTM's default, or ``y``), and ``frame.yaw`` [rad]
and ``frame.x``/``frame.y`` [m] place it in ``odom`` (ENU)::

    p_odom = Rz(yaw) A p_qtm / 1000 + [x, y, 0],    R_odom_body = Rz(yaw) A R_qtm_body

with A = I for ``z`` up and A mapping (x, y, z)_qtm -> (x, -z, y) for ``y`` up. The rigid
body's own axes must be defined in QTM as ``base_link`` (x forward, y left, z up).

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
from dataclasses import dataclass, field
import logging
import math
import threading
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

#: QTM's RT server port for little-endian clients (the one qtm-rt speaks).
DEFAULT_PORT = 22223

_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class QtmFrame:
    """Where QTM's global frame sits in ``odom`` (see the module docstring)."""

    yaw: float = 0.0     # [rad]
    x: float = 0.0       # [m]
    y: float = 0.0       # [m]
    up: str = 'z'        # 'z' or 'y'
    rotation: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Precompute Rz(yaw) A."""
        if self.up not in ('z', 'y'):
            raise ValueError(f"frame.up: 'z' or 'y', got {self.up!r}")
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        object.__setattr__(self, 'rotation', rz @ (_Y_UP if self.up == 'y' else np.eye(3)))

    def to_odom(self, position_mm: Any, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """QTM position [mm] and body rotation -> odom position [m] and rotation."""
        p = self.rotation @ (np.asarray(position_mm, dtype=float) * 1e-3)
        return p + np.array([self.x, self.y, 0.0]), self.rotation @ rotation

    def from_odom(self, position_m: Any, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Odom position [m] and rotation -> QTM position [mm] and rotation (the emulator)."""
        p = np.asarray(position_m, dtype=float) - np.array([self.x, self.y, 0.0])
        return self.rotation.T @ p * 1e3, self.rotation.T @ rotation


def matrix_from_column_major(values: Any) -> np.ndarray:
    """Return the 3x3 rotation matrix of QTM's 9 column-major floats."""
    return np.asarray(values, dtype=float).reshape(3, 3).T


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


def body_names(xml_text: Any) -> list[str]:
    """Rigid body names of a ``GetParameters 6D`` answer, in data-packet order."""
    text = xml_text.decode(errors='replace') if isinstance(xml_text, bytes) else xml_text
    root = ET.fromstring(text.rstrip('\0'))
    return [(e.text or '').strip() for e in root.findall('*/Body/Name')]


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


def _where(host: str, port: int) -> str:
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
        raise DeviceError(f'{_where(host, port)}: no answer to the connection and Version '
                          f'{version} within {timeout} s') from err
    finally:
        log.removeHandler(catcher)
    if conn is None:
        raise DeviceError(f'{_where(host, port)}: cannot connect or protocol version '
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
        raise DeviceError(f'{where}: GetParameters 6D refused: {err}') from err
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
        self.device = f'{s.host}' if emulation.is_emulated(s.host) else _where(s.host, s.port)
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
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._error: DeviceError | None = None
        self._pub = self.create_topic_publisher(topics.MOCAP_POSE)

    def _apply(self, settings: QualisysSettings) -> None:
        self.settings = settings

    # -- device ------------------------------------------------------------------------------
    def open_device(self) -> None:
        """Find the server (the emulator looked up again) and start the session thread."""
        s = self.settings
        if emulation.is_emulated(s.host):
            host, port = emulation.lookup('tcp', s.host)
            self.device = f'{s.host} ({_where(host, port)})'
        else:
            host, port = s.host, s.port
        self._error = None
        self._stop.clear()
        self._disconnected = False
        self._last_frame = None
        self.state = 'connecting'
        self._thread = threading.Thread(target=self._run, args=(host, port),
                                        name=f'{self.get_name()}_qtm', daemon=True)
        self._thread.start()

    def close_device(self) -> None:
        """End the session (the thread disconnects) and wait for its thread."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(2.0 + self.settings.timeout)
        self.state = 'closed'

    def supervise(self) -> None:
        """Hand a failure of the session thread to ``device_fault`` (executor thread)."""
        err = self._error
        if err is not None and self.connected:
            self._error = None
            self.device_fault(err)

    def _run(self, host: str, port: int) -> None:
        try:
            asyncio.run(self._session(host, port))
        except DeviceError as err:
            if not self._stop.is_set():
                self._error = err
        except Exception as err:  # noqa: BLE001 - a bug must still reach /diagnostics
            if not self._stop.is_set():
                self._error = DeviceError(f'{_where(host, port)}: session failed: {err!r}')

    def _on_disconnect(self, exc: BaseException | None) -> None:
        self._disconnected = exc or True

    async def _session(self, host: str, port: int) -> None:
        import qtm_rt
        s = self.settings
        where = _where(host, port)
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
                raise DeviceError(f'{where}: StreamFrames refused: {err}') from err
            self.state = 'streaming'
            self.get_logger().info(f'{where}: streaming {s.body!r} (6D bodies: '
                                   f'{", ".join(self.bodies)})')
            while not self._stop.is_set():
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


def check_device(target: Any) -> list[str]:
    """``enbarr check-device qualisys --host HOST [--name BODY]``: bodies and one pose."""
    if not target.host:
        raise DeviceError("qualisys: give --host (the QTM computer's address) or emulated")
    host, port = parse_host(target.host)
    emulator = None
    if emulation.is_emulated(host):
        from enbarr_plugins.mocap.qtm_emulator import QtmEmulator
        emulator = QtmEmulator()
        host, port = emulator.start()
    port = port or DEFAULT_PORT
    where = _where(host, port)

    async def check() -> list[str]:
        conn = await open_session(host, port, '1.25', target.timeout)
        try:
            names = await read_bodies(conn, where)
            body = target.name or (names[0] if names else '')
            index = body_index(names, body, where)
            try:
                packet = await conn.get_current_frame(components=['6d'])
            except asyncio.TimeoutError as err:
                raise DeviceError(f'{where}: no answer to GetCurrentFrame 6D') from err
        finally:
            conn.disconnect()
        lines = [f'{where}: QTM RT protocol 1.25, 6D bodies: {", ".join(names)}']
        pose = pose_of(packet, index)
        if pose is None:
            return lines + [f'{where}: {body!r} not tracked in frame {packet.framenumber} '
                            '(NaN)']
        p, r = pose
        yaw = math.degrees(math.atan2(r[1, 0], r[0, 0]))
        return lines + [f'{where}: {body!r} in frame {packet.framenumber}: x {p[0]:.1f} mm, '
                        f'y {p[1]:.1f} mm, z {p[2]:.1f} mm, yaw {yaw:.1f} deg (QTM frame)']

    try:
        return asyncio.run(check())
    finally:
        if emulator is not None:
            emulator.stop()
