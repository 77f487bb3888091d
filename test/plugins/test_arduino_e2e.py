"""End to end: the arduino_pwm driver in its own process, paused and killed, against the
board's firmware (host build) on a pty; the board must go neutral on its own each time.
"""

from __future__ import annotations

from pathlib import Path
import signal
import subprocess
import sys
from typing import Any

import pytest

from enbarr_plugins.arduino.emulator import ArduinoEmulator
from support.waiting import poll_until

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
node.start()
source.create_timer(0.02, lambda: pub.publish(duty_msg([8.2, 9.4] * 3)))
ex = SingleThreadedExecutor()
ex.add_node(node)
ex.add_node(source)
print('spinning', flush=True)
ex.spin()
"""


def wait(condition, timeout: float = 30.0) -> bool:
    return poll_until(condition, timeout, step=0.02)


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


PROFILE = """
include: [{root}/params/saucer_sim.yaml]
nodes:
  arduino_emulator:
    plugin: arduino_emulator
  arduino:
    plugin: arduino_pwm
    parameters: {{port: emulated, boot_wait: 0.5}}
"""


def read_bag(path: Path) -> dict[str, list[tuple[int, Any]]]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores
    out: dict[str, list[tuple[int, Any]]] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out


def test_saucer_flies_through_the_emulated_board(tmp_path):
    # The Saucer's simulated run with the real driver against the emulated board in place
    # of sim_arduino: the duties the chain commands are the duties the board outputs (read
    # back from the bag), and the vessel goes ahead as the scripted joystick says.
    from support.cli import enbarr
    profile = tmp_path / 'saucer_emulated.yaml'
    profile.write_text(PROFILE.format(root=ROOT))
    bag = tmp_path / 'bag'
    result = enbarr('bringup', '--profile', str(profile), '--duration', '8', '--output',
                    str(bag), '--record-topic', '/pwm/duty_cycle', '--record-topic',
                    '/emulator/arduino', '--record-topic', '/sim/odometry', cwd=ROOT,
                    timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    msgs = read_bag(bag)
    commanded = [tuple(round(d, 2) for d in m.data) for _, m in msgs['/pwm/duty_cycle']]
    outputs = [m for _, m in msgs['/emulator/arduino']]
    assert len(commanded) > 100 and len(outputs) > 100
    assert list(outputs[0].name) == [f'{a}/{k}' for a in ('az_bow', 'az_port_aft',
                                                          'az_stbd_aft')
                                     for k in ('motor', 'servo')]
    seen = {tuple(round(d, 2) for d in m.position) for m in outputs}
    # Every output is a commanded duty (or the neutral start); the board outputs most commands
    # (one sampled per 20 ms PWM period: a command replaced within it never shows).
    assert seen <= set(commanded) | {tuple(NEUTRAL)}, seen - set(commanded)
    assert len(set(commanded) & seen) >= 0.5 * len(set(commanded))
    xs = [m.pose.pose.position.x for _, m in msgs['/sim/odometry']]
    assert max(xs) > 0.2, max(xs)  # 'sticks 0.6 ahead' for the first 4 s
