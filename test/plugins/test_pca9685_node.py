"""Node tests: the PCA9685 thruster driver against its emulator on one executor.

Commands -> the exact bytes on the (fake) I2C bus -> the pulse widths the emulated chip
outputs; arming; the watchdog; every device fault, each followed by the device coming back.
"""

from __future__ import annotations

import itertools
import threading
from typing import Any

import numpy as np
import pytest
from rcl_interfaces.msg import Parameter
from sensor_msgs.msg import JointState
from support.devices import diagnostics_of, pass_time
from support.nodes import TIMEOUT, add, probe
from support.rov import layout_overrides, sim_parameters

from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins import emulation
from enbarr_plugins.thrusters.pca9685 import Pca9685ThrustersNode
from enbarr_plugins.thrusters.pca9685_emulator import (
    EMULATOR_PCA9685, Pca9685Emulator, Pca9685EmulatorNode, WrongDevice)

NAMES = sim_parameters()['thruster_names']
CHANNELS = {f'pca9685.channels.{n}': i for i, n in enumerate(NAMES)}
CMD = [0.5, -0.5, 1.0, -1.0, 0.0, 0.25, -0.25, 0.1]
ADDRESS = 0x40
PRESCALE = 121                  # round(25e6 / (4096 * 50)) - 1
TICK_US = (PRESCALE + 1) / 25.0  # one count [us] at 50 Hz with the nominal oscillator
_bus_names = itertools.count()


def expected_pulse(c: float) -> float:
    """The default calibration (1100/1500/1900 us, dead band 25 us), written out again."""
    if c > 0:
        return 1525.0 + c * (1900.0 - 1525.0)
    if c < 0:
        return 1475.0 + c * (1475.0 - 1100.0)
    return 1500.0


def expected_block(cmd: list[float]) -> bytes:
    out = b''
    for c in cmd:
        counts = round(expected_pulse(c) / TICK_US)
        out += bytes([0, 0, counts & 0xFF, counts >> 8])
    return out


class Rig:
    """Emulator (optional at start), driver and a controller, in one process."""

    def __init__(self, context: Any, executor: Any, spin: Any, *, emulator: bool = True,
                 start: bool = True, **extra: Any) -> None:
        self.context, self.executor, self.spin = context, executor, spin
        self.bus_name = f't{next(_bus_names)}'
        self.emulator: Pca9685EmulatorNode | None = None
        if emulator:
            self.start_emulator()
        params = {**CHANNELS, 'bus': f'emulated:{self.bus_name}', 'arming_time': 0.0,
                  'command_timeout': 10.0, 'verify_period': 0.1,
                  'reconnect.initial_delay': 0.05, 'reconnect.max_delay': 0.2, **extra}
        self.node = add(executor, Pca9685ThrustersNode(
            context=context, parameter_overrides=layout_overrides(**params)))
        self.probe = p = probe(context, executor, 'controller')
        self.pub = p.create_topic_publisher(topics.THRUSTER_COMMANDS)
        self.outputs: list[JointState] = []
        self.thrusts: list[JointState] = []
        self.pulses: list[JointState] = []
        p.create_topic_subscription(topics.THRUSTER_OUTPUT, self.outputs.append)
        p.create_topic_subscription(topics.SIM_THRUST, self.thrusts.append)
        p.create_subscription(JointState, EMULATOR_PCA9685.name, self.pulses.append,
                              EMULATOR_PCA9685.qos)
        self.diagnostics = diagnostics_of(p, 'thruster_control')
        LinkBus.of(context).connect()
        if start:
            self.node.start()

    def start_emulator(self, **extra: Any) -> Pca9685EmulatorNode:
        self.emulator = add(self.executor, Pca9685EmulatorNode(
            context=self.context, parameter_overrides=layout_overrides(
                **CHANNELS, name=self.bus_name, rate=50.0, **{'esc.arming_time': 0.2},
                **extra)))
        self.emulator.start()
        return self.emulator

    @property
    def bus(self) -> Any:
        return emulation.lookup('i2c', f'emulated:{self.bus_name}')

    @property
    def chip(self) -> Pca9685Emulator:
        return self.bus.devices[ADDRESS]

    def command(self, efforts: list[float]) -> None:
        msg = JointState(name=list(NAMES), effort=[float(e) for e in efforts])
        msg.header.stamp = self.probe.get_clock().now().to_msg()
        self.pub.publish(msg)

    def until(self, condition: Any) -> bool:
        return self.spin(self.executor, condition, TIMEOUT)

    def channel_writes(self) -> list[bytes]:
        return [data for op, addr, reg, data in list(self.bus.log)
                if op == 'write' and addr == ADDRESS and reg == 0x06]

    def wrote(self, block: bytes) -> bool:
        return bool(self.channel_writes()) and self.channel_writes()[-1] == block

    def faulted(self) -> bool:
        return not self.node.connected and self.node.faults > 0

    def commanding_until(self, cmd: list[float], condition: Any) -> bool:
        """Command ``cmd`` every spin until ``condition()`` (a chain commands at its rate)."""
        def step() -> bool:
            self.command(cmd)
            return condition()
        return self.until(step)


