"""Node tests: sim thrusters."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import rclpy.parameter
import pytest
from sensor_msgs.msg import JointState
from support.devices import pass_time
from support.nodes import TIMEOUT, add, probe
from support.rov import layout_overrides, sim_parameters
from support.saucer import SimClock

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.stamps import StampVerdict
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.thrusters.sim import SimThrustersNode

NAMES = sim_parameters()['thruster_names']
CMD = [0.5, -0.5, 1.0, -1.0, 0.0, 0.25, -0.25, 0.1]


class Controller:
    """The thrusters (no motor lag, 0.1 s watchdog) and a controller commanding them."""

    def __init__(self, context: Any, executor: Any, start: bool = True) -> None:
        self.node = add(executor, SimThrustersNode(
            node_name='thruster_control', context=context,
            parameter_overrides=layout_overrides(time_constant=0.0, command_timeout=0.1)))
        self.probe = p = probe(context, executor, 'controller')
        self.pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
        self.outputs: list[JointState] = []
        self.thrusts: list[JointState] = []
        p.create_topic_subscription(topics.THRUSTER_OUTPUT, self.outputs.append)
        p.create_topic_subscription(topics.SIM_THRUST, self.thrusts.append)
        LinkBus.of(context).connect()
        if start:
            self.node.start()

    def command(self, efforts: list[float], names: list[str] = NAMES) -> None:
        msg = JointState(name=list(names), effort=[float(e) for e in efforts])
        msg.header.stamp = self.probe.get_clock().now().to_msg()
        self.pub.publish(msg)


@pytest.fixture
def rig(context, executor) -> Controller:
    return Controller(context, executor)


def test_starts_neutral_with_the_profile_names(rig):
    assert rig.node.names == NAMES and rig.node.neutral
    assert rig.outputs[-1].effort.tolist() == [0.0] * len(NAMES)   # neutral went out at start


def test_a_constructed_node_publishes_nothing_until_started(context, executor, spin):
    rig = Controller(context, executor, start=False)
    pass_time(executor, spin, rig.probe)
    assert rig.outputs == [] and rig.thrusts == [] and rig.node.timeouts == 0
    rig.node.start()
    assert len(rig.outputs) == len(rig.thrusts) == 1
    assert not np.any(rig.outputs[0].effort) and not np.any(rig.thrusts[0].effort)


def test_command_becomes_output_and_thrust(rig):
    n = len(rig.outputs)            # the neutral of start()
    rig.command(CMD)
    assert len(rig.outputs) == len(rig.thrusts) == n + 1
    assert rig.outputs[-1].name == NAMES and rig.thrusts[-1].name == NAMES
    assert rig.outputs[-1].effort.tolist() == pytest.approx(CMD)
    expected = [c * (51.5 if c >= 0 else 40.2) for c in CMD]
    assert rig.thrusts[-1].effort.tolist() == pytest.approx(expected)
    assert not rig.node.neutral


def test_commands_go_by_name_and_missing_thrusters_are_zero(rig):
    rig.command([0.2, -0.3], ['vert_rear_left', 'front_right'])
    assert rig.outputs[-1].effort.tolist() == pytest.approx([-0.3, 0, 0, 0, 0, 0, 0, 0.2])
    assert rig.thrusts[-1].effort.tolist() == pytest.approx(
        [-0.3 * 40.2, 0, 0, 0, 0, 0, 0, 0.2 * 51.5])


def test_bad_commands_are_refused_and_counted(rig):
    # Refused: NaN, Inf, an unknown name, names/efforts of different lengths.
    rig.command(CMD)
    n, before = len(rig.outputs), rig.node.command.copy()
    rig.command([math.nan] + CMD[1:])
    rig.command([math.inf] + CMD[1:])
    rig.command([0.1], ['bow_thruster'])
    rig.pub.publish(JointState(name=NAMES, effort=[0.1, 0.2]))
    assert rig.node.refused == 4
    assert len(rig.outputs) == n and len(rig.thrusts) == n
    assert rig.node.command.tolist() == before.tolist()


def test_commands_beyond_one_are_clipped_and_counted(rig):
    rig.command([1.5, -2.0, 0, 0, 0, 0, 0, 0])
    assert rig.node.clipped == 1
    assert rig.outputs[-1].effort.tolist() == pytest.approx([1.0, -1.0, 0, 0, 0, 0, 0, 0])
    assert rig.thrusts[-1].effort.tolist() == pytest.approx([51.5, -40.2, 0, 0, 0, 0, 0, 0])
    rig.command([0, 0, 0, 0, 0, 0, 0, -1.25])   # only one, below -1
    assert rig.node.clipped == 2
    assert rig.outputs[-1].effort.tolist() == pytest.approx([0, 0, 0, 0, 0, 0, 0, -1.0])
    rig.command([1.0, -1.0, 0, 0, 0, 0, 0, 0])  # the limits themselves are not clipped
    assert rig.node.clipped == 2


def test_watchdog_goes_neutral_once_when_commands_stop(executor, spin, rig):
    rig.command(CMD)
    n = len(rig.outputs)
    assert rig.node.timeouts == 0
    assert spin(executor, lambda: rig.node.timeouts == 1, TIMEOUT)
    assert len(rig.outputs) == n + 1
    assert not np.any(rig.outputs[-1].effort) and not np.any(rig.thrusts[-1].effort)
    assert rig.node.neutral
    ticks = [0]
    rig.node.create_timer(0.05, lambda: ticks.__setitem__(0, ticks[0] + 1))
    assert spin(executor, lambda: ticks[0] >= 4, TIMEOUT)
    assert rig.node.timeouts == 1 and len(rig.outputs) == n + 1  # neutral is not repeated


def test_safe_state_zeroes_every_thruster_at_once(rig):
    rig.command(CMD)
    assert np.any(rig.outputs[-1].effort)
    rig.node.safe_state()
    assert rig.outputs[-1].name == NAMES
    assert not np.any(rig.outputs[-1].effort) and not np.any(rig.thrusts[-1].effort)
    assert rig.node.neutral


def test_time_constant_ramps_thrust(context, executor):
    node = add(executor, SimThrustersNode(
        node_name='thruster_control', context=context, parameter_overrides=layout_overrides(
            time_constant=5.0, command_timeout=10.0)))
    names = node.names
    msg = JointState(name=names, effort=[1.0] * len(names))
    LinkBus.of(context).connect()
    p = probe(context, executor, 'controller')
    pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
    msg.header.stamp.sec = 1
    pub.publish(msg)        # from neutral: no lag on the first command
    assert node.thrust == pytest.approx([51.5] * len(names))
    pub.publish(stamped(names, -1.0, 2_000_000_000))
    assert np.all(node.thrust > -40.2) and np.all(node.thrust < 51.5)  # lags


def test_needs_thruster_names(context):
    with pytest.raises(ConfigurationError, match='thruster_names'):
        SimThrustersNode(node_name='thruster_control', context=context)


# -- the motor lag against its closed form ---------------------------------------------------

TC = 0.2                     # motor time constant of these tests [s]
F_FWD, F_REV = 51.5, 40.2    # the sim profile's max_forward / max_reverse [N]


class LagRig:
    """Thrusters with a ``TC`` lag on simulated ROS time that only the test moves (what
    ``enbarr scenario`` does): ``at(t)`` sets the clock and commands. The wall clock runs on
    unseen; the motor lag must not read it."""

    def __init__(self, context: Any, executor: Any) -> None:
        self.node = add(executor, SimThrustersNode(
            node_name='thruster_control', context=context, parameter_overrides=layout_overrides(
                time_constant=TC, command_timeout=10.0)))
        self.clock = SimClock(self.node, t0_ns=1_000_000_000)
        self.sent = 0
        self.names = self.node.names
        p = probe(context, executor, 'controller')
        self.pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
        self.thrusts: list[JointState] = []
        p.create_topic_subscription(topics.SIM_THRUST, self.thrusts.append)
        LinkBus.of(context).connect()

    @property
    def now_ns(self) -> int:
        return self.clock.ns

    @now_ns.setter
    def now_ns(self, ns: int) -> None:
        self.clock.set(ns)

    def at(self, t_s: float, effort: float) -> np.ndarray:
        """Command every thruster to ``effort`` at ROS time 1 s + ``t_s``."""
        self.now_ns = 1_000_000_000 + round(t_s * 1e9)
        # Stamped now, plus 1 ns per command so that a command at a standing clock is still
        # newer than the last (the time policy refuses repeats; the lag is what is tested).
        self.sent += 1
        self.pub.publish(stamped(self.names, effort, self.now_ns + self.sent))
        published = np.array(self.thrusts[-1].effort)
        np.testing.assert_array_equal(published, self.node.thrust)  # what the simulator gets
        assert self.thrusts[-1].header.stamp.sec * 10 ** 9 + \
            self.thrusts[-1].header.stamp.nanosec == self.now_ns   # stamped on that clock
        return published


@pytest.fixture
def lag(context, executor) -> LagRig:
    return LagRig(context, executor)


def first_order(f0: float, target: float, t: float) -> float:
    """Thrust of a first-order motor t [s] after its command became ``target``."""
    return target + (f0 - target) * math.exp(-t / TC)


@pytest.mark.parametrize('before, after', [(0.2, 1.0), (1.0, 0.2), (0.6, -1.0), (-1.0, 0.5),
                                           (-0.3, -0.9)])
def test_lag_step_follows_the_first_order_closed_form(lag, before, after):
    """A step between two commands: f(t) = f* + (f0 - f*) exp(-t / T), 63 % at t = T, from
    either side and through zero. The lag treats each command as held since the previous
    one (``f += (f* - f)(1 - exp(-dt / T))``), so t counts from the last command before the
    step. Budget: float64 rounding of a few hundred updates, 1e-9 N.
    """
    f0 = before * (F_FWD if before >= 0 else F_REV)
    target = after * (F_FWD if after >= 0 else F_REV)
    lag.at(0.0, before)                                 # from neutral: the thrust is set
    assert lag.node.thrust == pytest.approx([f0] * len(lag.names), abs=1e-12)
    t_step, dt = 0.5, 0.01
    lag.at(t_step, before)                              # held: no change
    assert lag.node.thrust == pytest.approx([f0] * len(lag.names), abs=1e-12)
    prev = f0
    for k in range(1, 201):                             # 2 s = 10 T
        t = k * dt
        f = lag.at(t_step + t, after)
        assert f == pytest.approx([first_order(f0, target, t)] * len(lag.names), abs=1e-9)
        # Toward the target, never beyond it, and strictly closer each command.
        assert np.all(np.sign(target - f0) * (target - f) >= -1e-12)
        assert np.all(np.abs(target - f) < abs(target - prev))
        prev = f[0]
        if k == round(TC / dt):
            frac = (f - f0) / (target - f0)
            assert frac == pytest.approx([1.0 - math.exp(-1.0)] * len(lag.names), abs=1e-9)


def test_lag_does_not_depend_on_the_command_spacing(lag):
    """Irregular command intervals land on the same curve (the update is exact for a held
    command, not a fixed-step approximation)."""
    rng = np.random.default_rng(3)
    lag.at(0.0, -0.4)
    lag.at(0.1, -0.4)
    f0 = -0.4 * F_REV
    t = 0.0
    while t < 1.0:
        t += round(float(rng.uniform(0.001, 0.05)), 6)   # whole microseconds: exact in ns
        f = lag.at(0.1 + t, 0.8)
        assert f == pytest.approx([first_order(f0, 0.8 * F_FWD, t)] * len(lag.names), abs=1e-9)


def test_a_zero_command_spins_down_with_the_lag_and_the_next_command_continues(lag):
    """Commanding 0 is not a cut: the motor spins down with the lag, and a command after it
    continues from the thrust of that moment (a reversal through 0 has no jump)."""
    lag.at(0.0, 1.0)
    lag.at(0.05, 1.0)
    f = lag.at(0.06, 0.0)
    f_zero = first_order(F_FWD, 0.0, 0.01)
    assert f == pytest.approx([f_zero] * len(lag.names), abs=1e-9)
    f = lag.at(0.07, -0.5)
    assert f == pytest.approx([first_order(f_zero, -0.5 * F_REV, 0.01)] * len(lag.names),
                              abs=1e-9)
    assert np.all(f > 0.0)       # still pushing forward 10 ms into the reversal


def test_safe_state_cuts_the_thrust_and_the_next_command_starts_from_its_target(lag):
    """safe_state (watchdog, every exit path) cuts the thrust at once, not ramped; from that
    rest the next command sets its thrust (documented: no lag on the first command)."""
    lag.at(0.0, 1.0)
    lag.at(0.05, 1.0)
    lag.now_ns += 10_000_000
    lag.node.safe_state()
    assert lag.node.thrust == pytest.approx([0.0] * len(lag.names), abs=0.0)
    assert lag.at(0.07, -0.5) == pytest.approx([-0.5 * F_REV] * len(lag.names), abs=1e-12)


# -- two clocks: the lag on ROS time, the watchdog on the wall clock --------------------------

def test_lag_does_not_move_while_only_the_wall_clock_runs(lag):
    """Simulated time stands still (a scenario between two steps, a paused simulation) while
    the wall clock runs 50 ms: the thrust must not move. On the wall clock it would have moved
    1 - exp(-0.05 / 0.2) = 22 % of the way."""
    f0 = 0.2 * F_FWD
    lag.at(0.0, 0.2)
    time.sleep(0.05)                                    # at least 50 ms of wall time
    assert lag.at(0.0, 1.0) == pytest.approx([f0] * len(lag.names), abs=1e-12)
    # The same 50 ms of simulated time, taken at once, move it by the closed form.
    assert lag.at(0.05, 1.0) == pytest.approx([first_order(f0, F_FWD, 0.05)] * len(lag.names),
                                              abs=1e-9)


def test_clock_going_back_holds_the_thrust(lag):
    """A simulation restarted under a running node sends its clock back: the lag does not
    run backwards (exp of a positive number would throw the thrust past its target), it
    holds, and goes on from the new present."""
    f0 = 0.2 * F_FWD
    lag.at(0.0, 0.2)
    lag.at(0.5, 0.2)
    assert lag.at(0.2, 1.0) == pytest.approx([f0] * len(lag.names), abs=1e-12)
    assert lag.at(0.3, 1.0) == pytest.approx([first_order(f0, F_FWD, 0.1)] * len(lag.names),
                                             abs=1e-9)


def sim_time_thrusters(context: Any, executor: Any, command_timeout: float) -> Any:
    """Thrusters on simulated ROS time, commanded once at 1 s."""
    node = add(executor, SimThrustersNode(
        node_name='thruster_control', context=context, parameter_overrides=layout_overrides(
            time_constant=TC, command_timeout=command_timeout)))
    clock = SimClock(node, t0_ns=1_000_000_000)
    pub = probe(context, executor, 'controller').create_topic_publisher(
        topics.THRUSTER_COMMANDS)
    LinkBus.of(context).connect()
    node.start()
    pub.publish(JointState(name=node.names, effort=[0.5] * len(node.names)))
    assert not node.neutral
    return node, clock


def test_watchdog_ignores_simulated_time_racing_ahead(context, executor, spin):
    """Simulated time jumps 60 s ahead in three steps right after a command (a scenario runs
    faster than real time); the watchdog's timer fires on each step, but its 10 s timeout is
    wall time, as an ESC's, and the real time since the command is far shorter."""
    node, clock = sim_time_thrusters(context, executor, command_timeout=10.0)
    commanded = time.monotonic()
    calls = []
    supervise = node.supervise
    node.supervise = lambda: (calls.append(clock.ns), supervise())
    for k in range(1, 4):
        clock.advance(20.0)
        assert spin(executor, lambda: len(calls) >= k, TIMEOUT)
    assert time.monotonic() - commanded < 10.0, 'precondition: under 10 s of wall time'
    assert node.timeouts == 0 and not node.neutral


