"""The driver contract (``framework/driver.py``): an absent device, run-time faults, the
actuator watchdog and stale sensors. Time is a fake monotonic clock the test moves, and the
supervision tick (``_supervise``) is called directly: nothing here depends on how fast the
machine is.
"""

from __future__ import annotations

import threading
from types import SimpleNamespace
from typing import Any

import pytest
from rclpy.parameter import Parameter
from support.nodes import TIMEOUT, add, probe
from support.waiting import poll_until

from enbarr_core.framework import driver
from enbarr_core.framework.driver import ERROR, OK, WARN, ActuatorDriver, SensorDriver
from enbarr_core.framework.errors import DeviceError
from enbarr_interfaces import topics

S = 1_000_000_000  # ns per s


class FakeClock:
    def __init__(self) -> None:
        self.ns = 1000 * S

    def at(self, seconds: float) -> None:
        self.ns = 1000 * S + int(seconds * S)


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    c = FakeClock()
    monkeypatch.setattr(driver, 'time', SimpleNamespace(monotonic_ns=lambda: c.ns))
    return c


class Reports:
    """What a driver put on /diagnostics: (level, message, values) per report."""

    def __init__(self, node: Any) -> None:
        self.items: list[tuple[int, str, dict[str, Any]]] = []
        publish = node.publish_diagnostics

        def record(level: int, message: str, values: dict[str, Any]) -> None:
            self.items.append((level, message, values))
            publish(level, message, values)

        node.publish_diagnostics = record

    @property
    def last(self) -> tuple[int, str, dict[str, Any]]:
        return self.items[-1]


class FakeActuator(ActuatorDriver):
    """One output on a device that can be absent; counts opens and closes."""

    def __init__(self, present: bool = True, **kwargs: Any) -> None:
        self.present = present
        self.opens = 0
        self.closes = 0
        self.neutral = True
        self.outputs: list[float] = []
        super().__init__('fake_actuator', device='fake0', **kwargs)

    def open_device(self) -> None:
        self.opens += 1
        if not self.present:
            raise DeviceError('fake0: no answer')

    def close_device(self) -> None:
        self.closes += 1

    def is_neutral(self) -> bool:
        return self.neutral

    def write_neutral(self) -> None:
        self.neutral = True
        self.outputs.append(0.0)

    def command(self, value: float) -> None:
        with self.commanding():
            self.neutral = value == 0.0
            self.outputs.append(value)


class FakeSensor(SensorDriver):
    def __init__(self, **kwargs: Any) -> None:
        self.present = True
        super().__init__('fake_sensor', device='fake1', **kwargs)

    def open_device(self) -> None:
        if not self.present:
            raise DeviceError('fake1: gone')


def actuator(context: Any, present: bool = True, start: bool = True,
             **params: Any) -> FakeActuator:
    values = {'reconnect.initial_delay': 0.5, 'reconnect.max_delay': 4.0,
              'command_timeout': 0.25, **params}
    node = FakeActuator(present, context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in values.items()])
    if start:
        node.start()
    return node


def tick(node: Any, clock: FakeClock, seconds: float) -> None:
    clock.at(seconds)
    node._supervise()


# -- an absent device ------------------------------------------------------------------------

def test_absent_device_at_start_is_an_error_on_diagnostics(context, clock):
    node = actuator(context, present=False)
    reports = Reports(node)
    assert not node.connected and node.faults == 1 and node.opens == 1
    tick(node, clock, 0.0)
    level, message, values = reports.last
    assert level == ERROR
    assert 'fake0: no answer' in message
    assert values['connected'] is False and values['faults'] == 1 and values['device'] == 'fake0'
    node.destroy_node()


def retry_times(node: Any, clock: FakeClock, seconds: float = 30.0,
                after_open: Any = None) -> list[float]:
    """Tick the supervision every 50 ms for ``seconds``; the times a retry opened the device
    (``after_open`` runs after each)."""
    attempts = []
    t = 0.0
    while t < seconds:
        t = round(t + 0.05, 2)
        before = node.opens
        tick(node, clock, t)
        if node.opens > before:
            attempts.append(t)
            if after_open is not None:
                after_open()
    return attempts


