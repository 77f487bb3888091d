"""Node tests: collision avoidance at the force level (``avoidance.level`` force): the DP
control node filters its force outside manual only, brakes with a reason when no force keeps
the obstacles out, reports stale obstacles while the guidance node holds, and checks its
parameters. The guidance node then passes its law's reference through unfiltered.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from support.nodes import TIMEOUT, param_client, set_param
from support.saucer import CROSS, DpHarness, joy_msg, node_parameters, SQUARE, TRIANGLE

from enbarr_core.control.dp_control_node import DpControlNode
from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.framework.health import DEGRADED
from enbarr_core.guidance.guidance_node import msg_to_reference
from enbarr_interfaces import avoidance, topics
from enbarr_interfaces.modes import Mode
from enbarr_interfaces.obstacles import CIRCLE, Obstacle, to_cloud

# Force level on in both nodes, as a profile's common parameters give it.
FORCE = {'avoidance.enabled': True, 'avoidance.level': 'force', 'avoidance.vessel_radius': 0.15,
         'avoidance.safety_radius': 0.2}
PSI = 0.4
AHEAD = np.array([math.cos(PSI), math.sin(PSI)])
HOLD = np.array([0.0, 0.0, PSI])
BRAKE_RATE = 5.0   # force_cbf's brake: tau_xy = -5 M nu_xy, clipped to the box [1/s]


class ForceHarness(DpHarness):
    """The DP harness with the force level on, an obstacles publisher and what the controller
    says about its filter."""

    def __init__(self, context: Any, executor: Any, spin: Any,
                 extra: dict[str, Any] | None = None,
                 guidance_extra: dict[str, Any] | None = None) -> None:
        # No gain ramp: the integral a bumpless entry sets is cut to its limit at once, so
        # the controller pulls at full force from the second estimate on.
        super().__init__(context, executor, spin,
                         {**FORCE, 'gain_ramp_time': 0.0, **(extra or {})},
                         {**FORCE, **(guidance_extra or {})})
        self.obstacles_pub = self.probe.create_topic_publisher(topics.OBSTACLES)
        self.status: list[Any] = []
        self.probe.create_topic_subscription(topics.CONTROL_AVOIDANCE, self.status.append)

    def obstacles(self, obstacles: list[Obstacle]) -> None:
        """Publish ``obstacles`` stamped with the last estimate; wait until both nodes have
        them."""
        stamp = self.t_odom
        self.obstacles_pub.publish(to_cloud(obstacles, stamp, topics.WORLD_FRAME))
        assert self.spin(self.executor, lambda: self.node._obstacles[1] == stamp
                         and self.guidance._obstacles[1] == stamp, TIMEOUT)


def buoy_at(distance: float, radius: float = 0.05) -> Obstacle:
    """A buoy ``distance`` [m] ahead of the vessel at HOLD - 0.5 m AHEAD, centre to centre."""
    x, y = (-0.5 + distance) * AHEAD
    return Obstacle(id=1, kind=CIRCLE, x=float(x), y=float(y), radius=radius)


def to_automatic_at_hold(h: ForceHarness) -> None:
    """Zero sticks, an estimate at HOLD, triangle: automatic holds HOLD."""
    h.estimate(HOLD)
    h.joy(joy_msg(0.0, 0.0, 0.0))
    h.joy(joy_msg(0.0, 0.0, 0.0, pressed=(TRIANGLE,)))
    h.wait_mode('automatic')


def behind_hold(h: ForceHarness, u: float, n: int = 3) -> None:
    """n estimates 0.5 m short of HOLD, moving ahead at ``u``: the hold pulls the vessel on."""
    eta = np.concatenate((HOLD[:2] - 0.5 * AHEAD, [PSI]))
    for _ in range(n):
        h.estimate(eta, nu=(u, 0.0, 0.0))


def test_the_force_is_filtered_outside_manual_and_the_sticks_never(context, executor, spin):
    h = ForceHarness(context, executor, spin)
    assert h.node.force_filter is not None
    to_automatic_at_hold(h)
    h.obstacles([buoy_at(5.0)])               # far: the controller's force goes out as it is
    behind_hold(h, 0.1)
    free = h.taus[-1].copy()
    assert free[0] > 1.0 and not h.node.force_output.engaged   # pulled ahead, to the hold
    h.obstacles([buoy_at(0.45)])              # in between: 5 cm outside the safety zone
    behind_hold(h, 0.1, 1)
    assert h.node.force_output.engaged
    assert h.taus[-1][0] < 0.0                # the pull ahead became a stop
    status = avoidance.from_msg(h.status[-1])
    assert status['engaged'] == 1.0 and status['obstacles'] == 1
    assert status['min_barrier'] == pytest.approx(0.05, abs=1e-6)
    # Manual: the sticks full ahead, into the buoy, are the force as they are.
    h.joy(joy_msg(1.0, 0.0, 0.0, pressed=(CROSS,)))
    h.wait_mode('manual')
    h.joy(joy_msg(1.0, 0.0, 0.0))
    manual = np.array(node_parameters('dp_control')['manual_tau_max']) * [1.0, 0.0, 0.0]
    np.testing.assert_allclose(h.taus[-1], manual, rtol=0.0, atol=1e-12)
    engaged = h.node.force_counts['engaged']
    behind_hold(h, 0.1)                       # estimates in manual: no force, no filter
    assert h.node.force_counts['engaged'] == engaged
    np.testing.assert_allclose(h.taus[-1], manual, rtol=0.0, atol=1e-12)


def test_no_force_keeping_the_buoy_out_brakes_with_the_reason(context, executor, spin):
    h = ForceHarness(context, executor, spin)
    to_automatic_at_hold(h)
    h.obstacles([buoy_at(0.41)])              # 1 cm outside the zone, closing at 0.6 m/s:
    behind_hold(h, 0.6, 1)                    # 2 N astern cannot stop it in time
    out = h.node.force_output
    assert out.infeasible and out.reason == 'infeasible: braking'
    # The brake: -5 M nu in surge, clipped to the 2 N box; the yaw the controller's.
    m = node_parameters('dp_control')['vessel.inertia'][0]
    assert h.taus[-1][0] == pytest.approx(max(-BRAKE_RATE * m * 0.6, -2.0))
    assert h.taus[-1][1] == pytest.approx(0.0, abs=1e-12)
    assert h.node.force_counts['infeasible'] == 1
    assert avoidance.from_msg(h.status[-1])['infeasible'] == 1.0
    level, message, values = h.node.diagnostic_status()
    assert level == DEGRADED and 'force-level avoidance infeasible: braking' in message
    assert values['force_avoidance_infeasible'] == 1
    level, _, _ = h.node.diagnostic_status()  # a window without an infeasible step: ok again
    assert level != DEGRADED


def test_the_guidance_passes_its_reference_and_holds_on_stale_obstacles(context, executor,
                                                                        spin):
    """Level force: the guidance filters nothing (the line-of-sight reference runs through
    the buoy), but stale obstacles still stop and hold; the controller says so too."""
    path = {'path.waypoints': [0.0, 0.0, 5.0, 0.0]}
    h = ForceHarness(context, executor, spin, guidance_extra=path)
    h.estimate([0.0, 0.0, 0.0])
    h.joy(joy_msg(0.0, 0.0, 0.0))
    h.joy(joy_msg(0.0, 0.0, 0.0, pressed=(SQUARE,)))
    h.wait_mode('guidance')
    h.obstacles([Obstacle(id=1, kind=CIRCLE, x=0.6, y=0.0, radius=0.05)])   # on the path
    h.estimate([0.0, 0.0, 0.0], nu=(0.2, 0.0, 0.0))
    ref = msg_to_reference(h.refs[-1])
    assert ref.position_mask == (False, False, True)   # the law's reference, not filtered
    assert ref.nu_d[0] == pytest.approx(0.2)
    assert h.guidance.avoidance_output is None and h.guidance.blind_reason is None
    assert h.node.force_output.engaged                  # the controller's filter acts
    # The lidar stalls: past avoidance.staleness (0.5 s) the guidance holds, with the reason.
    for _ in range(30):
        h.estimate([0.0, 0.0, 0.0])
    ref = msg_to_reference(h.refs[-1])
    assert ref.position_mask == (True, True, True)
    np.testing.assert_array_equal(ref.nu_d, [0.0, 0.0, 0.0])
    assert 'obstacles 0.6' in h.guidance.blind_reason
    assert h.node.force_counts['stale'] > 0
    level, message, _ = h.node.diagnostic_status()
    assert level == DEGRADED and 'obstacles 0.6' in message


@pytest.mark.parametrize('change, match', [
    ({'avoidance.level': 'sideways'}, 'avoidance.level: expected one of guidance, force'),
    ({'avoidance.force_max': [2.5, 2.0]}, r'avoidance.force_max\[0\]: 2.5 N is more than'),
    ({'avoidance.force_max': [2.0]}, 'avoidance.force_max: expected'),
    ({'avoidance.vessel_radius': 0.0}, 'avoidance.vessel_radius: give the hull radius'),
])
def test_force_level_parameters_are_checked_naming_the_parameter(context, change, match):
    given = {**node_parameters('dp_control'), **FORCE, **change}
    with pytest.raises(ConfigurationError, match=match) as info:
        DpControlNode(node_name='dp_control', context=context,
                      parameter_overrides=[Parameter(k, value=v) for k, v in given.items()])
    assert 'Traceback' not in str(info.value)


def test_force_level_gains_are_live_and_ranged_the_level_is_not(context, executor, spin):
    h = ForceHarness(context, executor, spin)
    f = h.node.force_filter
    client = param_client(executor, spin, context, 'dp_control')
    assert set_param(executor, spin, client, 'avoidance.a1', 0.5).successful
    assert h.node.force_filter is f and f.settings.a1 == 0.5   # the same filter, new gains
    assert not set_param(executor, spin, client, 'avoidance.a2', 0.0).successful   # range
    assert f.settings.a2 == 1.0
    assert not set_param(executor, spin, client, 'avoidance.level', 'guidance').successful
    assert h.node.force_filter is f and h.node.mode is Mode.MANUAL


def test_level_guidance_leaves_the_force_alone(context, executor, spin):
    h = DpHarness(context, executor, spin, {**FORCE, 'avoidance.level': 'guidance'})
    assert h.node.force_filter is None
