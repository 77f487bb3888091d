"""``surface_station``: the operator's web page, served by a node in the vessel's process.

Open the URL the node logs at start (``http://127.0.0.1:8080/`` by default) in a browser on
the same machine; on another address (``host``) the URL carries the token every request needs
(``station.server``). The page drives, shows and tunes:

- Drive: keyboard, on-screen buttons or a gamepad (the browser's Gamepad API, a DualShock 4 in
  its standard mapping). The input enters the graph as the command the vessel already takes
  from its operator, so every failsafe downstream applies: ``command: joy`` (a DP vessel such
  as the CS Saucer) publishes ``joy`` in the profile's ``joy.layout`` with ``joy/connected``,
  as the DualShock 4 driver does (left stick surge and sway, right stick yaw, triangle
  automatic, square guidance, cross manual: the manual's section 3.2.5, named in the profile);
  ``command: twist`` (the ROV) publishes the velocity goal on ``surface_command/twist``, and
  the lights and the manipulator's steps on ``surface_command/io`` (executors
  ``lights_executor`` and ``manipulator_executor``, as the keyboard teleop sends them); their
  state comes back from ``io_state``. A gamepad's buttons on the ROV are the ROV pilot's pad
  (``control.rov_gamepad``, docs/rov_gamepad.png): a press sends its io request once (pilot
  modes, manipulator, camera tilt; options toggles the page's lights). When the page stops
  sending (closed, frozen, network lost) the station publishes one neutral command (sticks at
  rest and ``joy/connected`` False, or a zero twist) and then nothing (``station.protocol``).
- See: the estimate (or the simulator's truth) on a map with the guidance reference and the
  obstacles, velocities, the azimuths or thruster commands, the mode (the DP controller's, or
  the ROV's pilot mode), why a mode change was refused (``pilot_mode/reason`` on the ROV), the
  ROV's active failsafes (``failsafe/active``), and every node's ``/diagnostics`` (the
  recorder's among them). The subscriptions
  only keep the latest message; the server's thread samples them at ``telemetry_rate``.
  The camera (``camera/image_raw/compressed``) with the boxes of ``detections``: subscribed
  only while a page watches, the latest JPEG sent at ``camera_rate``.
- Record: ``start`` and ``stop`` on ``recorder/control``; the recorder's state (recording, the
  bag, its size, the free space) comes back on its ``/diagnostics``.
- Tune: every declared parameter of every node of this process, read and set through the
  standard parameter services (what ``ros2 param set`` calls), so the node's own validation
  decides and its refusal reason is shown.
"""

from __future__ import annotations

import asyncio
import collections
from collections.abc import Mapping
import concurrent.futures
from dataclasses import dataclass
import math
import re
import secrets
from typing import Any

from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter as ParameterMsg, ParameterDescriptor, ParameterType
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import Joy
from std_msgs.msg import Bool, String

from enbarr_core.control.joy_layouts import AXIS_CONTROLS, BUTTON_CONTROLS, get_layout, LAYOUTS
from enbarr_core.control.rov_gamepad import GamepadMapper, GamepadSettings
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, detections, topics
from enbarr_interfaces.obstacles import from_cloud, ObstacleEncodingError
from enbarr_plugins.station.protocol import (
    Boxes, CameraFrame, DriveInput, joy_axes_buttons, twist_of)
from enbarr_plugins.station.server import is_loopback, StationServer

COMMANDS = ('joy', 'twist')
#: Detections messages kept for the page: a detector answers an image after it was sent.
KEPT_DETECTIONS = 8
#: Bound on one parameter service answer [s]: a node that does not answer is shown as such.
SERVICE_TIMEOUT = 3.0

