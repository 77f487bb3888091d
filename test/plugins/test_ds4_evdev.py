"""DualShock 4 evdev driver against its emulator: decoding (unit), check-device (unit and
CLI), and the driver node with every device fault (node).
"""

from __future__ import annotations

import struct
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Joy
from std_msgs.msg import Bool
from support.nodes import TIMEOUT, add, probe

from enbarr_core.framework.errors import ConfigurationError, DeviceError
from enbarr_interfaces import topics
from enbarr_plugins.check import CheckTarget
from enbarr_plugins.joystick import ds4_emulator, ds4_evdev, ds4_protocol
from enbarr_plugins.joystick.check import check_device
from enbarr_plugins.joystick.ds4_emulator import Ds4Emulator, Ds4EmulatorNode
from enbarr_plugins.joystick.ds4_evdev import Ds4EvdevNode, EventDecoder
from enbarr_plugins.joystick.ds4_protocol import AbsInfo
from enbarr_core.control.joy_layouts import get_layout

# alone (setup.cfg): the node tests judge the emulator's real-time stream; they starve
# beside another worker, so ./dev test runs them after the parallel pass
pytestmark = pytest.mark.alone

LAYOUT = get_layout('enbarr_ds4')
TRIANGLE = LAYOUT.buttons.index('triangle')

# The kernel's numbers, typed from its sources (never read from the code under test):
# include/uapi/linux/input-event-codes.h ...
EV_SYN, EV_KEY, EV_ABS, EV_MSC = 0x00, 0x01, 0x03, 0x04
SYN_REPORT, SYN_DROPPED = 0, 3
AXES = {'ABS_X': 0x00, 'ABS_Y': 0x01, 'ABS_Z': 0x02, 'ABS_RX': 0x03, 'ABS_RY': 0x04,
        'ABS_RZ': 0x05, 'ABS_HAT0X': 0x10, 'ABS_HAT0Y': 0x11}
INPUT_PROP_ACCELEROMETER = 0x06
# ... and drivers/hid/hid-playstation.c, ps_gamepad_buttons: the DS4's buttons as key codes.
CODES = {'square': 0x134,    # BTN_WEST
         'triangle': 0x133,  # BTN_NORTH
         'circle': 0x131,    # BTN_EAST
         'cross': 0x130,     # BTN_SOUTH
         'l1': 0x136, 'r1': 0x137, 'l2': 0x138, 'r2': 0x139,  # BTN_TL, TR, TL2, TR2
         'share': 0x13a, 'options': 0x13b, 'ps': 0x13c,       # BTN_SELECT, START, MODE
         'l3': 0x13d, 'r3': 0x13e}                            # BTN_THUMBL, THUMBR
# include/uapi/linux/input.h: struct input_event = struct timeval (two 8-byte longs on 64-bit),
# __u16 type, __u16 code, __s32 value.
EVENT = struct.Struct('<qqHHi')
# ps_gamepad_create: sticks and triggers 0..255, the hat -1..1 (flat 0).
ABSINFO = {**{AXES[a]: AbsInfo(128, 0, 255) for a in ('ABS_X', 'ABS_Y', 'ABS_RX', 'ABS_RY')},
           AXES['ABS_Z']: AbsInfo(0, 0, 255), AXES['ABS_RZ']: AbsInfo(0, 0, 255),
           AXES['ABS_HAT0X']: AbsInfo(0, -1, 1), AXES['ABS_HAT0Y']: AbsInfo(0, -1, 1)}


def pack(*events: tuple[int, int, int], t: float = 1.0) -> bytes:
    return b''.join(EVENT.pack(int(t), int((t % 1) * 1e6), *e) for e in events)


def decoder() -> EventDecoder:
    d = EventDecoder(frozenset(CODES.values()), dict(ABSINFO))
    d.reset(frozenset(), {c: a.value for c, a in ABSINFO.items()})
    return d


# -- decoding (unit) -------------------------------------------------------------------------

@pytest.mark.unit
def test_record_is_the_64_bit_input_event():
    assert EVENT.size == 24
    for struct_ in (ds4_protocol.EVENT, ds4_emulator.EVENT):  # the driver's, the device's
        assert struct_.size == 24
        record = EVENT.pack(1, 2, 3, 4, -5)
        assert struct_.unpack(record) == (1, 2, 3, 4, -5)


