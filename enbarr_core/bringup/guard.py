"""One vessel per set of node names on a ROS graph: the vessel guard of every run."""

from __future__ import annotations

from collections.abc import Sequence
import json
import logging
import os
import socket
import time

from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import String

from enbarr_interfaces import topics

from enbarr_core.framework.errors import EnbarrError
from enbarr_core.bringup.stop import STOP_POLL, StopRequest

log = logging.getLogger('enbarr.bringup')

#: How long a group watches the graph for a namesake before it builds its nodes [s]. Two
#: processes discover each other either at once or at the next periodic announcement of
#: the running one (Fast-DDS announces every 3 s by default): one period and a margin for
#: a loaded machine. A later discovery is still caught by the claims, at the cost of a late
#: stop after the nodes were built (docs/architecture.md, Safety).
DISCOVERY_WAIT = 4.0
#: Where every running group announces its node names and when it started (std_msgs/String,
#: JSON). Latched: a process that joins later still gets every claim.
CLAIM_TOPIC = topics.VESSEL_CLAIMS.name
CLAIM_QOS = topics.VESSEL_CLAIMS.qos
MAX_CLAIM_BYTES = 1 << 16
#: Claims a guard queues and keeps from before its own (a graph is not trusted to be small).
MAX_EARLY_CLAIMS = 64


class DuplicateVesselError(EnbarrError):
    """Another process on this ROS graph runs nodes with the same fully qualified names.

    ``started``: False when refused before any source started (nothing may be published then,
    not even a safe state: the topics are the other vessel's too).
    """

    def __init__(self, message: str, *, started: bool) -> None:
        self.started = started
        super().__init__(message)


class VesselGuard:
    """Refuse a second process that runs a profile's nodes on the same graph.

    Two runs of one profile in one domain would drive each other's thrusters, and a refused
    run must not disturb the running one: it may not even create a publisher on its topics
    (a second joystick publisher makes the running controller refuse the joystick as
    contested, a latched ``mode`` from a new controller switches the running guidance). So the
    guard is a hidden node of its own, made before any of the profile's nodes: it watches the
    graph for ``DISCOVERY_WAIT`` (``check_start``) and refuses (``DuplicateVesselError``, exit
    code 2) if any of the names the profile will use is already there. Only then are the
    nodes built (``check_built`` looks once more at the names they really got), and once they
    run it publishes a claim (``claim``: its names, host, pid and start time) on
    ``CLAIM_TOPIC``; every group reads the others' claims for the whole run. When two runs
    missed each other at start (slow discovery, or both started at once), both get each
    other's claim and agree without talking further: the one whose claim is later in (start
    time, host, pid) order stops; the earlier one keeps running and logs a warning. The groups
    of one split profile have disjoint names; a restarted group is a new process that never
    discovers its killed predecessor.
    """

    def __init__(self, context: Context, names: Sequence[str]) -> None:
        self.names = sorted(names)
        self.host, self.pid = socket.gethostname(), os.getpid()
        self.started_ns = 0
        # Hidden (a leading underscore): `ros2 node list` leaves it out unless asked.
        self.node = Node(f'_enbarr_guard_{self.pid}', context=context,
                         start_parameter_services=False, enable_rosout=False)
        self._pub = self.node.create_publisher(String, CLAIM_TOPIC, CLAIM_QOS)
        # Every run's claim lands in one reader: a depth of 1 (the latched writers' own)
        # kept only the newest, so of two runs claiming at once one never saw the other's.
        self._sub = self.node.create_subscription(
            String, CLAIM_TOPIC, self._on_claim,
            QoSProfile(depth=MAX_EARLY_CLAIMS, reliability=CLAIM_QOS.reliability,
                       durability=CLAIM_QOS.durability))
        self._warned: set[tuple[str, int]] = set()
        self._early: list[String] = []  # claims that came before ours: judged at our claim

    def duplicates(self, own: int = 0) -> list[str]:
        """Our names that the graph lists more than ``own`` times (``own``: ours built)."""
        seen: dict[str, int] = {}
        for name, ns in self.node.get_node_names_and_namespaces():
            fq = f'{ns.rstrip("/")}/{name}'
            seen[fq] = seen.get(fq, 0) + 1
        return [fq for fq in self.names if seen.get(fq, 0) > own]

    def check_start(self, wait: float = DISCOVERY_WAIT) -> None:
        """Watch the graph for ``wait`` s before the nodes exist; refuse on a namesake."""
        deadline = time.monotonic() + wait
        while True:
            self._refuse(self.duplicates())
            stop = StopRequest.active
            if stop is not None and stop.requested:
                raise KeyboardInterrupt  # a stop before the start: nothing to start
            if time.monotonic() >= deadline:
                break
            time.sleep(STOP_POLL)

    def check_built(self, nodes: Sequence[Node]) -> None:
        """Look once more with the names the built nodes really have (a remapped name)."""
        built = sorted(n.get_fully_qualified_name() for n in nodes)
        if built != self.names:
            self.names = built
            self._refuse(self.duplicates(own=1))

    def _refuse(self, duplicates: list[str]) -> None:
        if duplicates:
            raise DuplicateVesselError(
                f'another process on this ROS graph (ROS_DOMAIN_ID '
                f'{os.environ.get("ROS_DOMAIN_ID", "0")}) already runs '
                f'{_names(duplicates)}: refusing to start a second vessel with the same node '
                'names; stop the other run, or use another ROS_DOMAIN_ID or namespace',
                started=False)

    def claim(self) -> None:
        """Announce this run's names (latched); from now on a later namesake stops.

        A claim that arrived while the guard watched (another run that started just before
        this one but was not yet on the graph when it looked) is judged now.
        """
        self.started_ns = time.time_ns()
        self._pub.publish(String(data=json.dumps({
            'nodes': self.names, 'host': self.host, 'pid': self.pid,
            'started_ns': self.started_ns})))
        early, self._early = self._early, []
        for msg in early:
            self._on_claim(msg)

    def destroy(self) -> None:
        """Destroy the guard's node."""
        self.node.destroy_node()

    def _key(self) -> tuple[int, str, int]:
        return self.started_ns, self.host, self.pid

    def _on_claim(self, msg: String) -> None:
        if len(msg.data) > MAX_CLAIM_BYTES:
            return
        if not self.started_ns:
            if len(self._early) < MAX_EARLY_CLAIMS:
                self._early.append(msg)
            return
        try:
            claim = json.loads(msg.data)
            other = (int(claim['started_ns']), str(claim['host']), int(claim['pid']))
            names = {str(n) for n in claim['nodes']}
        except (ValueError, KeyError, TypeError):
            return  # not a claim of ours: nothing to agree on
        if other[1:] == (self.host, self.pid):
            return
        shared = sorted(names.intersection(self.names))
        if not shared:
            return
        if other < self._key():
            raise DuplicateVesselError(
                f'process {other[2]} on {other[1]} runs {_names(shared)} on this ROS graph '
                f'and started first: this later run stops (its sources were running for '
                f'{(time.time_ns() - self.started_ns) / 1e9:.1f} s)', started=True)
        if other[1:] not in self._warned:
            self._warned.add(other[1:])
            log.warning('process %d on %s started later with %s on this ROS graph: it must '
                        'stop (it will, on seeing the claim of this run)', other[2], other[1],
                        _names(shared))


def _names(names: Sequence[str]) -> str:
    shown = ', '.join(names[:5])
    return f'node(s) {shown}' + (f' and {len(names) - 5} more' if len(names) > 5 else '')