SPECS = [
    ParamSpec('host', '127.0.0.1', 'Address the page is served on; not loopback: a token is '
              'required', read_only=True),
    ParamSpec('port', 8080, 'TCP port of the page (0: any free port)', '', 0, 65535,
              read_only=True),
    ParamSpec('token', '', 'Token every request needs (empty: none on loopback, a random one '
              'made at start on any other address)', read_only=True),
    ParamSpec('command', 'twist', 'What the page commands: joy (a DP vessel: sensor_msgs/Joy '
              'in joy.layout) or twist (surface_command/twist)', read_only=True),
    ParamSpec('input_rate', 20.0, 'Rate at which the page sends its input', 'Hz', 2.0, 50.0,
              read_only=True),
    ParamSpec('input_timeout', 0.5, 'No input from the driving page for this long: one neutral '
              'command, then silence (the vessel failsafe takes over)', 's', 0.05, 5.0),
    ParamSpec('telemetry_rate', 15.0, 'Rate of the telemetry sent to the page', 'Hz', 1.0,
              30.0, read_only=True),
    ParamSpec('max_linear', 0.5, 'Linear velocity goal at full stick (twist)', 'm/s', 0.0,
              5.0),
    ParamSpec('max_angular', 0.5, 'Yaw rate goal at full stick (twist)', 'rad/s', 0.0, 5.0),
    ParamSpec('lights_executor', 'gpio_12', 'Executor of the lights (twist)'),
    ParamSpec('manipulator_executor', 'manipulator', 'Executor of the manipulator (twist)'),
    ParamSpec('manipulator_step', 50, 'Steps per press of a manipulator button (twist)',
              'steps', 1, 100000),
    ParamSpec('camera_rate', 5.0, 'Rate of the camera images sent to a watching page (the '
              'latest one each time)', 'Hz', 0.5, 30.0, read_only=True),
    ParamSpec('joy.layout', '', 'Joystick layout to publish in (command joy): '
              + ', '.join(LAYOUTS), read_only=True),
    *(ParamSpec(f'joy.{c}', '', f'Axis name of {c} in joy.layout', read_only=True)
      for c in AXIS_CONTROLS),
    *(ParamSpec(f'joy.{c}', '', f'Button name to {c} in joy.layout', read_only=True)
      for c in BUTTON_CONTROLS),
]


@dataclass(frozen=True)
class JoyOutput:
    """How a page input becomes a ``Joy`` of the profile's layout."""

    rest: tuple[float, ...]                     # every axis at rest
    axes: tuple[tuple[int, float], ...]         # (index, sign) of surge, sway, yaw
    buttons: tuple[str, ...]                    # name of each button index
    modes: tuple[tuple[str, str], ...]          # (mode, button name) for the page


@dataclass(frozen=True)
class StationSettings:
    """Settings of ``SurfaceStationNode`` (see ``SPECS``)."""

    host: str
    port: int
    token: str
    command: str
    input_rate: float        # [Hz]
    input_timeout: float     # [s]
    telemetry_rate: float    # [Hz]
    max_linear: float        # [m/s]
    max_angular: float       # [rad/s]
    lights_executor: str
    joy: JoyOutput | None    # command joy only
    manipulator_executor: str = 'manipulator'
    manipulator_step: int = 50   # [steps] per button press
    camera_rate: float = 5.0     # [Hz]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> StationSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        if v['command'] not in COMMANDS:
            raise ValueError(f'command: one of {", ".join(COMMANDS)}, got {v["command"]!r}')
        if v['input_timeout'] < 2.0 / v['input_rate']:
            raise ValueError(f'input_timeout: {v["input_timeout"]} s is less than two input '
                             f'periods at input_rate {v["input_rate"]} Hz: one late message '
                             'would stop the vessel')
        joy = None
        if v['command'] == 'joy':
            try:
                layout = get_layout(v['joy.layout'])
            except ValueError as err:
                raise ValueError(f'joy.layout: {err} (command joy publishes in it)') from err
            axes = []
            for c in AXIS_CONTROLS:
                try:
                    axes.append(layout.axis(v[f'joy.{c}']))
                except ValueError as err:
                    raise ValueError(f'joy.{c}: {err}') from err
            modes = []
            for c in BUTTON_CONTROLS:
                try:
                    layout.button(v[f'joy.{c}'])
                except ValueError as err:
                    raise ValueError(f'joy.{c}: {err}') from err
                modes.append((c, v[f'joy.{c}']))
            joy = JoyOutput(layout.rest, tuple(axes), layout.buttons, tuple(modes))
        return cls(v['host'], v['port'], v['token'], v['command'], v['input_rate'],
                   v['input_timeout'], v['telemetry_rate'], v['max_linear'], v['max_angular'],
                   v['lights_executor'], joy, v['manipulator_executor'],
                   v['manipulator_step'], v['camera_rate'])