@pytest.mark.unit
@pytest.mark.parametrize('side', [ds4_protocol, ds4_emulator], ids=['driver', 'emulator'])
def test_kernel_numbers_are_the_kernels(side):
    """Each side's copy of the kernel's numbers against the numbers typed from its sources."""
    assert side.BUTTON_CODES == CODES
    assert (side.EV_SYN, side.EV_KEY, side.EV_ABS) == (EV_SYN, EV_KEY, EV_ABS)
    assert (side.SYN_REPORT, side.SYN_DROPPED) == (SYN_REPORT, SYN_DROPPED)
    for name, code in AXES.items():
        assert getattr(side, name) == code, name


@pytest.mark.unit
def test_the_drivers_axis_roles_and_properties_are_the_kernels():
    p = ds4_protocol
    assert p.EV_MSC == EV_MSC and p.INPUT_PROP_ACCELEROMETER == INPUT_PROP_ACCELEROMETER
    assert p.STICKS == (AXES['ABS_X'], AXES['ABS_Y'], AXES['ABS_RX'], AXES['ABS_RY'])
    assert p.TRIGGERS == (AXES['ABS_Z'], AXES['ABS_RZ'])
    assert p.GAMEPAD_KEYS == frozenset(CODES.values())
    assert p.GAMEPAD_ABS == frozenset(AXES.values())
    assert ds4_emulator.ABSINFO == ABSINFO


@pytest.mark.unit
def test_sticks_triggers_and_hat_in_the_enbarr_ds4_layout():
    d = decoder()
    # Left stick full up (ABS_Y 0) and full left (ABS_X 0), right stick right (ABS_RX 255),
    # L2 fully pressed, d-pad up-left.
    assert d.feed(pack((EV_ABS, 1, 0), (EV_ABS, 0, 0), (EV_ABS, 3, 255), (EV_ABS, 2, 255),
                       (EV_ABS, 16, -1), (EV_ABS, 17, -1), (EV_SYN, SYN_REPORT, 0)))
    axes, buttons = d.joy()
    assert axes == pytest.approx([1.0, 1.0, -1.0, -0.0039, 1.0, 0.0], abs=1e-3)
    pressed = [n for n, b in zip(LAYOUT.buttons, buttons) if b]
    assert pressed == ['dpad_left', 'dpad_up']


@pytest.mark.unit
@pytest.mark.parametrize('name', list(CODES))
def test_every_button_lands_on_its_layout_index(name):
    d = decoder()
    d.feed(pack((EV_KEY, CODES[name], 1), (EV_SYN, SYN_REPORT, 0)))
    _, buttons = d.joy()
    assert [n for n, b in zip(LAYOUT.buttons, buttons) if b] == [name]


@pytest.mark.unit
def test_a_frame_applies_only_at_syn_report_and_split_records_are_reassembled():
    d = decoder()
    data = pack((EV_KEY, CODES['cross'], 1), (EV_SYN, SYN_REPORT, 0))
    assert not d.feed(data[:10]) and d.partial == 10
    assert not d.feed(data[10:24])  # the key, no SYN_REPORT yet
    assert not d.pressed
    assert d.feed(data[24:]) and d.pressed == {CODES['cross']} and d.partial == 0


@pytest.mark.unit
def test_corrupted_records_are_dropped_and_counted():
    d = decoder()
    assert not d.feed(pack((0x1f, 0, 7), (EV_KEY, 0x2ff, 1), (EV_ABS, 0x28, 5),
                           (EV_ABS, 0, 999), (EV_KEY, CODES['cross'], 7),
                           (EV_SYN, SYN_REPORT, 0)))
    assert d.bad_events == 5 and not d.pressed and d.values[0] == 128


@pytest.mark.unit
def test_syn_dropped_discards_up_to_the_next_report_and_asks_for_the_state():
    d = decoder()
    d.feed(pack((EV_ABS, 0, 0), (EV_SYN, SYN_DROPPED, 0), (EV_ABS, 1, 0),
                (EV_SYN, SYN_REPORT, 0)))
    assert d.dropped == 1 and d.resync_due and d.values[0] == 128 and d.values[1] == 128


@pytest.mark.unit
def test_event_times_going_back_are_counted():
    d = decoder()
    d.feed(pack((EV_KEY, CODES['cross'], 1), (EV_SYN, SYN_REPORT, 0), t=5.0))
    d.feed(pack((EV_KEY, CODES['cross'], 0), (EV_SYN, SYN_REPORT, 0), t=4.0))
    assert d.out_of_order == 1 and not d.pressed  # applied in the kernel's order


# -- check-device (unit) -----------------------------------------------------------------------

