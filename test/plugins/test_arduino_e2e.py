"""End to end: the arduino_pwm driver in its own process, paused and killed, against the
board's firmware (host build) on a pty; the board must go neutral on its own each time.
"""

from __future__ import annotations

from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest

from enbarr_plugins.arduino.emulator import ArduinoEmulator

pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parents[2]
GOOD = [8.2, 9.4] * 3
NEUTRAL = [6.85] * 6

DRIVER = """
import sys
sys.path.insert(0, 'test')
import rclpy
from rclpy.executors import SingleThreadedExecutor
from support.saucer import duty_msg, overrides
from enbarr_core.framework.node import EnbarrNode
from enbarr_interfaces import topics
from enbarr_interfaces.links import LinkBus
from enbarr_plugins.arduino.link import ArduinoPwmNode

rclpy.init()
node = ArduinoPwmNode('arduino', parameter_overrides=overrides(
    {'port': sys.argv[1], 'command_timeout': 10.0, 'boot_wait': 0.3}))
source = EnbarrNode('pwm')
pub = source.create_topic_publisher(topics.PWM_DUTY)
LinkBus.of(node.context).connect()
source.create_timer(0.02, lambda: pub.publish(duty_msg([8.2, 9.4] * 3)))
ex = SingleThreadedExecutor()
ex.add_node(node)
ex.add_node(source)
print('spinning', flush=True)
ex.spin()
"""


def wait(condition, timeout: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def test_board_goes_neutral_when_the_driver_process_is_paused_or_killed():
    board = ArduinoEmulator()
    proc = None
    try:
        path = board.start()
        proc = subprocess.Popen([sys.executable, '-c', DRIVER, path], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert wait(lambda: board.duties() == pytest.approx(GOOD)), board.counters()
        proc.send_signal(signal.SIGSTOP)  # paused: nothing is sent any more
        assert wait(lambda: board.neutral, 10.0)
        assert board.counters()['watchdog_trips'] == 1
        proc.send_signal(signal.SIGCONT)  # back: the duties return
        assert wait(lambda: board.duties() == pytest.approx(GOOD)), board.counters()
        proc.kill()  # killed: no last word
        proc.wait(timeout=10)
        assert wait(lambda: board.neutral, 10.0)
        assert board.counters()['watchdog_trips'] == 2
        assert board.duties() == NEUTRAL
    finally:
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGCONT)
            proc.kill()
            proc.wait(timeout=10)
        board.stop()
