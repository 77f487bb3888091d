"""The ROV pilot's gamepad node: ``joy`` to ``surface_command/twist`` and ``surface_command/io``.

Thin: ``enbarr_core.control.rov_gamepad`` holds the mapping (sticks, dead band, button
edges, when the pad is lost). The velocity goal is sent at ``rate``, stamped on the node
clock, only while the pad commands; a lost pad (disconnected, or its ``Joy`` stale) sends
nothing at all, so that the vehicle's command receiver times out and its failsafe holds zero.
Button presses go out at once as io requests. The picture of the pad is
``docs/rov_gamepad.png`` (``scripts/draw_rov_gamepad.py``).
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import Parameter
from sensor_msgs.msg import Joy
from std_msgs.msg import Bool

from enbarr_core.control.joy_layouts import LAYOUTS
from enbarr_core.control.rov_gamepad import (
    BUTTON_CONTROLS, GamepadMapper, GamepadSettings, settings_from_params, STICK_DOFS)
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics

_D = GamepadSettings()
_STICKS, _FULL, _BUTTONS = dict(_D.sticks), dict(_D.full_stick), dict(_D.buttons)

SPECS = [
    ParamSpec('layout', _D.layout, 'Joy layout of the pad driver: ' + ', '.join(LAYOUTS),
              read_only=True),
    ParamSpec('rate', 20.0, 'Rate at which the velocity goal is sent', 'Hz', 1.0, 100.0,
              read_only=True),
    *(ParamSpec(f'sticks.{c}', _STICKS[c], f'Axis of the layout for {c} (-name: the other '
                'way; +1 is stick up/left in every layout; empty: unused)') for c in STICK_DOFS),
    *(ParamSpec(f'full_stick.{c}', _FULL[c], f'{c} velocity goal at full stick',
                'rad/s' if c == 'yaw' else 'm/s', 0.0, 5.0) for c in STICK_DOFS),
    ParamSpec('deadzone', _D.deadzone, 'Dead band of each stick', 'fraction', 0.0, 0.9),
    *(ParamSpec(f'buttons.{c}', _BUTTONS[c], f'Button of the layout for {c} (empty: unused)')
      for c in BUTTON_CONTROLS),
    ParamSpec('lights_executor', _D.lights_executor, 'Executor of the lights'),
    ParamSpec('manipulator_executor', _D.manipulator_executor, 'Executor of the manipulator'),
    ParamSpec('manipulator_step', _D.manipulator_step, 'Manipulator steps per press', 'steps',
              1, 100000),
    ParamSpec('tilt_executor', _D.tilt_executor, 'Executor of the camera tilt servo'),
    ParamSpec('tilt_step', _D.tilt_step, 'Camera tilt change per press', 'deg', 0.1, 90.0),
    ParamSpec('tilt_min', _D.tilt_min, 'Lowest camera tilt goal (down)', 'deg', -90.0, 0.0),
    ParamSpec('tilt_max', _D.tilt_max, 'Highest camera tilt goal (up)', 'deg', 0.0, 90.0),
    ParamSpec('joy_timeout', _D.joy_timeout, 'A Joy (or, for a driver that publishes on '
              'change, a joy/connected heartbeat) older than this: the pad is lost', 's',
              0.01, 10.0),
]


def _build(v: dict[str, Any]) -> GamepadSettings:
    settings = settings_from_params(v)
    settings.validate()
    return settings


class RovGamepadNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'gamepad', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: GamepadSettings
        self.bind_settings(SPECS, _build, self._apply)
        self._twist_pub = self.create_topic_publisher(topics.SURFACE_TWIST)
        self._io_pub = self.create_topic_publisher(topics.SURFACE_IO)
        self.create_topic_subscription(topics.JOY, self._on_joy)
        self.create_topic_subscription(topics.JOY_CONNECTED, self._on_connected)
        rate = self.get_parameter('rate').value
        self.create_source_timer(1.0 / rate, self._send)
        self._lost_reason: str | None = ''   # '' : nothing said yet

    def _apply(self, settings: GamepadSettings) -> None:
        # A new mapping starts from a lost pad: the next sample arms the buttons.
        self.settings = settings
        self.mapper = GamepadMapper(settings)

    def _now(self) -> float:
        return self.now_ns() * 1e-9

    def _on_connected(self, msg: Bool) -> None:
        self.mapper.on_connection(bool(msg.data), self._now())

    def _on_joy(self, msg: Joy) -> None:
        for request in self.mapper.on_joy(msg.axes, msg.buttons, self._now()):
            self._io_pub.publish(Parameter(
                name=request.executor,
                value=convert.python_to_parameter_value(request.value)))

    def _send(self) -> None:
        now = self._now()
        nu = self.mapper.twist(now)
        reason = self.mapper.lost(now)
        if reason != self._lost_reason:
            if reason is None:
                self.get_logger().info('gamepad commands the vehicle')
            else:
                self.get_logger().warn(f'gamepad lost ({reason}): sending nothing')
            self._lost_reason = reason
        if nu is None:
            return
        msg = TwistStamped()
        convert.ns_to_stamp(self.now_ns(), msg.header.stamp)
        msg.header.frame_id = topics.BODY_FRAME
        convert.set_twist(msg.twist, nu)
        self._twist_pub.publish(msg)