def test_watchdog_fires_on_wall_time_while_simulated_time_stands(context, executor):
    """Simulated time stands still after a command; 0.1 s of wall time later the check (the
    supervision timer's callback, called here because timers wait for simulated time) finds
    the 0.05 s timeout passed and puts the thrusters neutral."""
    node, _ = sim_time_thrusters(context, executor, command_timeout=0.05)
    time.sleep(0.1)                                     # at least 0.1 s of wall time
    node.supervise()
    assert node.timeouts == 1 and node.neutral
    assert not np.any(node.thrust)


# -- the time policy ------------------------------------------------------------------------

def stamped(names: list[str], effort: float, stamp_ns: int) -> JointState:
    msg = JointState(name=list(names), effort=[effort] * len(names))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return msg


def test_commands_stamped_ahead_or_out_of_order_are_refused_and_counted(rig):
    """An older command arriving after a newer one replaced it (and one stamped 20 s ahead
    put a negative latency in the log). Both are refused, counted, and never applied."""
    reports: list[Any] = []
    rig.node.publish_diagnostics = lambda *a: reports.append(a)
    now = rig.probe.get_clock().now().nanoseconds
    rig.pub.publish(stamped(NAMES, 0.5, now))
    n = len(rig.outputs)
    rig.pub.publish(stamped(NAMES, -0.9, now - 1_000_000))          # older: out of order
    rig.pub.publish(stamped(NAMES, -0.8, now + 20_000_000_000))     # 20 s ahead
    assert len(rig.outputs) == n
    assert rig.node.command.tolist() == [0.5] * len(NAMES)
    assert rig.node.gate.counts[StampVerdict.NOT_NEWER] == 1
    assert rig.node.gate.counts[StampVerdict.FUTURE] == 1
    assert rig.node.gate.counts[StampVerdict.ACCEPTED] == 1
    assert np.all(rig.node.latency.last(rig.node.latency.count) >= 0)
    rig.node._supervise()
    level, message, values = reports[-1]
    assert level == 1 and 'thruster_commands' in message, message
    assert values['thruster_commands.future'] == 1