def test_absent_device_is_retried_with_growing_backoff(context, clock):
    clock.at(0.0)
    node = actuator(context, present=False)
    attempts = retry_times(node, clock)
    gaps = [round(b - a, 2) for a, b in zip([0.0] + attempts, attempts)]
    # 0.5 s, doubling, capped at reconnect.max_delay = 4 s.
    assert gaps[:6] == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    assert not node.connected and node.faults == 1 + len(attempts)
    node.destroy_node()


def test_device_appearing_connects_and_reports_ok(context, clock):
    clock.at(0.0)
    node = actuator(context, present=False)
    reports = Reports(node)
    tick(node, clock, 0.5)       # second attempt fails; next in 1 s
    node.present = True
    tick(node, clock, 1.0)
    assert not node.connected    # not due yet: the backoff holds
    tick(node, clock, 1.5)
    assert node.connected and node.opens == 3
    tick(node, clock, 3.0)
    assert reports.last[0] == OK and reports.last[2]['connected'] is True
    assert node._backoff.delay == 0.5  # reset for the next fault
    node.destroy_node()


# -- opening belongs to start, not to construction ------------------------------------------

def test_constructing_a_driver_opens_nothing_and_reports_nothing(context, clock):
    """``bringup --check`` builds every node: a driver's constructor must not touch its device
    (opening a PCA9685 rewrites every channel, opening an Arduino's port resets it)."""
    node = actuator(context, start=False)
    reports = Reports(node)
    assert node.opens == 0 and not node.connected and node.outputs == []
    tick(node, clock, 5.0)               # supervision before start: no retry, no report
    assert node.opens == 0 and reports.items == []
    node.start()
    assert node.opens == 1 and node.connected and node.confirmed
    assert node.outputs == [0.0]         # neutral before the first command
    node.destroy_node()
    assert node.closes == 1


def test_start_after_a_failed_open_waits_for_the_scheduled_retry(context, clock):
    clock.at(0.0)
    node = actuator(context, present=False)
    assert node.opens == 1 and node.faults == 1
    node.stop()
    node.start()                          # a restart does not hammer an absent device
    assert node.opens == 1
    node.destroy_node()


class FakeStream(SensorDriver):
    """A device whose open only starts a reader (a serial stream, a TCP client): it is back
    when a valid sample arrives, not when the port opened."""

    confirmed_by_open = False

    def __init__(self, **kwargs: Any) -> None:
        self.opens = 0
        super().__init__('fake_stream', device='fake2', **kwargs)

    def open_device(self) -> None:
        self.opens += 1


def stream(context: Any) -> FakeStream:
    node = FakeStream(context=context, parameter_overrides=[
        Parameter('reconnect.initial_delay', value=0.5),
        Parameter('reconnect.max_delay', value=4.0)])
    node.start()
    return node


def test_an_open_that_never_answers_backs_off_instead_of_being_back(context, clock):
    """A reader that opens and then faults with no valid sample (a QTM server that is down,
    a lidar that sends garbage) keeps doubling its delay: it was never back."""
    clock.at(0.0)
    node = stream(context)
    infos: list[str] = []
    node.get_logger = lambda: type('Log', (), {'error': lambda self, m, **k: None,
                                               'warn': lambda self, m, **k: None,
                                               'info': lambda self, m, **k: infos.append(m)})()
    assert node.connected and not node.confirmed
    node.device_fault(DeviceError('fake2: no answer'))
    attempts = [0.0, *retry_times(  # each time: opened, then nothing
        node, clock, after_open=lambda: node.device_fault(DeviceError('fake2: no answer')))]
    gaps = [round(b - a, 2) for a, b in zip(attempts, attempts[1:])]
    assert gaps[:6] == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    assert not any('device back' in m for m in infos)
    node.destroy_node()


