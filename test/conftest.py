"""Shared test setup: keep ROS traffic on this machine, in a private domain, and give node
tests a private rclpy context and a bounded spin helper.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator

# Before anything imports rclpy: never leave the machine, never meet another run.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
os.environ.pop('ROS_LOCALHOST_ONLY', None)
sys.path.insert(0, os.path.dirname(__file__))  # shared test helpers: the support package

import itertools  # noqa: E402

import pytest  # noqa: E402

_domains = itertools.count(int(os.environ['ROS_DOMAIN_ID']))
# Test runs side by side on one machine keep apart with ENBARR_TEST_DOMAINS=first-last.
_first, _, _last = os.environ.get('ENBARR_TEST_DOMAINS', '1-100').partition('-')
_DOMAIN_FIRST, _DOMAIN_COUNT = int(_first), int(_last) - int(_first) + 1


@pytest.fixture(autouse=True)
def private_domain(monkeypatch: pytest.MonkeyPatch) -> str:
    """A fresh ROS_DOMAIN_ID (1..100) for every test and the processes it starts: a test
    that SIGKILLs a run leaves DDS participants (and shared-memory ports) behind until their
    leases expire, and the next test must not meet them.
    """
    domain = str(_DOMAIN_FIRST + next(_domains) % _DOMAIN_COUNT)
    monkeypatch.setenv('ROS_DOMAIN_ID', domain)
    return domain


@pytest.fixture
def context() -> Iterator[object]:
    """A private, initialized rclpy Context, shut down after the test."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.fixture
def executor(context: object) -> Iterator[object]:
    from rclpy.executors import SingleThreadedExecutor
    ex = SingleThreadedExecutor(context=context)
    try:
        yield ex
    finally:
        for node in list(ex.get_nodes()):
            ex.remove_node(node)
            node.destroy_node()
        ex.shutdown()


def spin_until(executor: object, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
    """Spin ``executor`` until ``condition()`` holds or ``timeout`` [s] passes (never a fixed
    sleep: cross-process discovery alone can take 2.5 s).
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        executor.spin_once(timeout_sec=0.05)
    return condition()


@pytest.fixture
def spin() -> Callable[..., bool]:
    return spin_until
