"""Bad inputs of a chaos run: samples stamped out of time, and a second command source.

Each must cost at most itself: control kept, and nothing the bad input carried executed
(``judge.judge_kept``).
"""

from __future__ import annotations

import time
from typing import Any

from enbarr_core.tools.chaos import judge
from enbarr_core.tools.chaos.judge import KEEPS_CONTROL, Verdict
from enbarr_core.tools.chaos.observer import COMMAND_TOPICS, Observer
from enbarr_core.tools.chaos.plan import Plan

#: Stamp offsets injected on every stamped input [s]: far future, just beyond a tolerance,
#: older than the last accepted sample.
STAMP_OFFSETS = (('future+20s', 20.0), ('future+0.4s', 0.4), ('past-0.1s', -0.1))
STAMP_BURST = 10                # bad-stamped samples per stamp fault, 10 ms apart
INTRUDER_FORCE_MIN = 0.05      # [N] a surge force in manual above this is the joystick intruder's
INTRUDER_SPEED = -0.21          # m/s: the intruder's twist, never the vehicle's own


def intruder(topic: str, template: Any, plan: Plan) -> Any:
    """Return a distinctive command for ``topic`` (never the vehicle's own)."""
    from geometry_msgs.msg import TwistStamped
    from rcl_interfaces.msg import Parameter, ParameterType
    if topic == 'surface_command/twist':
        msg = TwistStamped()
        msg.header.frame_id = 'base_link'
        msg.twist.linear.x = INTRUDER_SPEED
        return msg
    if topic == 'surface_command/io':
        msg = Parameter()
        msg.name = 'gpio_12'
        msg.value.type = ParameterType.PARAMETER_BOOL
        msg.value.bool_value = True
        return msg
    if topic == 'joy' and template is not None:
        msg = type(template)()
        msg.header.frame_id = template.header.frame_id
        msg.axes = [0.0] * len(template.axes)
        msg.buttons = [0] * len(template.buttons)
        press = plan.joy_buttons.get('button_manual')
        if press is not None and press < len(msg.buttons):
            msg.buttons[press] = 1
        surge = plan.joy_buttons.get('axis_surge')
        if surge is not None and surge < len(msg.axes):
            msg.axes[surge] = -0.6
        return msg
    return template


def executed(obs: Observer, topic: str, start: int, end: int, mode_before: str | None) -> int:
    """Count how often the intruder's command took effect in ``start .. end``."""
    if topic == 'surface_command/twist':
        return sum(1 for t, m in list(obs.goals) if start <= t <= end
                   and abs(m.twist.linear.x - INTRUDER_SPEED) < 1e-6)
    if topic == 'surface_command/io':
        return sum(1 for t, m in list(obs.io) if start <= t <= end
                   and m.name == 'gpio_12' and m.value.bool_value)
    if topic == 'joy':
        # The intruder presses manual and pushes surge. Manual with zero force is also the
        # safe outcome (a contested joystick counts as lost), so what gives the intruder
        # away is a surge force in manual.
        modes = list(obs.modes)

        def mode_at(t: int) -> str | None:
            return next((m for tm, m in reversed(modes) if tm <= t), mode_before)
        return sum(1 for t, surge in list(obs.forces) if start <= t <= end
                   and mode_at(t) == 'manual' and abs(surge) > INTRUDER_FORCE_MIN)
    return 0


def current_mode(obs: Observer) -> str | None:
    """Return the last mode the observer saw, or None."""
    return obs.modes[-1][1] if obs.modes else None


def stamp(obs: Observer, plan: Plan, window: float, name: str, topic: str,
          offset: float) -> Verdict:
    """Inject samples of ``topic`` stamped ``offset`` s from now; control must hold."""
    from enbarr_interfaces.convert import ns_to_stamp
    template = obs.sample_of(topic)
    msg = intruder(topic, template, plan)
    if msg is None:
        return judge.skipped(name, KEEPS_CONTROL, f'no sample of {topic} to copy')
    pub = obs.publisher(topic)
    mode_before = current_mode(obs)
    start = time.time_ns()
    # A burst, not one sample: a split chain over DDS drops samples its executor cannot take
    # in time, and any one of these that gets through is the fault.
    for _ in range(STAMP_BURST):
        msg.header.stamp = ns_to_stamp(time.time_ns() + int(offset * 1e9))
        pub.publish(msg)
        time.sleep(0.01)
    time.sleep(window)
    end = time.time_ns()
    obs.node.destroy_publisher(pub)
    count = executed(obs, topic, start, end, mode_before) if msg is not template else 0
    return judge.judge_kept(name, list(obs.control), list(obs.actuators), start, end,
                            executed=count, executed_what='commands with that stamp executed',
                            allow_neutral=topic in COMMAND_TOPICS)


def compete(obs: Observer, plan: Plan, window: float, name: str, topic: str) -> Verdict:
    """Publish on command ``topic`` as a second source; its commands must not act."""
    from enbarr_interfaces.convert import ns_to_stamp
    template = obs.sample_of(topic) if topic == 'joy' else None
    msg = intruder(topic, template, plan)
    if msg is None:
        return judge.skipped(name, KEEPS_CONTROL, f'no sample of {topic} to copy')
    pub = obs.publisher(topic)
    mode_before = current_mode(obs)
    start = time.time_ns()
    sent = 0
    while time.time_ns() - start < window * 1e9:
        if hasattr(msg, 'header'):
            msg.header.stamp = ns_to_stamp(time.time_ns())
        pub.publish(msg)
        sent += 1
        time.sleep(0.05)
    end = time.time_ns()
    time.sleep(0.2)  # what was sent last is still on its way
    obs.node.destroy_publisher(pub)
    count = executed(obs, topic, start, end + int(0.2e9), mode_before)
    return judge.judge_kept(name, list(obs.control), list(obs.actuators), start, end,
                            executed=count, executed_what="of the intruder's commands executed",
                            allow_neutral=True, figures={'sent': sent})
