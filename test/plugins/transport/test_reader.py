"""DeviceThread: a driver's device thread hands its failure to the supervision timer."""

from __future__ import annotations

import threading
import time

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.transport.reader import DeviceThread

TIMEOUT = 10.0


def failure_of(reader: DeviceThread) -> DeviceError | None:
    """The failure, as the supervision timer takes it: polled, for at most TIMEOUT."""
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        err = reader.failure()
        if err is not None:
            return err
        time.sleep(0.01)
    return None


def test_a_device_error_is_kept_until_taken_once():
    reader = DeviceThread('x_reader')

    def fails() -> None:
        assert threading.current_thread().name == 'x_reader'
        raise DeviceError('/dev/ttyUSB0: read failed')
    reader.start('/dev/ttyUSB0', fails)
    err = failure_of(reader)
    assert isinstance(err, DeviceError) and str(err) == '/dev/ttyUSB0: read failed'
    assert reader.failure() is None


def test_a_bug_is_a_device_error_naming_the_device():
    reader = DeviceThread('x_reader')
    reader.start('tcp://qtm:22223', lambda n: [][n], 3)
    assert str(failure_of(reader)) == ("tcp://qtm:22223: x_reader failed: "
                                     "IndexError('list index out of range')")


def test_stop_ends_the_loop_and_keeps_no_failure():
    reader = DeviceThread('x_reader')
    laps: list[int] = []

    def loop() -> None:
        while not reader.wait(0.01):
            laps.append(1)
        raise DeviceError('closed under it')   # what a port closed by stop() raises
    reader.start('/dev/ttyUSB0', loop)
    reader.stop(TIMEOUT)
    assert reader.stopping and reader.failure() is None
    reader.start('/dev/ttyUSB0', lambda: None)  # started again: no longer stopping
    assert not reader.stopping
    reader.stop(TIMEOUT)


def test_stop_from_the_thread_itself_does_not_wait_for_itself():
    reader = DeviceThread('x_reader')
    done = threading.Event()

    def stops_itself() -> None:
        reader.stop(TIMEOUT)
        done.set()
    reader.start('/dev/ttyUSB0', stops_itself)
    assert done.wait(TIMEOUT)