def test_the_first_valid_sample_confirms_the_device_and_resets_the_backoff(context, clock):
    clock.at(0.0)
    node = stream(context)
    reports = Reports(node)
    node.device_fault(DeviceError('fake2: no answer'))
    tick(node, clock, 0.5)               # reopened, not yet answered
    tick(node, clock, 1.5)
    assert node.connected and not node.confirmed and node._backoff.delay == 1.0
    level, message, values = reports.last
    assert level == WARN and 'waiting' in message and values['confirmed'] is False
    clock.at(2.0)
    node.sample_received()
    assert node.confirmed and node._backoff.delay == 0.5 and node._backoff.next_ns is None
    tick(node, clock, 2.6)
    assert reports.last[0] == OK and reports.last[2]['confirmed'] is True
    node.destroy_node()


# -- a fault at run time ---------------------------------------------------------------------

def test_run_time_fault_puts_outputs_in_safe_state(context, clock):
    node = actuator(context)
    node.command(0.5)
    assert not node.is_neutral()
    node.device_fault(DeviceError('fake0: unplugged'))
    assert node.is_neutral() and node.outputs[-1] == 0.0
    assert not node.connected and node.closes == 1 and node.faults == 1
    assert node.last_fault == 'fake0: unplugged'
    node.destroy_node()


@pytest.mark.parametrize('error, logged', [
    ('fake0: unplugged', 'fake0: unplugged (fault 1; retry in 0.5 s)'),
    ('no answer from the bus', 'fake0: no answer from the bus (fault 1; retry in 0.5 s)')])
def test_the_fault_log_names_the_device_once(context, clock, error, logged):
    node = actuator(context)
    lines: list[str] = []
    node.get_logger = lambda: type('Log', (), {'error': lambda self, m, **k: lines.append(m),
                                               'warn': lambda self, m, **k: None,
                                               'info': lambda self, m, **k: None})()
    node.device_fault(DeviceError(error))
    assert lines == [logged]
    node.destroy_node()


def test_run_time_fault_is_reported_as_error(context, clock):
    node = actuator(context)
    reports = Reports(node)
    node.device_fault(DeviceError('fake0: unplugged'))
    tick(node, clock, 0.1)
    assert reports.last[0] == ERROR and 'fake0: unplugged' in reports.last[1]
    node.destroy_node()


def test_run_time_fault_is_retried_and_commands_resume(context, clock):
    clock.at(0.0)
    node = actuator(context)
    node.present = False
    node.device_fault(DeviceError('fake0: unplugged'))
    tick(node, clock, 0.5)
    assert node.opens == 2 and not node.connected
    node.present = True
    tick(node, clock, 1.5)
    assert node.connected and node.opens == 3
    node.command(0.3)
    assert node.outputs[-1] == 0.3 and not node.is_neutral()
    node.destroy_node()


def test_a_second_fault_report_while_down_is_ignored(context, clock):
    node = actuator(context)
    node.device_fault(DeviceError('fake0: unplugged'))
    node.device_fault(DeviceError('fake0: again'))
    assert node.faults == 1 and node.closes == 1 and node.last_fault == 'fake0: unplugged'
    node.destroy_node()


class LoopSensor(SensorDriver):
    """A device opened on its own loop's thread (``open_on``), as the camera and IMUs are."""

    def __init__(self, **kwargs: Any) -> None:
        self.opened_on: list[str] = []  # the thread of every open
        super().__init__('loop_sensor', device='fake2', **kwargs)
        self.loop = self.create_rate_loop(200.0, self._tick)
        self.open_on(self.loop)

    def open_device(self) -> None:
        self.opened_on.append(threading.current_thread().name)

    def _tick(self) -> None:
        if not self.connected:
            self.open_if_requested()


def test_a_device_opened_on_its_loop_reconnects_on_the_loop_thread(context, clock):
    # Opening may block (a stalled bus, a camera): the executor must never wait for it.
    node = LoopSensor(context=context, parameter_overrides=[
        Parameter('reconnect.initial_delay', value=0.5)])
    node.start()  # the first open is made in place: an absent device is reported at once
    here = threading.current_thread().name
    assert node.connected and node.opened_on == [here]
    node.device_fault(DeviceError('fake2: unplugged'))
    tick(node, clock, 1.0)  # the retry is due: asked of the loop, not made on this thread
    assert node.opened_on == [here]
    assert poll_until(lambda: node.connected, TIMEOUT, step=0.01)
    assert node.opened_on == [here, node.loop.name]
    node.destroy_node()