#: ``ParamSpec.descriptor``'s text: the description, `` [units]`` when it has units, then
#: `` (each element in [low, high])`` for a bounded array (rclpy's ranges are scalar only).
_UNIT = re.compile(r' \[([^\]]*)\](?= \(each element in |$)')
_ELEMENT_RANGE = re.compile(r' \(each element in \[([^,\]]*), ([^\]]*)\]\)$')
_TYPE_NAMES = {ParameterType.PARAMETER_BOOL: 'bool', ParameterType.PARAMETER_INTEGER: 'int',
               ParameterType.PARAMETER_DOUBLE: 'double',
               ParameterType.PARAMETER_STRING: 'string',
               ParameterType.PARAMETER_BYTE_ARRAY: 'byte[]',
               ParameterType.PARAMETER_BOOL_ARRAY: 'bool[]',
               ParameterType.PARAMETER_INTEGER_ARRAY: 'int[]',
               ParameterType.PARAMETER_DOUBLE_ARRAY: 'double[]',
               ParameterType.PARAMETER_STRING_ARRAY: 'string[]'}


def describe(name: str, value: Any, d: ParameterDescriptor) -> dict[str, Any]:
    """One parameter as the page lists it: value, type, description, unit, range."""
    unit = _UNIT.search(d.description)
    low = high = None
    element = _ELEMENT_RANGE.search(d.description)
    if element:
        low, high = _number(element.group(1)), _number(element.group(2))
    elif d.floating_point_range:
        low, high = d.floating_point_range[0].from_value, d.floating_point_range[0].to_value
    elif d.integer_range:
        low, high = d.integer_range[0].from_value, d.integer_range[0].to_value
    return {'name': name, 'value': _json_value(value), 'type': _TYPE_NAMES.get(d.type, '?'),
            'description': d.description, 'unit': unit.group(1) if unit else '',
            'low': _finite(low), 'high': _finite(high), 'read_only': d.read_only}


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:   # 'None': that side is open
        return None


def _finite(x: float | None) -> float | None:
    return x if x is not None and math.isfinite(x) and abs(x) < 1e300 else None


