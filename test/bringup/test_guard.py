"""The vessel guard: a refused run touches nothing of the running one, and two runs that
missed each other at start agree on which one stops.
"""

from __future__ import annotations

import json
import logging

import pytest
from std_msgs.msg import String
from support.nodes import add

from enbarr_core.bringup.guard import CLAIM_QOS, CLAIM_TOPIC, DuplicateVesselError, VesselGuard
from enbarr_core.framework.node import EnbarrNode


@pytest.fixture
def guard(context, executor) -> VesselGuard:
    g = VesselGuard(context, ['/imu', '/control_loop'])
    add(executor, g.node)
    g.check_start(wait=0.0)  # nothing else runs in this private domain
    g.claim()
    return g


def claim(g: VesselGuard, dt_ns: int, nodes=('/imu',), pid: int = 1, host: str = 'other'):
    return String(data=json.dumps({'nodes': list(nodes), 'host': host, 'pid': pid,
                                   'started_ns': g.started_ns + dt_ns}))


def test_an_earlier_claim_on_our_names_stops_this_run(guard: VesselGuard) -> None:
    with pytest.raises(DuplicateVesselError) as info:
        guard._on_claim(claim(guard, -1))
    assert info.value.started and 'started first' in str(info.value)
    assert '/imu' in str(info.value)


def test_a_later_claim_is_warned_about_once(guard: VesselGuard, caplog) -> None:
    with caplog.at_level(logging.WARNING, 'enbarr.bringup'):
        guard._on_claim(claim(guard, +1))
        guard._on_claim(claim(guard, +1))
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and 'must stop' in warned[0], warned


def test_equal_start_times_are_ordered_by_host_then_pid(guard: VesselGuard) -> None:
    guard._on_claim(claim(guard, 0, host=guard.host, pid=guard.pid + 1))  # later: no stop
    with pytest.raises(DuplicateVesselError):
        guard._on_claim(claim(guard, 0, host=guard.host, pid=guard.pid - 1))


@pytest.mark.parametrize('msg', [
    'not json', '{}', json.dumps({'nodes': 5, 'host': 'h', 'pid': 1, 'started_ns': 0}),
    'x' * 100_000])
def test_garbage_on_the_claim_topic_is_ignored(guard: VesselGuard, msg: str) -> None:
    guard._on_claim(String(data=msg))


def test_claims_on_other_names_or_our_own_are_ignored(guard: VesselGuard) -> None:
    guard._on_claim(claim(guard, -1, nodes=('/thruster_control',)))  # a sibling group
    guard._on_claim(claim(guard, -1, host=guard.host, pid=guard.pid))  # our own claim


def test_the_claim_is_published_latched(guard: VesselGuard, context, executor, spin) -> None:
    got: list[str] = []
    late = add(executor, EnbarrNode('late', context=context))
    late.create_subscription(String, CLAIM_TOPIC, lambda m: got.append(m.data), CLAIM_QOS)
    assert spin(executor, lambda: bool(got))
    assert json.loads(got[0])['nodes'] == ['/control_loop', '/imu']


def test_a_namesake_already_on_the_graph_refuses_before_anything_is_built(context,
                                                                          executor) -> None:
    """The guard looks before the profile's nodes exist: a refused run has created no
    publisher on the running vessel's topics (its joystick publisher alone would make the
    running controller refuse the joystick as contested)."""
    add(executor, EnbarrNode('imu', context=context))          # the running vessel's node
    g = VesselGuard(context, ['/control_loop', '/imu'])
    try:
        with pytest.raises(DuplicateVesselError) as info:
            g.check_start(wait=0.0)
        assert not info.value.started and '/imu' in str(info.value)
        assert '/control_loop' not in str(info.value)
    finally:
        g.destroy()


def test_no_namesake_passes_and_the_names_it_watches_are_the_profiles(context) -> None:
    g = VesselGuard(context, ['/vessel/imu', '/control_loop'])
    try:
        g.check_start(wait=0.0)
        assert g.names == ['/control_loop', '/vessel/imu'] and g.started_ns == 0
    finally:
        g.destroy()


def test_built_nodes_under_other_names_are_looked_for_once_more(context, executor) -> None:
    """A node renamed by a remap is not where the profile said: the guard checks the names
    the nodes really got, counting our own once."""
    g = VesselGuard(context, ['/imu'])
    try:
        g.check_start(wait=0.0)
        ours = [add(executor, EnbarrNode('imu_renamed', context=context))]
        g.check_built(ours)                                        # alone on the graph: fine
        add(executor, EnbarrNode('imu_renamed', context=context))  # a namesake appears
        g.names = ['/imu']
        with pytest.raises(DuplicateVesselError):
            g.check_built(ours)
    finally:
        g.destroy()


def test_node_names_are_formed_as_rclpy_forms_them(context) -> None:
    """The guard watches names computed from the profile before building: they must be the
    names the built nodes get."""
    from enbarr_core.bringup.compose import node_names
    from enbarr_core.bringup.profile import NodeSpec

    class Prof:
        nodes = [NodeSpec(name='imu', plugin='x'), NodeSpec(name='a', plugin='x',
                                                              namespace='vessel'),
                 NodeSpec(name='b', plugin='x', namespace='/deep/ns/')]
    built = [EnbarrNode('imu', context=context),
             EnbarrNode('a', namespace='vessel', context=context),
             EnbarrNode('b', namespace='/deep/ns', context=context)]
    try:
        assert node_names(Prof()) == sorted(n.get_fully_qualified_name() for n in built)
    finally:
        for n in built:
            n.destroy_node()


def _two_guards(context, executor) -> tuple[VesselGuard, VesselGuard]:
    first = VesselGuard(context, ['/imu'])
    second = VesselGuard(context, ['/imu'])
    second.pid = first.pid + 1  # another process, as far as the claims say
    for g in (first, second):
        add(executor, g.node)
    return first, second


def test_two_runs_claiming_at_once_both_see_the_other_claim(context, executor, spin) -> None:
    """Both claims land in every guard's reader before it spins: the earlier claim must not
    be overwritten by the later one (a reader of depth 1 kept only the newest)."""
    first, second = _two_guards(context, executor)
    first.claim()
    second.started_ns = 0
    second.claim()
    second.started_ns = first.started_ns + 1  # certainly later
    with pytest.raises(DuplicateVesselError, match='started first: this later run stops'):
        spin(executor, lambda: False, 3.0)


def test_a_claim_that_came_while_the_guard_watched_is_judged_at_its_own_claim(
        context, executor, spin) -> None:
    first, second = _two_guards(context, executor)
    first.claim()
    assert spin(executor, lambda: bool(second._early), 5.0)  # before our claim: kept
    with pytest.raises(DuplicateVesselError, match='started first'):
        second.claim()