# -- the actuator watchdog -------------------------------------------------------------------

def test_watchdog_goes_neutral_after_command_timeout(context, clock):
    clock.at(0.0)
    node = actuator(context)
    node.command(0.5)
    tick(node, clock, 0.2)
    assert not node.is_neutral() and node.timeouts == 0
    tick(node, clock, 0.3)
    assert node.is_neutral() and node.timeouts == 1
    node.destroy_node()


def test_watchdog_neutral_is_not_repeated(context, clock):
    clock.at(0.0)
    node = actuator(context)
    node.command(0.5)
    tick(node, clock, 0.3)
    n = len(node.outputs)
    tick(node, clock, 0.6)
    tick(node, clock, 5.0)
    assert node.timeouts == 1 and len(node.outputs) == n
    node.destroy_node()


def test_watchdog_is_fed_by_commands(context, clock):
    clock.at(0.0)
    node = actuator(context)
    for i in range(1, 10):
        clock.at(0.2 * i)
        node.command(0.5)
        node._supervise()
    assert node.timeouts == 0 and not node.is_neutral()
    node.destroy_node()


def test_watchdog_count_is_reported(context, clock):
    clock.at(0.0)
    node = actuator(context)
    reports = Reports(node)
    node.command(0.5)
    tick(node, clock, 2.0)
    assert reports.last[2]['timeouts'] == 1 and reports.last[2]['neutral'] is True
    node.destroy_node()


# -- a sensor going stale --------------------------------------------------------------------

def sensor(context: Any) -> FakeSensor:
    node = FakeSensor(context=context, parameter_overrides=[
        Parameter('sample_timeout', value=1.0)])
    node.start()
    return node


def test_sensor_without_samples_warns(context, clock):
    node = sensor(context)
    reports = Reports(node)
    tick(node, clock, 0.0)
    assert reports.last[0] == WARN and reports.last[1] == 'no samples'
    node.destroy_node()


def test_sensor_with_fresh_samples_is_ok(context, clock):
    clock.at(0.0)
    node = sensor(context)
    reports = Reports(node)
    node.sample_received()
    tick(node, clock, 0.9)
    assert reports.last[0] == OK and reports.last[2]['samples'] == 1
    node.destroy_node()


def test_sensor_whose_samples_stop_warns(context, clock):
    clock.at(0.0)
    node = sensor(context)
    reports = Reports(node)
    node.sample_received()
    tick(node, clock, 1.1)
    assert node.stale
    assert reports.last[0] == WARN and reports.last[1] == 'samples stopped'
    node.destroy_node()


def test_a_faulted_sensor_is_an_error_not_a_warning(context, clock):
    node = sensor(context)
    reports = Reports(node)
    node.present = False
    node.device_fault(DeviceError('fake1: gone'))
    tick(node, clock, 0.0)
    assert reports.last[0] == ERROR
    node.destroy_node()


# -- the real topic --------------------------------------------------------------------------

def test_the_error_travels_on_the_diagnostics_topic(context, executor, spin, clock):
    node = add(executor, actuator(context, present=False))
    seen = []
    p = probe(context, executor, 'monitor')
    p.create_subscription(topics.DIAGNOSTICS.msg_type, topics.DIAGNOSTICS.name,
                          lambda m: seen.extend(m.status), topics.DIAGNOSTICS.qos)
    t = [0.0]

    def report_and_look() -> bool:
        t[0] += 1.0  # one report per call
        tick(node, clock, t[0])
        return any(s.hardware_id == 'fake_actuator' for s in seen)

    assert spin(executor, report_and_look, TIMEOUT)
    status = next(s for s in seen if s.hardware_id == 'fake_actuator')
    assert status.level == bytes([ERROR]) and 'fake0: no answer' in status.message


# -- a driver over the transport layer -------------------------------------------------------