@pytest.fixture
def rig(context, executor, spin) -> Rig:
    return Rig(context, executor, spin)


def test_a_constructed_driver_touches_nothing_until_started(context, executor, spin):
    """Building the node (bringup --check) must not put a running vessel's chip to sleep."""
    rig = Rig(context, executor, spin, start=False)
    pass_time(executor, spin, rig.probe)
    assert list(rig.bus.log) == []                 # not one transfer: the chip is untouched
    assert rig.chip.regs[0x00] == 0x11             # MODE1 still at its power-on value
    assert rig.outputs == [] and rig.diagnostics == []
    assert not rig.node.connected and rig.node.faults == 0
    rig.node.start()
    assert rig.bus.log[0] == ('read', ADDRESS, 0x00, bytes([0x11]))   # MODE1 first
    assert rig.until(lambda: rig.outputs and rig.outputs[-1].effort.tolist() == [0.0] * 8)


def test_an_emulator_plugs_its_chip_in_when_started(context, executor):
    node = add(executor, Pca9685EmulatorNode(context=context, parameter_overrides=(
        layout_overrides(**CHANNELS, name='unstarted'))))
    with pytest.raises(DeviceError, match="no i2c emulator named 'unstarted'"):
        emulation.lookup('i2c', 'emulated:unstarted')
    node.start()
    assert emulation.lookup('i2c', 'emulated:unstarted').devices[ADDRESS] is node.chip


def test_configures_the_chip_as_the_data_sheet_says(rig):
    assert rig.node.connected
    writes = [(reg, data) for op, addr, reg, data in rig.bus.log if op == 'write']
    # Asleep with auto-increment, totem-pole outputs, prescale for 50 Hz, channels neutral,
    # then awake.
    assert writes[:3] == [(0x00, bytes([0x30])), (0x01, bytes([0x04])),
                          (0xFE, bytes([PRESCALE]))]
    assert writes[3] == (0x06, expected_block([0.0] * 8))
    assert (0x00, bytes([0x20])) in writes[4:]
    assert rig.chip.prescale_blocked == 0 and rig.chip.early_restart == 0
    assert rig.until(lambda: rig.chip.pulse_us(0) > 0)
    assert rig.chip.pulse_us(0) == pytest.approx(1500.0, abs=TICK_US)


