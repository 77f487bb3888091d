"""The QoS a recorder asks for and what it writes down of the publishers' offers, as rosbag2.

``ros2 bag record`` subscribes to each topic with a profile adapted to what its publishers
offer (rosbag2_transport, ``Rosbag2QoS::adapt_request_to_offers``): reliable when every
publisher is reliable, transient local when every publisher is (so that a latched message
published before the recorder started is still delivered), else best effort / volatile, which
matches any publisher. It stores the offered profiles of each topic in the bag
(``offered_qos_profiles`` of ``metadata.yaml`` and of the MCAP channel), a YAML list in the
encoding of bag version 9 (policies as rmw's names: ``keep_last``, ``reliable``,
``transient_local``, ``automatic``; durations as ``{sec, nsec}``), so that ``ros2 bag play``
offers them again. Pure: no rclpy here; the node turns its ``QoSProfile`` objects into
``Qos``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import yaml

#: rmw's infinite duration (RMW_DURATION_INFINITE) [ns], as rclpy reports it.
INFINITE_NS = 2 ** 63 - 1


@dataclass(frozen=True)
class Qos:
    """One QoS profile as rmw names its policies (what the graph reports of a publisher)."""

    history: str = 'keep_last'        # keep_last, keep_all, system_default, unknown
    depth: int = 10
    reliability: str = 'reliable'     # reliable, best_effort, system_default, unknown
    durability: str = 'volatile'      # volatile, transient_local, system_default, unknown
    deadline_ns: int = 0              # 0: the rmw default (none)
    lifespan_ns: int = 0
    liveliness: str = 'system_default'  # automatic, manual_by_topic, system_default
    liveliness_lease_ns: int = 0
    avoid_ros_namespace_conventions: bool = False

    @property
    def reliable(self) -> bool:
        """Whether the publisher resends what is lost."""
        return self.reliability == 'reliable'

    @property
    def transient_local(self) -> bool:
        """Whether the publisher keeps its last messages for late subscribers (latched)."""
        return self.durability == 'transient_local'


#: What the recorder offers again for the topics it writes itself (tf2's broadcasters' QoS).
TF_STATIC_QOS = Qos(depth=1, reliability='reliable', durability='transient_local')
TF_QOS = Qos(depth=100, reliability='reliable', durability='volatile')


@dataclass(frozen=True)
class Request:
    """What a recorder asks of a topic: reliable or best effort, transient local or volatile."""

    reliable: bool
    transient_local: bool


def adapt_request(offers: Sequence[Qos]) -> Request:
    """Return the request that matches every publisher and loses least (rosbag2's rule).

    No publisher known: best effort and volatile, which every later publisher matches.
    """
    if not offers:
        return Request(reliable=False, transient_local=False)
    return Request(reliable=all(q.reliable for q in offers),
                   transient_local=all(q.transient_local for q in offers))


def _duration(ns: int) -> dict[str, int]:
    return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}


def offered_qos_yaml(offers: Sequence[Qos]) -> str:
    """``offered_qos_profiles`` as rosbag2 writes it (bag version 9); '' for no offers."""
    if not offers:
        return ''
    return yaml.safe_dump([{
        'history': q.history, 'depth': q.depth, 'reliability': q.reliability,
        'durability': q.durability, 'deadline': _duration(q.deadline_ns),
        'lifespan': _duration(q.lifespan_ns), 'liveliness': q.liveliness,
        'liveliness_lease_duration': _duration(q.liveliness_lease_ns),
        'avoid_ros_namespace_conventions': q.avoid_ros_namespace_conventions,
    } for q in offers], default_flow_style=False, sort_keys=False)
