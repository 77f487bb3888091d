"""Pilot modes (pure): requests, refusals and the depth fallback, manual forces."""

from __future__ import annotations

import math

import pytest

from enbarr_core.control.pilot_modes import manual_force, manual_problem, PilotModes

pytestmark = pytest.mark.unit


def test_depth_hold_needs_a_fresh_depth_and_falls_back_to_stabilize():
    m = PilotModes('stabilize', depth_timeout=0.5)
    assert m.request('depth_hold', None).reason == 'depth_hold refused: no depth sensor heard'
    assert m.request('depth_hold', 0.8).reason == (
        'depth_hold refused: depth 0.8 s old (limit 0.5 s)')
    assert m.mode == 'stabilize' and m.refused == 2
    out = m.request('depth_hold', 0.1)
    assert (out.mode, out.changed, out.reason) == ('depth_hold', True, '')
    assert not m.check(0.4).changed
    out = m.check(0.6)
    assert (out.mode, out.changed) == ('stabilize', True) and out.reason.startswith(
        'depth_hold -> stabilize: depth 0.6 s old')
    assert m.fallbacks == 1


def test_manual_needs_finite_limits():
    m = PilotModes('velocity', depth_timeout=0.5)
    problem = manual_problem((1.0, math.inf, 1.0, 1.0, 1.0, 1.0))
    assert problem is not None
    assert m.request('manual', None, problem).reason.startswith('manual refused:')
    assert manual_problem((1.0,) * 6) is None
    assert m.request('manual', None, None).mode == 'manual'


def test_manual_force_is_the_stick_fraction_of_tau_max():
    assert manual_force((0.25, -2.0, 0.0), (0.5, 0.5, 1.0), (80.0, 80.0, 120.0)) == (
        40.0, -80.0, 0.0)


@pytest.mark.parametrize('initial, timeout, field', [('hover', 0.5, '^initial'),
                                                     ('velocity', 0.0, '^depth_timeout')])
def test_bad_settings_name_the_field(initial, timeout, field):
    with pytest.raises(ValueError, match=field):
        PilotModes(initial, timeout)