def test_thruster_sensors_report_the_speed_of_a_quadratic_propeller(rig):
    # T = K n|n|: a command c (thrust c T_max, no lag here) turns at sign(c) sqrt(|c|) n_full
    sensors: list[JointState] = []
    rig.probe.create_topic_subscription(topics.THRUSTER_SENSORS, sensors.append)
    LinkBus.of(rig.node.context).connect()
    rig.command(CMD)
    full = rig.node.settings.full_speed
    assert sensors[-1].name == NAMES
    assert sensors[-1].velocity.tolist() == pytest.approx(
        [math.copysign(math.sqrt(abs(c)) * full, c) for c in CMD])
    assert all(math.isnan(e) for e in sensors[-1].effort)   # the sim has no current


@pytest.mark.parametrize('factor', [0.0, 0.5])
def test_a_fouled_rotor_turns_slower_and_gives_the_square_of_its_thrust(rig, factor):
    sensors: list[JointState] = []
    rig.probe.create_topic_subscription(topics.THRUSTER_SENSORS, sensors.append)
    LinkBus.of(rig.node.context).connect()
    name = NAMES[2]   # commanded full forward in CMD
    rig.node.set_parameters([rclpy.parameter.Parameter('fouled', value=[f'{name}:{factor}'])])
    rig.command(CMD)
    full = rig.node.settings.full_speed
    assert sensors[-1].velocity[2] == pytest.approx(factor * full)
    assert rig.thrusts[-1].effort[2] == pytest.approx(factor * factor * 51.5)
    assert rig.thrusts[-1].effort[0] == pytest.approx(0.5 * 51.5)   # the others as before


@pytest.mark.parametrize('entry, match', [
    ('nope:0.5', "no thruster named 'nope'"), (f'{NAMES[0]}:1.5', 'factor in 0..1'),
    (NAMES[0], 'want name:factor')])
def test_a_bad_fouled_entry_is_refused_naming_it(rig, entry, match):
    result = rig.node.set_parameters([rclpy.parameter.Parameter('fouled', value=[entry])])
    assert not result[0].successful and match in result[0].reason
    assert rig.node.settings.fouled == {}
