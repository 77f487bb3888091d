"""Node tests: the guidance node's collision avoidance (``avoidance.*``, ``obstacles`` in,
``guidance/avoidance`` out): off by default, a hold with the reason when blind, resuming when
the obstacles are fresh again, live parameters."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from std_msgs.msg import Float64
from support.nodes import param_client, set_param, TIMEOUT
from support.saucer import T0_NS

from enbarr_core.guidance.guidance import LosPath
from enbarr_core.guidance.guidance_node import msg_to_reference
from enbarr_interfaces import avoidance, topics
from enbarr_interfaces.modes import Mode
from enbarr_interfaces.obstacles import CIRCLE, Obstacle, to_cloud

from guidance.test_guidance_node import Harness

PATH = [0.0, 0.0, 5.0, 0.0]
ON = {'path.waypoints': PATH, 'avoidance.enabled': True, 'avoidance.vessel_radius': 0.1375}
BUOY = Obstacle(id=1, kind=CIRCLE, x=2.0, y=0.0, radius=0.3)


class AvoidHarness(Harness):
    """The guidance harness plus obstacles, measurement age, and what avoidance publishes."""

    def __init__(self, context: Any, executor: Any, spin: Any, **params: Any) -> None:
        super().__init__(context, executor, spin, **params)
        from support.nodes import probe
        p = probe(context, executor, 'perception')
        self.obstacles_pub = p.create_topic_publisher(topics.OBSTACLES)
        self.age_pub = p.create_topic_publisher(topics.OBSERVER_AGE)
        self.avoid: list[Any] = []
        p.create_topic_subscription(topics.GUIDANCE_AVOIDANCE, self.avoid.append)
        self.diagnostics: list[DiagnosticArray] = []
        p.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name,
                              self.diagnostics.append, topics.DIAGNOSTICS.qos)

    def obstacles(self, obstacles: list[Obstacle], stamp_ns: int) -> None:
        self.obstacles_pub.publish(to_cloud(obstacles, stamp_ns, topics.WORLD_FRAME))
        assert self.spin(self.executor, lambda: self.node._obstacles[1] == stamp_ns, TIMEOUT)

    def drive(self, eta: Any, n: int = 1) -> Any:
        """n estimates at eta; the last reference as read from the topic."""
        for _ in range(n):
            self.estimate(eta)
        return msg_to_reference(self.refs[-1])


def test_disabled_reference_is_the_laws_and_nothing_is_published(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **{'path.waypoints': PATH})
    assert not h.node.settings.avoidance.enabled     # the default keeps profiles as they were
    h.estimate([1.5, 0.05, 0.0])
    h.mode(Mode.GUIDANCE)
    h.obstacles([BUOY], h.t)                           # right ahead: would engage if on
    law = LosPath([(0.0, 0.0), (5.0, 0.0)], 0.2, 0.5, 0.1, heading='fixed')
    law.reference(np.array([1.5, 0.05, 0.0]), 0.02)
    for _ in range(5):
        ref = h.drive([1.5, 0.05, 0.0])
        expected = law.reference(np.array([1.5, 0.05, 0.0]), 0.02)
        np.testing.assert_array_equal(ref.nu_d, expected.nu_d)
        assert ref.position_mask == (False, False, True)
    spin(executor, lambda: False, 0.2)
    assert h.avoid == [] and h.node.avoidance_output is None


def test_no_obstacles_in_guidance_holds_with_the_reason(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.2, 0.1, 0.3])
    h.mode(Mode.GUIDANCE)
    ref = h.drive([0.2, 0.1, 0.3], 3)
    assert ref.position_mask == (True, True, True)
    np.testing.assert_allclose(ref.eta_d, [0.2, 0.1, 0.3])
    np.testing.assert_array_equal(ref.nu_d, [0.0, 0.0, 0.0])
    assert 'no obstacles' in h.node.blind_reason
    assert spin(executor, lambda: h.avoid, TIMEOUT)
    assert avoidance.from_msg(h.avoid[-1])['blind'] == 1.0
    assert spin(executor, lambda: any('no obstacles' in s.message
                                      for d in h.diagnostics for s in d.status), 3.0)


def test_stale_obstacles_hold_then_fresh_ones_resume(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.GUIDANCE)
    h.obstacles([BUOY], h.t)
    ref = h.drive([0.0, 0.0, 0.0])
    assert h.node.blind_reason is None
    assert ref.position_mask == (False, False, True)  # far from the buoy: the LOS reference
    # The lidar stalls: estimates go on, the obstacles' stamp stays (0.5 s staleness).
    ref = h.drive([0.1, 0.0, 0.0], 30)
    assert 'obstacles 0.6' in h.node.blind_reason
    assert ref.position_mask == (True, True, True)
    np.testing.assert_array_equal(ref.nu_d, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(ref.eta_d, [0.1, 0.0, 0.0])
    assert h.node.counts['blind'] == 1
    # Fresh again: the path is followed again (LOS: velocity and heading).
    h.obstacles([BUOY], h.t)
    ref = h.drive([0.1, 0.0, 0.0])
    assert h.node.blind_reason is None
    assert ref.position_mask == (False, False, True)
    assert ref.nu_d[0] == pytest.approx(0.2)
    assert h.node.counts['blind'] == 1


def test_hold_resumes_from_where_it_held_without_a_step(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.AUTOMATIC)                             # holds (0, 0, 0)
    h.obstacles([BUOY], h.t)
    h.drive([0.0, 0.0, 0.0])
    ref = h.drive([0.1, 0.0, 0.0], 30)                 # blind: holds where it is now
    held = ref.eta_d.copy()
    np.testing.assert_allclose(held, [0.1, 0.0, 0.0])
    h.obstacles([BUOY], h.t)
    ref = h.drive([0.1, 0.0, 0.0])
    assert h.node.blind_reason is None
    assert np.linalg.norm(ref.eta_d[:2] - held[:2]) < 0.01   # no step back to the old hold
    for _ in range(400):
        h.obstacles([BUOY], h.t)
        ref = h.drive([0.1, 0.0, 0.0], 5)
        if not h.node.avoidance_output.engaged:
            break
    np.testing.assert_array_equal(ref.eta_d, [0.0, 0.0, 0.0])  # the law's hold again


def test_pose_lost_holds_with_the_reason(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.AUTOMATIC)
    h.obstacles([BUOY], h.t)
    h.drive([0.0, 0.0, 0.0])
    h.age_pub.publish(Float64(data=0.8))
    assert spin(executor, lambda: h.node._measurement_age == 0.8, TIMEOUT)
    ref = h.drive([0.05, 0.0, 0.0])
    assert 'pose lost' in h.node.blind_reason
    np.testing.assert_array_equal(ref.nu_d, [0.0, 0.0, 0.0])


def test_avoidance_message_carries_the_obstacle_stamp_and_the_barrier(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.AUTOMATIC)
    stamp = h.t - 30_000_000
    h.obstacles([BUOY], stamp)
    h.drive([0.0, 0.0, 0.0])
    assert spin(executor, lambda: h.avoid, TIMEOUT)
    got = avoidance.from_msg(h.avoid[-1])
    assert got['obstacles_stamp_ns'] == stamp
    assert got['estimate_stamp_ns'] == h.t
    # 2 m to the centre - 0.3 buoy - 0.1375 hull - 0.2 safety - 0.2 tracking margin
    assert got['min_barrier'] == pytest.approx(2.0 - 0.3 - 0.1375 - 0.2 - 0.2)
    assert got['obstacles'] == 1 and got['blind'] == 0.0 and got['solve_time'] >= 0.0


def test_moving_obstacles_are_carried_to_the_estimates_time(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.AUTOMATIC)
    boat = Obstacle(id=2, kind=CIRCLE, x=3.0, y=0.0, radius=0.3, vx=-1.0)
    h.obstacles([boat], h.t - 200_000_000)           # scanned 0.2 s before this estimate
    h.drive([0.0, 0.0, 0.0])                          # one more estimate: 0.22 s after
    # The boat is 0.22 m nearer than scanned.
    assert h.node.avoidance_output.min_barrier == pytest.approx(
        3.0 - 0.22 - 0.3 - 0.1375 - 0.2 - 0.2)


def test_live_parameter_change_takes_effect(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.AUTOMATIC)
    h.obstacles([BUOY], h.t)
    h.drive([0.0, 0.0, 0.0])
    before = h.node.avoidance_output.min_barrier
    client = param_client(executor, spin, context, 'guidance')
    result = set_param(executor, spin, client, 'avoidance.safety_radius', 0.5)
    assert result.successful, result.reason
    h.drive([0.0, 0.0, 0.0])
    assert h.node.avoidance_output.min_barrier == pytest.approx(before - 0.3)
    assert h.node.filter.settings.safety_radius == 0.5
    # A speed limit below the path speed would slow the nominal everywhere: refused.
    result = set_param(executor, spin, client, 'avoidance.max_speed', 0.15)
    assert not result.successful and 'avoidance.max_speed' in result.reason
    # Switched off live: the law's reference again.
    assert set_param(executor, spin, client, 'avoidance.enabled', False).successful
    n = len(h.avoid)
    ref = h.drive([0.0, 0.0, 0.0])
    np.testing.assert_allclose(ref.eta_d, [0.0, 0.0, 0.0])
    spin(executor, lambda: False, 0.2)
    assert len(h.avoid) == n


def test_enabling_without_a_hull_radius_is_refused(context, executor, spin):
    from enbarr_core.framework.errors import ConfigurationError
    from enbarr_core.guidance.guidance_node import GuidanceNode
    from support.saucer import overrides
    with pytest.raises(ConfigurationError, match='avoidance.vessel_radius'):
        GuidanceNode(node_name='guidance', context=context, parameter_overrides=overrides(
            {'avoidance.enabled': True}))


def test_an_unknown_level_is_refused_and_the_force_level_skips_the_speed_check(context):
    """avoidance.level names where the barrier functions act; at the force level the
    guidance's speed limit filters nothing, so a path speed above it is no error."""
    from enbarr_core.framework.errors import ConfigurationError
    from enbarr_core.guidance.guidance_node import GuidanceNode
    from support.saucer import overrides
    with pytest.raises(ConfigurationError, match='avoidance.level: expected one of guidance, '
                                                 "force, got 'thrust'"):
        GuidanceNode(node_name='guidance', context=context, parameter_overrides=overrides(
            {**ON, 'avoidance.level': 'thrust'}))
    fast = {**ON, 'path.speed': 0.5}
    with pytest.raises(ConfigurationError, match='avoidance.max_speed'):
        GuidanceNode(node_name='guidance', context=context,
                     parameter_overrides=overrides(fast))
    node = GuidanceNode(node_name='guidance', context=context, parameter_overrides=overrides(
        {**fast, 'avoidance.level': 'force'}))
    assert node.settings.avoidance.level == 'force' and not node.settings.avoidance.filters
    node.destroy_node()