@pytest.mark.unit
def test_check_device_against_the_emulator_prints_identity_and_state():
    lines = check_device(CheckTarget(device='emulated'))
    assert 'name: Sony Interactive Entertainment Wireless Controller' in lines
    assert lines[-1].endswith('pressed: cross')


@pytest.mark.unit
def test_check_device_refuses_a_wrong_node_and_an_absent_one(monkeypatch):
    with pytest.raises(DeviceError, match='/dev/input/event99: cannot open'):
        check_device(CheckTarget(device='/dev/input/event99'))
    emu = Ds4Emulator()
    emu.wrong_identity = True
    h = emu.open()
    with pytest.raises(DeviceError, match=r"emulated: not a DualShock 4 gamepad: "
                       r"'Sony Interactive Entertainment Wireless Controller Motion Sensors'"):
        ds4_evdev.check_identity(h)
    h.close()


@pytest.mark.unit
def test_check_device_through_the_cli(capsys):
    from enbarr_core.commands.main import main
    assert main(['check-device', 'ds4', '--device', 'emulated']) == 0
    assert 'Wireless Controller' in capsys.readouterr().out
    assert main(['check-device', 'ds4', '--device', '/dev/input/event99']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and '/dev/input/event99' in err[0]


# -- the driver node against the emulator node ----------------------------------------------------

class Rig:
    """An emulator node, the driver on 'emulated:NAME', and a listener."""

    def __init__(self, context: Any, executor: Any, spin: Any, name: str = 'pad',
                 absent: bool = False, wrong: bool = False, **params: Any) -> None:
        self.executor, self.spin = executor, spin
        self.emu_node = add(executor, Ds4EmulatorNode(
            node_name=f'emu_{name}', context=context,
            parameter_overrides=[Parameter('name', value=name)]))
        self.emu_node.start()  # bringup starts the emulators first
        self.emu = self.emu_node.emulator
        self.emu.absent, self.emu.wrong_identity = absent, wrong
        self.joys: list[Joy] = []
        self.connected: list[bool] = []
        self.diags: list[Any] = []
        p = probe(context, executor, f'listen_{name}')
        p.create_subscription(Joy, topics.JOY.name, self.joys.append, topics.JOY.qos)
        p.create_subscription(Bool, topics.JOY_CONNECTED.name,
                              lambda m: self.connected.append(m.data), topics.JOY_CONNECTED.qos)
        p.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name,
                              lambda m: self.diags.extend(s for s in m.status
                                                          if 'joystick' in s.name),
                              topics.DIAGNOSTICS.qos)
        overrides = {'device': f'emulated:{name}', 'reconnect.initial_delay': 0.05,
                     'reconnect.max_delay': 0.2, **params}
        self.node = add(executor, Ds4EvdevNode(
            node_name='joystick', context=context,
            parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()]))
        self.node.start()

    def until(self, condition: Any, timeout: float = TIMEOUT) -> bool:
        return self.spin(self.executor, condition, timeout)

    def pressed(self, name: str) -> bool:
        i = LAYOUT.buttons.index(name)
        return any(j.buttons[i] for j in self.joys[-5:])


@pytest.mark.node
def test_driver_reads_the_emulator_and_heartbeats(context, executor, spin):
    r = Rig(context, executor, spin)
    assert r.until(lambda: r.node.connected and len(r.joys) >= 3 and True in r.connected)
    r.emu.sticks({'left_y': 1.0, 'right_x': -0.5})
    r.emu.press('triangle')
    assert r.until(lambda: r.pressed('triangle'))
    j = r.joys[-1]
    assert j.axes[1] == pytest.approx(1.0) and j.axes[2] == pytest.approx(-0.5, abs=0.01)
    # Nothing moves: the heartbeat goes on with the held state (a resting stick is not silence).
    n = len(r.joys)
    assert r.until(lambda: len(r.joys) >= n + 5)
    assert r.joys[-1].axes[1] == pytest.approx(1.0) and r.joys[-1].header.stamp.sec > 0


