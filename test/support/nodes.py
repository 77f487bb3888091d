"""Helpers shared by the node tests: add a node to an executor, a probe node, parameter
clients, and waiting on futures.
"""

from __future__ import annotations

from typing import Any

from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

from enbarr_core.framework.node import EnbarrNode
from enbarr_interfaces import convert

TIMEOUT = 10.0  # [s] every spin-until; never a bound on how fast anything must be


def add(executor: Any, node: Any) -> Any:
    """Hand ``node`` to the executor (which destroys it at teardown) and return it."""
    executor.add_node(node)
    return node


def probe(context: Any, executor: Any, name: str = 'probe') -> EnbarrNode:
    """A helper node in the test's context, to publish and listen as other nodes would."""
    return add(executor, EnbarrNode(name, context=context))


def call(executor: Any, future: Any) -> Any:
    executor.spin_until_future_complete(future, timeout_sec=TIMEOUT)
    assert future.done(), 'no answer from the parameter service'
    return future.result()


def param_client(executor: Any, spin: Any, context: Any, target: str) -> AsyncParameterClient:
    caller = probe(context, executor, 'ros2_param')
    client = AsyncParameterClient(caller, target)
    assert spin(executor, client.services_are_ready, TIMEOUT), 'parameter services not found'
    return client


def get_param(executor: Any, spin: Any, client: AsyncParameterClient, name: str) -> Any:
    response = call(executor, client.get_parameters([name]))
    return convert.parameter_value_to_python(response.values[0])


def set_param(executor: Any, spin: Any, client: AsyncParameterClient, name: str,
              value: Any) -> Any:
    response = call(executor, client.set_parameters([Parameter(name, value=value)]))
    assert len(response.results) == 1
    return response.results[0]