class I2cSensor(SensorDriver):
    """A sensor checked by its identity register over the fake I2C bus."""

    WHO_AM_I = 0x75

    def __init__(self, bus: Any, **kwargs: Any) -> None:
        from enbarr_plugins.transport.i2c import I2cDevice
        self.chip = I2cDevice(bus, 0x68, bus_name='i2c-1', retries=1, retry_delay=0.0)
        super().__init__('i2c_sensor', device=self.chip.name, **kwargs)

    def open_device(self) -> None:
        if self.chip.read_u8(self.WHO_AM_I) != 0x71:
            raise DeviceError(f'{self.chip.name}: not the expected chip')

    def poll(self) -> None:
        try:
            self.chip.read_block(0x3B, 6)
        except DeviceError as err:
            self.device_fault(err)
            return
        self.sample_received()


def test_a_driver_over_the_fake_i2c_bus_faults_and_recovers(context, clock):
    from enbarr_plugins.transport.i2c import FakeI2cBus, RegisterMap
    bus = FakeI2cBus()
    clock.at(0.0)
    node = I2cSensor(bus, context=context, parameter_overrides=[
        Parameter('reconnect.initial_delay', value=0.5)])
    node.start()
    assert not node.connected and 'i2c-1 0x68: read register 0x75' in node.last_fault
    bus.attach(0x68, RegisterMap({0x75: 0x71}))
    tick(node, clock, 0.5)
    assert node.connected and node.device == 'i2c-1 0x68'
    node.poll()
    assert node.samples == 1
    bus.nack(0x68, 2)  # more NACKs than the retries cover
    node.poll()
    assert not node.connected and 'EREMOTEIO' in node.last_fault
    tick(node, clock, 1.0)
    assert node.connected
    node.poll()
    assert node.samples == 2
    node.destroy_node()


# -- the watchdog and the retry schedule as plain objects (unit tier) --------------------------
# The node tests above exercise them through a driver; these pin the boundaries on the fake
# clock with nanosecond steps, no rclpy context.

class Output:
    """An actuator output the watchdog guards; records whether the lock was held."""

    def __init__(self) -> None:
        self.neutral = False
        self.calls = 0
        self.lock_held: list[bool] = []
        self.dog = driver.CommandWatchdog(lambda: self.neutral, self.go_neutral)

    def go_neutral(self) -> None:
        self.calls += 1
        self.neutral = True
        self.lock_held.append(self.dog.lock.locked())

    def command(self) -> None:
        with self.dog.lock:
            self.neutral = False
            self.dog.fed()


def test_watchdog_timeout_is_exact_to_the_nanosecond(clock):
    out = Output()
    out.dog.set_timeout(0.25)
    assert out.dog.timeout_ns == 250_000_000
    clock.at(1.0)
    out.command()
    clock.ns += 250_000_000               # exactly the timeout: still fed
    assert out.dog.check() is False and out.calls == 0 and out.dog.timeouts == 0
    clock.ns += 1                         # one nanosecond past it: neutral
    assert out.dog.check() is True
    assert out.calls == 1 and out.dog.timeouts == 1 and out.lock_held == [True]


def test_watchdog_does_not_repeat_neutral_and_rearms_on_a_command(clock):
    out = Output()
    out.dog.set_timeout(0.1)
    clock.at(0.0)
    out.command()
    clock.at(0.5)
    assert out.dog.check() is True
    clock.at(0.6)
    assert out.dog.check() is False and out.dog.timeouts == 1  # already neutral
    out.command()
    clock.at(0.65)
    assert out.dog.check() is False and not out.neutral        # fed 0.05 s ago
    clock.at(0.75)
    assert out.dog.check() is True and out.dog.timeouts == 2 and out.calls == 2


def test_watchdog_does_not_act_on_a_neutral_output(clock):
    out = Output()
    out.neutral = True
    clock.at(100.0)                       # never fed, long past any timeout
    assert out.dog.check() is False and out.calls == 0 and out.dog.timeouts == 0


def test_watchdog_with_no_timeout_set_acts_after_any_silence(clock):
    out = Output()                        # timeout 0 until set_timeout
    clock.at(0.0)
    out.command()
    assert out.dog.check() is False       # same instant: 0 <= 0
    clock.ns += 1
    assert out.dog.check() is True