def _json_value(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
        return [_json_value(x) for x in list(value)]
    if isinstance(value, bytes):
        return list(value)
    return value


def typed_value(type_: int, value: Any) -> Any:
    """``value`` (decoded JSON) as the parameter type ``type_`` takes it; ValueError if not."""
    def one(kind: int, x: Any) -> Any:
        if kind == ParameterType.PARAMETER_BOOL and isinstance(x, bool):
            return x
        if kind == ParameterType.PARAMETER_INTEGER and not isinstance(x, bool) and (
                isinstance(x, int) or (isinstance(x, float) and x.is_integer())):
            return int(x)
        if (kind == ParameterType.PARAMETER_DOUBLE and not isinstance(x, bool)
                and isinstance(x, (int, float))):
            return float(x)
        if kind == ParameterType.PARAMETER_STRING and isinstance(x, str):
            return x
        raise ValueError(f'{x!r} is not a {_TYPE_NAMES.get(kind, "?")}')
    element = {ParameterType.PARAMETER_BOOL_ARRAY: ParameterType.PARAMETER_BOOL,
               ParameterType.PARAMETER_INTEGER_ARRAY: ParameterType.PARAMETER_INTEGER,
               ParameterType.PARAMETER_DOUBLE_ARRAY: ParameterType.PARAMETER_DOUBLE,
               ParameterType.PARAMETER_STRING_ARRAY: ParameterType.PARAMETER_STRING}.get(type_)
    if element is not None:
        if not isinstance(value, list):
            raise ValueError(f'{value!r} is not a list')
        return [one(element, x) for x in value]
    return one(type_, value)


async def _answer(future: Any) -> Any:
    """Await an rclpy service future from the asyncio thread, within ``SERVICE_TIMEOUT``."""
    loop = asyncio.get_running_loop()
    done: concurrent.futures.Future[Any] = concurrent.futures.Future()

    def transfer(f: Any) -> None:
        exc = f.exception()
        if exc is not None:
            done.set_exception(exc)
        else:
            done.set_result(f.result())

    future.add_done_callback(transfer)
    return await asyncio.wait_for(asyncio.wrap_future(done, loop=loop), SERVICE_TIMEOUT)


class SurfaceStationNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'station', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: StationSettings
        self.server: StationServer | None = None   # made at start: constructing opens nothing
        self.bind_settings(SPECS, StationSettings.from_params, self._apply)
        s = self.settings
        if not is_loopback(s.host) and not s.token:
            self._token = secrets.token_urlsafe(18)
        else:
            self._token = s.token
        # Latest message of each input: the callbacks only store it, the server samples it.
        self._latest: dict[str, Any] = {}
        self._diagnostics: dict[str, dict[str, Any]] = {}
        for key, spec in (('estimate', topics.OBSERVER_ODOMETRY), ('truth', topics.SIM_ODOMETRY),
                          ('mode', topics.MODE), ('azimuths', topics.AZIMUTH_COMMANDS),
                          ('thrusters', topics.THRUSTER_COMMANDS),
                          ('reference', topics.GUIDANCE_REFERENCE),
                          ('obstacles', topics.OBSTACLES),
                          ('active_source', topics.SURFACE_ACTIVE_SOURCE),
                          ('goal', topics.TRAJECTORY_REQUEST),
                          ('pilot_mode', topics.PILOT_MODE),
                          ('pilot_reason', topics.PILOT_MODE_REASON),
                          ('failsafe', topics.FAILSAFE_ACTIVE)):
            self.create_topic_subscription(spec, self._keeper(key))
        self.create_topic_subscription(topics.DIAGNOSTICS, self._on_diagnostics)
        self._record_pub = self.create_topic_publisher(topics.RECORDER_CONTROL)
        # The camera: subscribed on the executor's thread (``_camera_subscriptions``) while
        # the server says a page watches; the callbacks only keep the latest.
        self._camera_wanted = False
        self._camera_subs: list[Any] = []
        self._image: Any = None
        self._detections: collections.deque[Any] = collections.deque(maxlen=KEPT_DETECTIONS)
        self._io_state: dict[str, Any] = {}
        if s.command == 'joy':
            self._joy_pub = self.create_topic_publisher(topics.JOY)
            self._connected_pub = self.create_topic_publisher(topics.JOY_CONNECTED)
        else:
            self._twist_pub = self.create_topic_publisher(topics.SURFACE_TWIST)
            self._io_pub = self.create_topic_publisher(topics.SURFACE_IO)
            self._stop_pub = self.create_topic_publisher(topics.SURFACE_STOP)
            self.create_topic_subscription(topics.IO_STATE, self._on_io_state)
        self._lights: bool | None = None
        # The ROV pilot's pad for the buttons a page reports (twist vessels): the page's own
        # lights toggle stays the one lights state, so the pad's lights control is unused.
        pad = GamepadSettings(
            buttons=tuple((c, '' if c == 'lights' else b) for c, b in GamepadSettings().buttons),
            manipulator_executor=s.manipulator_executor, manipulator_step=s.manipulator_step)
        self._pad = GamepadMapper(pad)
        self._pad_buttons = get_layout(pad.layout).buttons
        self.commands_sent = 0
        self.neutrals_sent = 0
        self.driving = False   # between an input taken and the neutral that ends it
        self.surface_stopped = False   # what this station last set on surface_command/stop
        self._param_clients: dict[str, AsyncParameterClient] = {}
        self.create_periodic(1.0, self._report)
        self.create_periodic(0.2, self._camera_subscriptions)

    def _on_io_state(self, msg: ParameterMsg) -> None:
        s = self.settings
        if msg.name in (s.lights_executor, s.manipulator_executor):
            self._io_state[msg.name] = convert.parameter_value_to_python(msg.value)

    def _camera_subscriptions(self) -> None:
        """Subscribe to the camera while a page watches, and only then (executor thread)."""
        if self._camera_wanted and not self._camera_subs:
            self._camera_subs = [
                self.create_topic_subscription(topics.CAMERA_COMPRESSED, self._on_image),
                self.create_topic_subscription(topics.DETECTIONS, self._on_detections)]
        elif not self._camera_wanted and self._camera_subs:
            for sub in self._camera_subs:
                self.destroy_subscription(sub)
            self._camera_subs = []
            self._image = None
            self._detections.clear()

    def _on_image(self, msg: Any) -> None:
        self._image = msg

    def _on_detections(self, msg: Any) -> None:
        self._detections.append(msg)

    def _apply(self, settings: StationSettings) -> None:
        self.settings = settings
        if self.server is not None:
            self.server.lease.timeout = settings.input_timeout

    def _keeper(self, key: str) -> Any:
        def keep(msg: Any) -> None:
            self._latest[key] = msg
        return keep

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            self._diagnostics[status.name] = {
                'level': status.level[0] if isinstance(status.level, bytes) else status.level,
                'message': status.message,
                'values': {kv.key: kv.value for kv in status.values}}

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        """Make the parameter clients of the process's nodes, serve the page, log its URL."""
        executor = self.executor
        for n in executor.get_nodes() if executor is not None else [self]:
            name = n.get_fully_qualified_name()
            if not n.get_name().startswith('_'):
                self._param_clients[name] = AsyncParameterClient(self, name)
        s = self.settings
        self.server = StationServer(self, s.host, s.port, self._token, s.telemetry_rate,
                                    s.input_timeout, s.camera_rate,
                                    log=self.get_logger().warn)
        try:
            self.server.start()
        except OSError as err:
            self.server = None
            raise ConfigurationError(f'node {self.get_name()!r}: cannot serve on '
                                     f'{s.host}:{s.port}: {err}', parameter='port') from err
        super().start()
        url = self.server.url
        if self._token:
            # The token goes to the terminal only: the log also goes to /rosout, which a
            # recorder may keep in a bag that is shared later.
            print(f'surface station: open {url}', flush=True)
            url = url.split('?')[0] + ' (with the token printed on standard output)'
        self.get_logger().info(f'surface station: open {url}')

    def stop(self) -> None:
        """Stop serving (a driving page's lease ends: neutral once), then the sources."""
        if self.server is not None:
            self.server.stop()
        super().stop()

    def safe_state(self) -> None:
        """Send the neutral command if a page was driving."""
        if self.driving:
            self.command(None)

    def destroy_node(self) -> None:
        """Stop serving, then destroy the node."""
        if self.server is not None:
            self.server.stop()
        self._param_clients.clear()   # their service clients go with the node
        super().destroy_node()

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """Return (level, message, values) for ``/diagnostics``: pages, commands, failsafes."""
        server = self.server
        values: dict[str, Any] = {'commands_sent': self.commands_sent,
                                  'neutrals_sent': self.neutrals_sent}
        if server is not None:   # never the token: /diagnostics is recorded and shared
            values.update(pages=server.pages, input_timeouts=server.lease.timeouts,
                          refused_inputs=server.lease.refused, bad_inputs=server.bad_inputs,
                          address=f'{server.host}:{server.port}')
        return 0, 'a page drives' if self.driving else 'no page drives', values

    def _report(self) -> None:
        self.publish_diagnostics(*self.diagnostic_status())

    # -- StationBackend ---------------------------------------------------------------------
    def hello(self) -> dict[str, Any]:
        """Return the static facts for the page."""
        s = self.settings
        return {'node': self.get_fully_qualified_name(), 'command': s.command,
                'input_rate': s.input_rate, 'input_timeout': s.input_timeout,
                'telemetry_rate': s.telemetry_rate,
                'modes': [list(m) for m in s.joy.modes] if s.joy else [],
                'lights_executor': s.lights_executor if s.command == 'twist' else '',
                'manipulator_executor': s.manipulator_executor if s.command == 'twist' else '',
                'camera_rate': s.camera_rate,
                'surface_stop': s.command == 'twist'}

    def command(self, inp: DriveInput | None) -> None:
        """Publish the command of ``inp`` (None: the neutral one, once, ending the drive)."""
        s = self.settings
        now = self.now_ns()
        if s.joy is not None:
            axes, buttons = joy_axes_buttons(
                inp, s.joy.rest, s.joy.axes, len(s.joy.buttons),
                {b: i for i, b in enumerate(s.joy.buttons)})
            msg = Joy(axes=axes, buttons=buttons)
            convert.ns_to_stamp(now, msg.header.stamp)
            self._joy_pub.publish(msg)
            self._connected_pub.publish(Bool(data=inp is not None))
        else:
            twist = TwistStamped()
            convert.ns_to_stamp(now, twist.header.stamp)
            twist.header.frame_id = topics.BODY_FRAME
            convert.set_twist(twist.twist, twist_of(inp, s.max_linear, s.max_angular))
            self._twist_pub.publish(twist)
            self._pad_requests(inp, now * 1e-9)
            if inp is not None and inp.lights != self._lights:
                self._lights = inp.lights
                self._io_pub.publish(ParameterMsg(
                    name=s.lights_executor,
                    value=convert.python_to_parameter_value(inp.lights)))
        if inp is None:
            self.neutrals_sent += 1
            self.driving = False
        else:
            self.commands_sent += 1
            self.driving = True

    def _pad_requests(self, inp: DriveInput | None, now: float) -> None:
        """Publish the io requests of the buttons ``inp`` newly holds (the ROV's pad)."""
        if inp is None:     # the drive ended: the next page's first input arms, fires nothing
            self._pad.on_connection(False, now)
            return
        self._pad.on_connection(True, now)
        held = set(inp.buttons)
        for request in self._pad.on_joy((), [int(b in held) for b in self._pad_buttons], now):
            self._io_pub.publish(ParameterMsg(
                name=request.executor, value=convert.python_to_parameter_value(request.value)))

    def surface_stop(self, stop: bool) -> str:
        """Set or release ``surface_command/stop``; '' when done, else why not.

        The topic is latched; the command receiver holds the goal at zero while it is set,
        whatever any command source sends.
        """
        if self.settings.command != 'twist':
            return ('no surface stop on a joystick vessel: its operator modes decide (manual '
                    'with the sticks at rest stops it)')
        self._stop_pub.publish(Bool(data=stop))
        self.surface_stopped = stop
        return ''

    def manipulator(self, direction: int) -> str:
        """Ask the manipulator for ``direction`` x ``manipulator_step`` steps; '' or why not.

        The same io request the keyboard teleop sends (``surface_command/io``, int steps), so
        the command receiver's checks and the stepper's end stops apply.
        """
        s = self.settings
        if s.command != 'twist':
            return 'no manipulator on a joystick vessel'
        self._io_pub.publish(ParameterMsg(
            name=s.manipulator_executor,
            value=convert.python_to_parameter_value(int(direction) * s.manipulator_step)))
        return ''

    def record(self, action: str) -> str:
        """Publish ``action`` on ``recorder/control``; '' when sent, else why not."""
        if self._record_pub.get_subscription_count() == 0:
            return 'no recorder runs (bringup --record, or a profile with record:)'
        self._record_pub.publish(String(data=action))
        return ''

    def camera_watch(self, watch: bool) -> None:
        """Whether a page watches the camera (the executor subscribes within 0.2 s)."""
        self._camera_wanted = watch

    def camera(self) -> tuple[CameraFrame | None, list[Boxes]]:
        """Return the latest JPEG and the kept detections (called on the server's thread)."""
        msg = self._image
        frame = None
        if msg is not None:
            frame = CameraFrame(msg.header.stamp.sec, msg.header.stamp.nanosec, bytes(msg.data))
        out = []
        for d in list(self._detections):
            try:
                rows = detections.from_cloud(d)
            except detections.DetectionEncodingError:
                continue
            out.append(Boxes(d.header.stamp.sec, d.header.stamp.nanosec, tuple(
                (int(r['class_id']), float(r['score']), float(r['x_min']), float(r['y_min']),
                 float(r['x_max']), float(r['y_max'])) for r in rows)))
        return frame, out

    def telemetry(self) -> dict[str, Any]:
        """Return the latest state, JSON-ready (see the module docstring)."""
        latest = dict(self._latest)
        out: dict[str, Any] = {'stamp': self.now_ns() * 1e-9,
                               'surface_stop': self.surface_stopped}
        for key in ('estimate', 'truth'):
            msg = latest.get(key)
            if msg is not None:
                eta = convert.pose_to_eta(msg.pose.pose)
                p = msg.pose.pose.position
                t = msg.twist.twist
                out[key] = {'x': p.x, 'y': p.y, 'z': p.z, 'yaw': float(eta[2]),
                            'u': t.linear.x, 'v': t.linear.y, 'w': t.linear.z,
                            'r': t.angular.z}
        for key in ('mode', 'active_source', 'pilot_mode', 'pilot_reason', 'failsafe'):
            if key in latest:
                out[key] = latest[key].data
        if 'azimuths' in latest:
            m = latest['azimuths']
            out['azimuths'] = [{'name': n, 'angle': a, 'thrust': f}
                               for n, a, f in zip(m.name, m.position, m.effort)]
        if 'thrusters' in latest:
            m = latest['thrusters']
            out['thrusters'] = [{'name': n, 'effort': e} for n, e in zip(m.name, m.effort)]
        if 'goal' in latest:
            out['goal'] = [float(x) for x in convert.twist_to_nu(latest['goal'].twist)]
        ref = latest.get('reference')
        if ref is not None and ref.points and ref.points[0].transforms:
            tr = ref.points[0].transforms[0].translation
            if math.isfinite(tr.x) and math.isfinite(tr.y):
                out['reference'] = {'x': tr.x, 'y': tr.y}
        if 'obstacles' in latest:
            try:
                out['obstacles'] = [[o.x, o.y, o.x2, o.y2, o.radius]
                                    for o in from_cloud(latest['obstacles'])]
            except ObstacleEncodingError:
                out['obstacles'] = []
        out['diagnostics'] = dict(self._diagnostics)
        if self.settings.command == 'twist':
            s, io = self.settings, dict(self._io_state)
            out['io'] = {'lights': io.get(s.lights_executor),
                         'manipulator': io.get(s.manipulator_executor)}
        return out

    async def list_params(self) -> list[dict[str, Any]]:
        """Every declared parameter of every node of the process, by its services."""
        names = sorted(self._param_clients)
        results = await asyncio.gather(*(self._node_params(n) for n in names),
                                       return_exceptions=True)
        return [r if isinstance(r, dict) else {'node': n, 'error': f'no answer ({r!r})',
                                               'params': []}
                for n, r in zip(names, results)]

    async def _node_params(self, node: str) -> dict[str, Any]:
        client = self._param_clients[node]
        listed = await _answer(client.list_parameters())
        names = sorted(listed.result.names)
        described = await _answer(client.describe_parameters(names))
        values = await _answer(client.get_parameters(names))
        return {'node': node, 'params': [
            describe(n, parameter_value_to_python(v), d)
            for n, v, d in zip(names, values.values, described.descriptors)]}

    async def set_param(self, node: str, name: str, value: Any) -> dict[str, Any]:
        """Set one parameter through the node's SetParameters service; the refusal's reason."""
        client = self._param_clients.get(node)
        if client is None:
            return {'ok': False, 'reason': f'no node {node!r} in this process'}
        try:
            described = await _answer(client.describe_parameters([name]))
            d = described.descriptors[0]
            if d.type == ParameterType.PARAMETER_NOT_SET:
                return {'ok': False, 'reason': f'{node} has no parameter {name!r}'}
            param = Parameter(name, Parameter.Type(d.type), typed_value(d.type, value))
            answer = await _answer(client.set_parameters([param]))
        except ValueError as err:
            return {'ok': False, 'reason': f'{name}: {err}'}
        except (asyncio.TimeoutError, TimeoutError):
            return {'ok': False, 'reason': f'{node} did not answer in {SERVICE_TIMEOUT:g} s'}
        result = answer.results[0]
        return {'ok': bool(result.successful), 'reason': result.reason}
