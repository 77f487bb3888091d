"""``enbarr param`` as a user runs it: a process of its own against a node in another process.

The node tests (test/commands/test_param.py) cover every verb and error in one process; this
proves the command line itself: its own context and executor, discovery across processes, the
exit codes and one-line errors with no traceback.
"""

from __future__ import annotations

from collections.abc import Iterator
import os
import subprocess
import sys

import pytest
import yaml

from support.cli import enbarr, refused

#: A guidance node with its declared defaults, spun until stopped.
SERVER = """
import rclpy
from rclpy.executors import ExternalShutdownException
from enbarr_core.guidance.guidance_node import GuidanceNode
rclpy.init()
node = GuidanceNode(node_name='guidance')
print('up', flush=True)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
finally:
    node.destroy_node()
    rclpy.try_shutdown()
"""


@pytest.fixture
def guidance() -> Iterator[subprocess.Popen[str]]:
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    proc = subprocess.Popen([sys.executable, '-c', SERVER], env=env, text=True,
                            stdout=subprocess.PIPE, stdin=subprocess.DEVNULL)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == 'up\n'
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def param(*words: str) -> subprocess.CompletedProcess[str]:
    # --timeout: generous, discovery across processes takes up to seconds on a loaded host
    return enbarr('param', *words[:1], '--timeout', '20', *words[1:])


def test_set_get_dump_across_processes(guidance):
    result = param('set', 'guidance', 'avoidance.gamma', '0.3')
    assert (result.returncode, result.stdout) == (0, 'Set parameter successful\n'), result.stderr
    result = param('get', '/guidance', 'avoidance.gamma')
    assert (result.returncode, result.stdout) == (0, 'Double value is: 0.3\n'), result.stderr
    result = param('dump', '/guidance')
    assert result.returncode == 0, result.stderr
    assert yaml.safe_load(result.stdout)['/guidance']['ros__parameters']['avoidance'][
        'gamma'] == 0.3


def test_refused_set_exits_2_with_the_reason(guidance):
    result = param('set', 'guidance', 'path.heading', 'sideways')
    assert (result.returncode, result.stdout) == (2, '')
    assert result.stderr.startswith('Setting parameter failed: ') and 'Traceback' not in \
        result.stderr and result.stderr.count('\n') == 1, result.stderr


def test_unknown_node_is_one_line(guidance):
    line = refused(enbarr('param', 'get', '--timeout', '8', 'guidanc', 'avoidance.gamma'),
                   'param')
    assert 'did you mean /guidance?' in line, line