def test_manual_stays_manual_with_avoidance_on(context, executor, spin):
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.0, 0.0, 0.0])
    h.estimate([0.0, 0.0, 0.0])
    assert not h.refs and h.node.mode is Mode.MANUAL and h.node.blind_reason is None
    assert T0_NS < h.t


def test_a_malformed_obstacles_message_is_counted_and_leaves_them_stale(context, executor,
                                                                        spin):
    """A point cloud without the obstacle fields (another tool's cloud on the topic) is
    refused with a warning and counted; the last good obstacles age on, so the vessel holds
    once they are stale rather than trusting an empty sea."""
    h = AvoidHarness(context, executor, spin, **ON)
    h.estimate([0.0, 0.0, 0.0])
    h.mode(Mode.GUIDANCE)
    h.obstacles([BUOY], h.t)
    h.drive([0.0, 0.0, 0.0])
    good = h.node._obstacles
    bad = to_cloud([BUOY], h.t, topics.WORLD_FRAME)
    bad.fields = [f for f in bad.fields if f.name != 'radius']
    h.obstacles_pub.publish(bad)
    assert spin(executor, lambda: h.node.counts['obstacles_refused'] == 1, TIMEOUT)
    assert h.node._obstacles is good
    ref = h.drive([0.0, 0.0, 0.0], 30)       # 0.6 s on: the good ones are stale now
    assert 'obstacles 0.6' in h.node.blind_reason
    np.testing.assert_array_equal(ref.nu_d, [0.0, 0.0, 0.0])
