"""The parameter storm of a chaos run: every parameter of every node set, valid and invalid.

``SetParameters`` calls as ``ros2 param set`` makes them, one parameter per call, all sent at
once: each parameter set to its own value (valid), to a value of the wrong type and, for a
floating-point one, to NaN (invalid). Every call is judged (``judge.judge_storm``): an invalid
value accepted fails the storm, and so does a call left unanswered after ``ANSWER_TIMEOUT``.

Many ``ros2 param set`` processes have a service client each. One client sends the storm
here, so its request and response queues must hold every call of a node: rclpy's default
service QoS keeps the last 10, and a larger burst loses the rest.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import time
from typing import Any

#: A node's calls all fit the storm client's queues (a node has tens of parameters, three
#: calls each).
STORM_DEPTH = 1000
#: The longest wait for the last answer [s]: a loaded machine answers hundreds of calls in
#: well under this; a call still unanswered then is lost, and reported.
ANSWER_TIMEOUT = 20.0
#: The longest wait for a node's parameter services and its lists [s] before the storm.
DISCOVER_TIMEOUT = 5.0


@dataclass(frozen=True)
class Call:
    """One ``SetParameters`` call of the storm."""

    node: str        # fully qualified name
    parameter: str
    value: Any
    valid: bool      # the parameter's own value (True) or a value it must refuse

    def __str__(self) -> str:
        return f'{self.node}.{self.parameter}={self.value!r}'


@dataclass(frozen=True)
class StormOutcome:
    """What the storm sent and heard: each call with its answer (None: unanswered)."""

    nodes: int
    answers: tuple[tuple[Call, bool | None], ...]   # (call, successful)
    start_ns: int
    end_ns: int


def storm(node: Any, exclude: tuple[str, ...] = (), window: float = 0.0,
          answer_timeout: float = ANSWER_TIMEOUT) -> StormOutcome:
    """Storm every node the graph shows (but ``node`` and ``exclude``) from ``node``.

    ``node`` must be spun by an executor on another thread (the futures complete there). The
    storm lasts at least ``window`` seconds; it waits for every answer up to
    ``answer_timeout``. A value accepted that must not be is set back to the node's own.
    """
    from rclpy.parameter import Parameter, parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=STORM_DEPTH,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)
    targets = [(n, ns) for n, ns in node.get_node_names_and_namespaces()
               if n != node.get_name() and n not in exclude]
    clients: dict[str, Any] = {}
    current: dict[str, dict[str, Any]] = {}
    for n, ns in targets:
        full = (ns.rstrip('/') + '/' + n) if ns else n
        client = AsyncParameterClient(node, full, qos_profile=qos)
        if not client.wait_for_services(DISCOVER_TIMEOUT):
            continue
        names = _result(client.list_parameters(), DISCOVER_TIMEOUT)
        if names is None:
            continue
        names = [p for p in names.result.names if p != 'use_sim_time']
        values = _result(client.get_parameters(names), DISCOVER_TIMEOUT)
        if values is None:
            continue
        current[full] = dict(zip(names, (parameter_value_to_python(v)
                                          for v in values.values)))
        clients[full] = client
    calls: list[Call] = []
    for full, params in current.items():
        for pname, value in params.items():
            calls.append(Call(full, pname, value, True))
            calls.append(Call(full, pname, 3.5 if isinstance(value, str) else 'chaos', False))
            if isinstance(value, float):
                calls.append(Call(full, pname, math.nan, False))
    start = time.time_ns()
    futures = [clients[c.node].set_parameters([Parameter(c.parameter, value=c.value)])
               for c in calls]
    deadline = time.monotonic() + answer_timeout
    while time.monotonic() < deadline and not all(f.done() for f in futures):
        time.sleep(0.05)
    end = max(time.time_ns(), start + int(window * 1e9))
    time.sleep(max(0.0, (end - time.time_ns()) * 1e-9))
    answers = []
    for call, fut in zip(calls, futures):
        result = fut.result() if fut.done() else None
        ok = None if result is None else bool(result.results[0].successful)
        if ok and not call.valid:
            clients[call.node].set_parameters(
                [Parameter(call.parameter, value=current[call.node][call.parameter])])
        answers.append((call, ok))
    return StormOutcome(len(clients), tuple(answers), start, end)


def _result(future: Any, timeout: float) -> Any | None:
    deadline = time.monotonic() + timeout
    while not future.done() and time.monotonic() < deadline:
        time.sleep(0.02)
    return future.result() if future.done() else None