@pytest.mark.node
def test_unplug_is_disconnected_at_once_and_replug_resumes(context, executor, spin):
    r = Rig(context, executor, spin)
    assert r.until(lambda: r.node.connected and r.connected[-1:] == [True])
    r.emu.unplug()
    assert r.until(lambda: not r.node.connected and r.connected[-1] is False)
    assert r.node.last_fault == ('emulated:pad (Sony Interactive Entertainment Wireless '
                                 'Controller): end of input (unplugged)')
    assert r.until(lambda: any(s.level == b'\x02' or s.level == 2 for s in r.diags))
    n = len(r.joys)
    time.sleep(0.3)
    r.until(lambda: False, 0.3)
    assert r.until(lambda: not r.node.connected) and len(r.joys) <= n + 1  # no stale samples
    r.emu.replug()
    r.emu.press('cross')
    assert r.until(lambda: r.node.connected and r.connected[-1] is True)
    assert r.node.faults >= 2  # the unplug, then retries while it was out
    r.emu.press('square')
    assert r.until(lambda: r.pressed('square'))


@pytest.mark.node
def test_absent_at_start_then_plugged_in(context, executor, spin):
    r = Rig(context, executor, spin, absent=True)
    assert not r.node.connected and 'not plugged in' in r.node.last_fault
    assert r.until(lambda: r.node.faults >= 2)  # retried with backoff
    r.emu.replug()
    assert r.until(lambda: r.node.connected and r.connected[-1:] == [True])


@pytest.mark.node
def test_wrong_identity_is_refused_naming_what_was_read(context, executor, spin):
    r = Rig(context, executor, spin, wrong=True)
    assert not r.node.connected
    assert "not a DualShock 4 gamepad: 'Sony Interactive Entertainment Wireless Controller " \
        "Motion Sensors' is a motion-sensor node" in r.node.last_fault
    r.emu.wrong_identity = False
    assert r.until(lambda: r.node.connected)


@pytest.mark.node
def test_garbage_split_records_and_syn_dropped(context, executor, spin):
    r = Rig(context, executor, spin)
    assert r.until(lambda: r.node.connected and bool(r.joys))
    r.emu.garbage()
    assert r.until(lambda: r.node.decoder.bad_events == 5)
    r.emu.split_frame('circle')
    assert r.until(lambda: r.pressed('circle'))
    r.emu.syn_dropped('l1')  # the press was lost in the overrun: only the state has it
    assert r.until(lambda: r.pressed('l1') and r.node.resyncs == 1)
    assert r.node.connected and r.node.faults == 0
    values = r.node.status_values()
    assert values['dropped'] == 1 and values['bad_events'] == 5


@pytest.mark.node
def test_a_stalled_device_blocks_nothing(context, executor, spin):
    r = Rig(context, executor, spin)
    assert r.until(lambda: r.node.connected and bool(r.joys))
    r.emu.stall()
    r.emu.press('cross')  # never written
    n = len(r.joys)
    ticks = []
    timer = r.node.create_timer(0.01, lambda: ticks.append(1))
    assert r.until(lambda: len(ticks) >= 30 and len(r.joys) >= n + 5)
    r.node.destroy_timer(timer)
    assert r.node.connected and not r.pressed('cross')


@pytest.mark.node
def test_bad_device_parameter_is_named(context):
    with pytest.raises(ConfigurationError, match="device: '/dev/input/eventN', 'auto' or") as info:
        Ds4EvdevNode(node_name='joystick', context=context,
                     parameter_overrides=[Parameter('device', value='js0')])
    assert info.value.parameter == 'device'


@pytest.mark.node
def test_the_emulator_reports_what_it_wrote(context, executor, spin):
    r = Rig(context, executor, spin)
    assert r.until(lambda: r.node.connected)
    r.emu.press('cross')
    got: list[Any] = []
    p = probe(context, executor, 'emu_diag')
    p.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name,
                          lambda m: got.extend(s for s in m.status if 'emu_pad' in s.name),
                          topics.DIAGNOSTICS.qos)
    assert r.until(lambda: bool(got))
    values = {kv.key: kv.value for kv in got[-1].values}
    assert int(values['events']) >= 2 and int(values['opens']) == 1


def test_emulator_offers_its_device_from_start_until_destroyed(context):
    from enbarr_plugins import emulation
    node = Ds4EmulatorNode(node_name='emu_x', context=context,
                           parameter_overrides=[Parameter('name', value='x')])
    with pytest.raises(DeviceError):  # constructing it offers nothing
        emulation.lookup('evdev', 'emulated:x')
    node.start()
    assert emulation.lookup('evdev', 'emulated:x') is node.emulator
    node.destroy_node()
    with pytest.raises(DeviceError):
        emulation.lookup('evdev', 'emulated:x')