def test_backoff_doubles_up_to_the_maximum_from_the_failure_time():
    b = driver.Backoff(0.5, 3.0)
    assert b.next_ns is None and not b.due(10 * S)
    assert [b.schedule(10 * S) for _ in range(5)] == [0.5, 1.0, 2.0, 3.0, 3.0]
    assert b.next_ns == 13 * S            # the last failure at 10 s + 3.0 s
    b = driver.Backoff(0.5, 3.0)
    assert b.schedule(7 * S) == 0.5 and b.next_ns == 7 * S + S // 2
    assert not b.due(7 * S + S // 2 - 1) and b.due(7 * S + S // 2)


def test_backoff_reset_returns_to_the_first_delay_and_idles():
    b = driver.Backoff(0.25, 4.0)
    b.schedule(0)
    b.schedule(0)
    b.reset()
    assert b.next_ns is None and not b.due(100 * S)
    assert b.schedule(0) == 0.25


def test_backoff_maximum_below_initial_is_the_initial_delay():
    b = driver.Backoff(2.0, 0.5)
    assert b.maximum == 2.0
    assert [b.schedule(0) for _ in range(3)] == [2.0, 2.0, 2.0]


def test_watchdog_is_armed_before_the_first_command(clock):
    """An output that is not neutral and was never commanded goes neutral once a timeout has
    passed since the monotonic epoch (the watchdog counts from 0, not from its first feed)."""
    out = Output()
    out.dog.set_timeout(0.25)
    clock.ns = 250_000_000
    assert out.dog.check() is False
    clock.ns = 250_000_001
    assert out.dog.check() is True and out.calls == 1


def test_watchdog_timeout_in_seconds_is_exact_in_nanoseconds():
    dog = driver.CommandWatchdog(lambda: True, lambda: None)
    for seconds, ns in ((2.5, 2_500_000_000), (0.02, 20_000_000), (30.0, 30_000_000_000)):
        dog.set_timeout(seconds)
        assert dog.timeout_ns == ns


# -- command_timeout against the measured command rate ------------------------------------

def test_a_command_timeout_shorter_than_two_command_periods_is_refused_live(context, clock):
    """A timeout under the command period trips the watchdog between every two commands: the
    outputs flicker to neutral while the controller runs. Refused, with the measured period."""
    node = actuator(context)
    for i in range(20):  # 10 Hz
        clock.at(0.1 * i)
        node.command(0.5)
    result = node.set_parameters([Parameter('command_timeout', value=0.15)])[0]
    assert not result.successful
    assert 'command_timeout' in result.reason and 'period' in result.reason, result.reason
    assert '0.1 s' in result.reason, result.reason
    assert node.set_parameters([Parameter('command_timeout', value=0.3)])[0].successful
    node.destroy_node()


def test_a_start_command_timeout_too_short_for_the_commands_is_reported(context, clock):
    node = actuator(context, command_timeout=0.05)
    reports = Reports(node)
    for i in range(20):  # 10 Hz: the watchdog trips between every two commands
        clock.at(0.1 * i)
        node.command(0.5)
        node._supervise()
    clock.at(3.0)
    node._supervise()
    level, message, _ = reports.last
    assert level == WARN and 'command_timeout' in message and 'period' in message, message
    node.destroy_node()


def test_commanding_holds_the_lock_feeds_the_watchdog_and_releases_on_error(context, clock):
    """``with commanding():`` (a plain context manager on the hot path): lock held and the
    watchdog fed inside, released after, also when the command raises."""
    node = actuator(context)
    try:
        w = node.watchdog
        clock.at(5.0)
        with node.commanding():
            assert w.lock.locked() and w._last_ns == clock.ns
        assert not w.lock.locked()
        clock.at(6.0)
        with pytest.raises(RuntimeError, match='device gone'):
            with node.commanding():
                node.neutral = False
                raise RuntimeError('device gone')
        assert not w.lock.locked() and w._last_ns == clock.ns
        assert not w.check()            # fed just now: no timeout
        clock.at(6.3)                   # 0.3 s > command_timeout 0.25 s
        assert w.check() and w.timeouts == 1
    finally:
        node.destroy_node()