def test_commands_become_exact_register_bytes_and_pulse_widths(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    # One auto-increment block of 32 bytes for the 8 thrusters on channels 0..7.
    assert len(rig.channel_writes()[-1]) == 32
    for i, c in enumerate(CMD):
        assert rig.chip.pulse_us(i) == pytest.approx(expected_pulse(c), abs=TICK_US / 2 + 1e-9)
    assert rig.until(lambda: rig.outputs and rig.outputs[-1].effort.tolist() == CMD)
    assert rig.outputs[-1].name == NAMES and not rig.node.neutral


def test_the_emulated_escs_arm_then_thrust_reaches_the_simulator(rig):
    rig.emulator.start()
    assert rig.until(lambda: all(e.armed for e in rig.emulator.escs))
    assert rig.commanding_until(
        CMD, lambda: rig.thrusts and rig.thrusts[-1].effort[2] > 51.0)
    thrust = rig.thrusts[-1].effort
    assert thrust[2] == pytest.approx(51.5, rel=0.02) and thrust[3] == pytest.approx(-40.2,
                                                                                 rel=0.02)
    assert thrust[4] == 0.0 and thrust[0] > 0.0 > thrust[1]
    assert rig.until(lambda: rig.pulses and rig.pulses[-1].position[2] > 1890)
    assert rig.pulses[-1].name == NAMES


def test_commands_are_held_neutral_while_the_escs_arm(context, executor, spin):
    rig = Rig(context, executor, spin, arming_time=0.6)
    rig.command(CMD)
    assert rig.until(lambda: rig.node.held_arming >= 1 and rig.outputs)
    assert rig.wrote(expected_block([0.0] * 8)) and not rig.node.armed
    assert rig.outputs[-1].effort.tolist() == [0.0] * 8
    assert rig.commanding_until(CMD, lambda: rig.wrote(expected_block(CMD)))
    assert rig.node.armed


def test_watchdog_writes_neutral_when_commands_stop(context, executor, spin):
    rig = Rig(context, executor, spin, command_timeout=0.1)
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    assert rig.until(lambda: rig.node.timeouts == 1 and rig.wrote(expected_block([0.0] * 8)))
    assert rig.outputs[-1].effort.tolist() == [0.0] * 8


def test_safe_state_writes_neutral(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    rig.node.safe_state()
    assert rig.until(lambda: rig.wrote(expected_block([0.0] * 8)))
    assert rig.node.neutral


def test_destroying_the_node_leaves_the_chip_neutral(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    rig.executor.remove_node(rig.node)
    rig.node.destroy_node()           # no safe_state first: the driver's own last word
    assert rig.wrote(expected_block([0.0] * 8))
    assert rig.chip.pulse_us(2) == pytest.approx(1500.0, abs=TICK_US)


def test_unplugged_then_replugged(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    rig.bus.detach(ADDRESS)
    assert rig.until(rig.faulted)   # found by the MODE1 check, no command needed
    assert f'emulated:{rig.bus_name} 0x40' in rig.node.last_fault
    assert 'EREMOTEIO' in rig.node.last_fault
    assert rig.node.neutral         # safe state
    assert rig.until(lambda: any(s.level == b'\x02' and 'EREMOTEIO' in s.message
                                 for s in rig.diagnostics))
    rig.bus.attach(ADDRESS, Pca9685Emulator())    # replugged: power-on state
    assert rig.commanding_until(CMD, lambda: rig.node.connected and rig.wrote(
        expected_block(CMD)))
    assert rig.chip.pulse_us(2) == pytest.approx(1900.0, abs=TICK_US)


def test_absent_at_start_then_the_device_appears(context, executor, spin):
    rig = Rig(context, executor, spin, emulator=False)
    assert not rig.node.connected and rig.node.faults == 1
    assert f'no i2c emulator named {rig.bus_name!r}' in rig.node.last_fault
    rig.start_emulator()
    assert rig.until(lambda: rig.node.connected)
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))


def test_a_stalled_bus_blocks_only_the_writer_then_it_resumes(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    rig.chip.stall_time = 0.3      # each transfer blocks 0.3 s, then times out
    done = threading.Event()

    def chain() -> None:           # a chain thread that keeps commanding through the stall
        for _ in range(20):
            rig.command(CMD)
        done.set()
    threading.Thread(target=chain).start()
    assert done.wait(TIMEOUT)
    assert rig.until(rig.faulted)
    assert 'ETIMEDOUT' in rig.node.last_fault
    rig.chip.stall_time = 0.0
    assert rig.commanding_until(CMD, lambda: rig.node.connected and rig.wrote(
        expected_block(CMD)))


def test_one_nack_is_retried_without_a_fault(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    rig.bus.nack(ADDRESS, 1)
    rig.command([0.0] * 8)
    assert rig.until(lambda: rig.wrote(expected_block([0.0] * 8)))
    assert rig.node.connected and rig.node.faults == 0
    assert rig.node.chip.device.errors == 1


def test_corrupted_readback_is_a_fault_until_it_reads_right(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    rig.chip.corrupt = True
    assert rig.until(rig.faulted)
    assert 'MODE1 read 0x7a, expected 0x20' in rig.node.last_fault
    assert rig.until(lambda: rig.node.faults >= 2)   # reopening fails while it is corrupt
    # (0xea: 0xb0 = AI | SLEEP | RESTART, the chip went to sleep while running, xor 0x5a)
    assert 'not a PCA9685' in rig.node.last_fault and 'MODE1 read 0xea' in rig.node.last_fault
    rig.chip.corrupt = False
    assert rig.commanding_until(CMD, lambda: rig.node.connected and rig.wrote(
        expected_block(CMD)))


def test_a_chip_reset_by_power_is_reconfigured(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    rig.chip.power_cycle()          # brown-out: asleep, outputs off, 200 Hz
    assert rig.chip.pulse_us(0) == 0.0
    assert rig.commanding_until(CMD, rig.faulted)
    assert 'MODE1 read 0x11' in rig.node.last_fault
    assert rig.commanding_until(CMD, lambda: rig.node.connected and rig.wrote(
        expected_block(CMD)))
    assert rig.chip.prescale == PRESCALE


def test_a_wrong_device_at_the_address_is_refused_naming_what_it_read(context, executor,
                                                                      spin):
    rig = Rig(context, executor, spin, emulator=False)
    rig.start_emulator()
    chip = rig.chip
    rig.bus.attach(ADDRESS, WrongDevice(0xFF))
    assert rig.until(lambda: 'not a PCA9685' in rig.node.last_fault)
    assert (f'emulated:{rig.bus_name} 0x40: not a PCA9685' in rig.node.last_fault
            and 'MODE1 read 0xff, wrote 0x30' in rig.node.last_fault)
    assert not rig.node.connected
    rig.bus.attach(ADDRESS, chip)
    assert rig.until(lambda: rig.node.connected)


def test_future_and_old_commands_are_refused(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    msg = JointState(name=list(NAMES), effort=[0.0] * 8)
    msg.header.stamp = rig.probe.get_clock().now().to_msg()
    msg.header.stamp.sec += 5
    rig.pub.publish(msg)
    msg.header.stamp.sec -= 100
    rig.pub.publish(msg)
    rig.command([0.2, 0.1, 0, 0, 0, 0, 0, 1.5])     # clipped
    assert rig.node.refused == 2 and rig.node.clipped == 1
    assert rig.until(lambda: rig.wrote(expected_block([0.2, 0.1, 0, 0, 0, 0, 0, 1.0])))


@pytest.mark.parametrize('extra, match', [
    ({'bus': 'i2c-one'}, "bus: 'i2c-one' is not an I2C bus"),
    ({'pca9685.channels.front_left': 0}, 'two thrusters on one channel'),
    ({'pca9685.pulse.front_right.max': 1450.0}, 'pca9685.pulse.front_right'),
    ({'frequency': 600.0}, 'pca9685.pulse.front_right.max: 1900.0 us does not fit'),
])
def test_bad_parameters_name_the_parameter(context, extra, match):
    with pytest.raises(ConfigurationError, match=match):
        Pca9685ThrustersNode(context=context, parameter_overrides=layout_overrides(
            **{**CHANNELS, 'bus': 'emulated', **extra}))


def test_channels_are_required(context):
    with pytest.raises(ConfigurationError, match='pca9685.channels.front_right'):
        Pca9685ThrustersNode(context=context, parameter_overrides=layout_overrides(
            bus='emulated'))


def test_emulator_reports_what_it_received(rig):
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))
    seen = diagnostics_of(rig.probe, 'pca9685_emulator')
    assert rig.until(lambda: seen)
    values = {kv.key: kv.value for kv in seen[-1].values}
    assert int(values['transfers']) > 5 and values['prescale'] == str(PRESCALE)
    assert np.isfinite(float(values['bytes']))


# -- the camera tilt servo on a spare channel ----------------------------------------------
# Data sheet numbers typed in (NXP PCA9685 Rev. 4): LEDn_ON_L = 0x06 + 4 n (table 4), so
# channel 8's four registers start at 0x26; 4096 counts a period; PRE_SCALE =
# round(25 MHz / (4096 f)) - 1 (equation 1): 121 at 50 Hz. One count is 122 / 25 MHz =
# 4.88 us, so 1500 us is 307 counts (0x133), 1900 us 389 (0x185), 1100 us 225 (0xe1).
SERVO = {'servo.channel': 8, 'servo.rate': 90.0}
LED8_ON_L = 0x26


def servo_writes(rig: Rig) -> list[bytes]:
    return [data for op, addr, reg, data in list(rig.bus.log)
            if op == 'write' and addr == ADDRESS and reg == LED8_ON_L]


def test_the_servo_starts_centred_with_the_thrusters_first_block(context, executor, spin):
    rig = Rig(context, executor, spin, **SERVO)
    writes = [(reg, data) for op, addr, reg, data in rig.bus.log if op == 'write']
    # Channels 0..8 while asleep: 36 bytes, in blocks of at most 32 (one SMBus block).
    assert writes[3] == (0x06, expected_block([0.0] * 8))
    assert writes[4] == (LED8_ON_L, bytes([0x00, 0x00, 0x33, 0x01]))
    assert bytes(rig.chip.regs[LED8_ON_L:LED8_ON_L + 4]) == bytes([0x00, 0x00, 0x33, 0x01])


def test_a_tilt_request_moves_the_servo_at_its_rate_to_the_exact_pulse(context, executor, spin):
    rig = Rig(context, executor, spin, **SERVO)
    io = rig.probe.create_topic_publisher(topics.IO_REQUEST)
    io.publish(Parameter(name='camera_tilt', value=convert.python_to_parameter_value(45.0)))
    assert rig.until(lambda: servo_writes(rig)
                     and servo_writes(rig)[-1] == bytes([0x00, 0x00, 0x85, 0x01]))
    assert rig.chip.pulse_us(8) == pytest.approx(389 * 122 / 25.0)
    # On its way (servo.py's rate limit, its unit tests): rising, each written alone.
    ramp = [(w[3] << 8) | w[2] for w in servo_writes(rig)]
    assert ramp == sorted(ramp) and all(len(w) == 4 for w in servo_writes(rig))
    io.publish(Parameter(name='camera_tilt', value=convert.python_to_parameter_value(-90)))
    assert rig.until(lambda: servo_writes(rig)[-1] == bytes([0x00, 0x00, 0xe1, 0x00]))
    assert rig.node.servo.angle == -45.0   # clamped to servo.min_angle
    # The thrusters' block is still channels 0..7 alone.
    rig.command(CMD)
    assert rig.until(lambda: rig.wrote(expected_block(CMD)))


def test_a_tilt_request_of_the_wrong_type_is_refused(context, executor, spin):
    rig = Rig(context, executor, spin, **SERVO)
    io = rig.probe.create_topic_publisher(topics.IO_REQUEST)
    io.publish(Parameter(name='camera_tilt', value=convert.python_to_parameter_value(True)))
    assert rig.until(lambda: rig.node.servo_refused == 1)
    assert rig.node.servo.goal == 0.0
    assert servo_writes(rig) == [bytes([0x00, 0x00, 0x33, 0x01])]   # the first block's, alone


def test_the_emulator_reports_the_servo_pulse(context, executor, spin):
    rig = Rig(context, executor, spin, emulator=False, start=False, **SERVO)
    emulator = rig.start_emulator(**{'servo.channel': 8})
    rig.node.start()
    assert rig.until(lambda: emulator.servo_pulse() == pytest.approx(307 * 122 / 25.0))
    io = rig.probe.create_topic_publisher(topics.IO_REQUEST)
    io.publish(Parameter(name='camera_tilt', value=convert.python_to_parameter_value(45.0)))
    assert rig.until(lambda: emulator.servo_pulse() == pytest.approx(389 * 122 / 25.0))
    seen = diagnostics_of(rig.probe, 'pca9685_emulator')
    assert rig.until(lambda: any(kv.key == 'servo_pulse_us' and kv.value == '1898'
                                 for d in seen for kv in d.values))