@pytest.mark.node
def test_the_emulated_saucer_joystick_drives_the_modes(context, executor, spin):
    """ds4_emulator -> ds4_evdev -> dp_control with the Saucer's profile (enbarr_ds4 layout,
    connection rule): triangle through the event pipe is automatic, the sticks are the
    manual force, unplugging is manual with zero force at once.
    """
    from support.saucer import DpHarness
    h = DpHarness(context, executor, spin)
    h.probe.destroy_publisher(h.joy_pub)  # one joystick: the driver's
    h.probe.destroy_publisher(h.connected_pub)
    r = Rig(context, executor, spin)
    h.clock.attach(r.node)  # the driver stamps on the vessel's clock
    assert r.until(lambda: h.node.manager.connected)
    # The simulated clock stands still between steps: each new state gets a new stamp.
    h.clock.advance(0.05)
    r.emu.sticks({'left_y': 0.5})
    assert r.until(lambda: bool(h.taus) and h.taus[-1][0] > 0.1)
    eta = [0.2, 0.1, 0.3]
    h.estimate(eta)
    h.clock.advance(0.05)
    r.emu.press('triangle')
    h.wait_mode('automatic')
    h.estimate(eta)
    n_modes = len(h.modes)
    r.emu.unplug()
    assert r.until(lambda: len(h.modes) > n_modes and h.modes[-1] == 'manual')
    assert h.taus[-1].tolist() == [0.0, 0.0, 0.0]


@pytest.mark.unit
def test_auto_picks_the_gamepad_node_not_the_motion_sensors(monkeypatch):
    import evdev
    sensors, pad = Ds4Emulator(), Ds4Emulator()
    sensors.wrong_identity = True
    nodes = {'/dev/input/event3': sensors, '/dev/input/event4': pad}

    def fake_open(path: str) -> Any:
        if path not in nodes:
            raise DeviceError(f'{path}: cannot open: Permission denied')
        h = nodes[path].open()
        h.path = path
        return h

    monkeypatch.setattr(ds4_evdev, 'open_input', fake_open)
    monkeypatch.setattr(evdev, 'list_devices', lambda: ['/dev/input/event4',
                                                        '/dev/input/event2',
                                                        '/dev/input/event3'])
    h = ds4_evdev.open_device('auto')
    assert h.path == '/dev/input/event4'
    h.close()
    del nodes['/dev/input/event4']
    with pytest.raises(DeviceError, match=r'auto: no DualShock 4 gamepad .*event2: cannot open: '
                       r'Permission denied; /dev/input/event3 \(.*Motion Sensors\)'):
        ds4_evdev.open_device('auto')


class _Recorder:
    """A publisher that also keeps what it publishes."""

    def __init__(self, pub: Any, sink: list[Any]) -> None:
        self._pub, self._sink = pub, sink

    def publish(self, msg: Any) -> None:
        self._sink.append(msg)
        self._pub.publish(msg)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._pub, name)


@pytest.mark.node
def test_constructing_the_driver_opens_and_publishes_nothing(context, executor, spin,
                                                              monkeypatch):
    sent: list[Any] = []
    real = Ds4EvdevNode.create_topic_publisher
    monkeypatch.setattr(Ds4EvdevNode, 'create_topic_publisher',
                        lambda self, spec: _Recorder(real(self, spec), sent))
    emu_node = add(executor, Ds4EmulatorNode(
        node_name='emu_quiet', context=context,
        parameter_overrides=[Parameter('name', value='quiet')]))
    emu_node.start()
    node = add(executor, Ds4EvdevNode(
        node_name='joystick', context=context,
        parameter_overrides=[Parameter('device', value='emulated:quiet')]))
    assert emu_node.emulator.opens == 0 and sent == [] and not node.connected
    said_true = lambda: any(isinstance(m, Bool) and m.data for m in sent)  # noqa: E731
    real_safe_state = Ds4EvdevNode.safe_state

    def late_safe_state(self: Ds4EvdevNode) -> None:
        # Between opening and starting, give the reader its first heartbeats (they must not
        # say True yet) before the safe state says False: the order must not rest on luck.
        deadline = time.monotonic() + 0.2
        while not said_true() and time.monotonic() < deadline:
            time.sleep(0.005)
        real_safe_state(self)

    monkeypatch.setattr(Ds4EvdevNode, 'safe_state', late_safe_state)
    node.start()
    assert emu_node.emulator.opens == 1 and node.connected
    assert spin(executor, said_true, TIMEOUT)
    said = [m.data for m in sent if isinstance(m, Bool)]
    assert said[0] is False and said[said.index(True):].count(False) == 0, said
