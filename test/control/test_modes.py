"""Operator modes (``enbarr_core.control.modes``) with a DualShock 4 in the kernel joydev
layout and the manual's buttons (triangle automatic, square guidance, cross manual): the mode
rules as pure functions of joystick samples, time and estimator health (no ROS). Each layout
preset is pressed button by button in test/plugins/test_joy_layouts.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from enbarr_core.bringup.profile import load_profile
from enbarr_core.control.modes import JoyMapping, ModeManager, Transition
from enbarr_interfaces.modes import Mode
from enbarr_core.control.joy_layouts import mapping_from_params

SAUCER_JOY = {k: v for k, v in
              load_profile('saucer_core', allow_fragment=True).parameters.items()
              if k.startswith('joy.')}
DS4, _ = mapping_from_params({**SAUCER_JOY, 'joy.layout': 'joydev'})
TAU_MAX = (1.0, 2.0, 0.5)
N_AXES, N_BUTTONS = 8, 13          # a DS4 through joydev
TRIANGLE, SQUARE, CROSS = 2, 3, 0  # the DualShock 4 through joydev
assert (DS4.button_automatic, DS4.button_guidance, DS4.button_manual) == (2, 3, 0)
assert (DS4.axis_surge, DS4.axis_sway, DS4.axis_yaw) == (1, 0, 3)


def sample(surge: float = 0.0, sway: float = 0.0, yaw: float = 0.0,
           pressed: tuple[int, ...] = ()) -> tuple[list[float], list[int]]:
    axes = [0.0] * N_AXES
    axes[1], axes[0], axes[3] = surge, sway, yaw
    buttons = [0] * N_BUTTONS
    for b in pressed:
        buttons[b] = 1
    return axes, buttons


def manager(joy_timeout: float = 0.5) -> ModeManager:
    return ModeManager(DS4, TAU_MAX, joy_timeout)


def press(m: ModeManager, button: int, now: float, fresh: bool = True,
          path: bool = False) -> list[Transition]:
    """Press ``button`` (rising edge) and release it; the transitions of the press."""
    out = m.on_joy(*sample(pressed=(button,)), now, fresh, path)
    assert m.on_joy(*sample(), now + 0.01, fresh, path) == []
    return out


def test_starts_manual_with_zero_force():
    m = manager()
    assert m.mode is Mode.MANUAL
    assert m.tau_manual.tolist() == [0.0, 0.0, 0.0]
    assert m.rejected_samples == 0
    assert m.check(100.0, estimate_fresh=False) is None  # no joystick yet: nothing to lose


def test_sticks_map_to_manual_force():
    m = manager()
    # surge axis 1, sway axis 0, yaw axis 3; tau = tau_max * axis
    assert m.on_joy(*sample(surge=0.5, sway=-0.25, yaw=1.0), 0.0, True, False) == []
    assert m.tau_manual == pytest.approx([0.5 * 1.0, -0.25 * 2.0, 1.0 * 0.5], abs=1e-15)
    # The other axes (triggers, the right stick's vertical) do nothing.
    axes, buttons = sample(surge=0.2)
    axes[2] = axes[4] = axes[5] = -1.0
    m.on_joy(axes, buttons, 0.1, True, False)
    assert m.tau_manual == pytest.approx([0.2, 0.0, 0.0], abs=1e-15)
    # Full stick in every direction.
    m.on_joy(*sample(surge=-1.0, sway=1.0, yaw=-1.0), 0.2, True, False)
    assert m.tau_manual == pytest.approx([-1.0, 2.0, -0.5], abs=1e-15)
    # Within the 1e-6 tolerance of |axis| <= 1: accepted and clipped to the full force.
    m.on_joy(*sample(surge=1.0 + 1e-7), 0.3, True, False)
    assert m.tau_manual.tolist() == [1.0, 0.0, 0.0]
    assert m.mode is Mode.MANUAL and m.rejected_samples == 0


def test_deadzone():
    m = manager()
    m.on_joy(*sample(surge=0.049, sway=-0.04, yaw=0.01), 0.0, True, False)
    assert m.tau_manual.tolist() == [0.0, 0.0, 0.0]
    m.on_joy(*sample(surge=0.05, sway=-0.06, yaw=0.049), 0.1, True, False)
    assert m.tau_manual == pytest.approx([0.05, -0.12, 0.0], abs=1e-15)
    wide = ModeManager(dataclasses.replace(DS4, deadzone=0.3), TAU_MAX)
    wide.on_joy(*sample(surge=0.29, sway=0.31), 0.0, True, False)
    assert wide.tau_manual == pytest.approx([0.0, 0.62, 0.0], abs=1e-15)


def test_triangle_goes_automatic_with_fresh_estimate():
    m = manager()
    m.on_joy(*sample(surge=0.4), 0.0, True, False)
    out = m.on_joy(*sample(surge=0.4, pressed=(TRIANGLE,)), 0.05, True, False)
    assert out == [Transition(Mode.AUTOMATIC, Mode.MANUAL, True, 'operator request')]
    assert m.mode is Mode.AUTOMATIC
    # The sticks keep being read (the force of the moment), the mode does not change.
    assert m.tau_manual == pytest.approx([0.4, 0.0, 0.0])


def test_triangle_refused_without_fresh_estimate():
    m = manager()
    out = press(m, TRIANGLE, 0.0, fresh=False)
    assert out == [Transition(Mode.AUTOMATIC, Mode.MANUAL, False, 'no fresh pose estimate')]
    assert m.mode is Mode.MANUAL


def test_square_needs_a_path_and_a_fresh_estimate():
    m = manager()
    out = press(m, SQUARE, 0.0, fresh=True, path=False)
    assert out == [Transition(Mode.GUIDANCE, Mode.MANUAL, False, 'no path configured')]
    assert m.mode is Mode.MANUAL
    out = press(m, SQUARE, 0.1, fresh=False, path=True)
    assert len(out) == 1 and not out[0].accepted
    assert out[0].reason == 'no fresh pose estimate'
    assert m.mode is Mode.MANUAL
    out = press(m, SQUARE, 0.2, fresh=True, path=True)
    assert out == [Transition(Mode.GUIDANCE, Mode.MANUAL, True, 'operator request')]
    assert m.mode is Mode.GUIDANCE


def test_cross_returns_to_manual_from_any_mode():
    m = manager()
    press(m, TRIANGLE, 0.0)
    assert m.mode is Mode.AUTOMATIC
    out = press(m, CROSS, 0.1, fresh=False)  # manual needs no estimate
    assert out == [Transition(Mode.MANUAL, Mode.AUTOMATIC, True, 'operator request')]
    assert m.mode is Mode.MANUAL
    press(m, SQUARE, 0.2, path=True)
    assert m.mode is Mode.GUIDANCE
    assert press(m, CROSS, 0.3)[0].previous is Mode.GUIDANCE
    assert m.mode is Mode.MANUAL
    # Cross in manual: nothing changes (refused as 'already manual').
    out = press(m, CROSS, 0.4)
    assert out == [Transition(Mode.MANUAL, Mode.MANUAL, False, 'already manual')]
    # Automatic -> guidance directly.
    press(m, TRIANGLE, 0.5)
    out = press(m, SQUARE, 0.6, path=True)
    assert out == [Transition(Mode.GUIDANCE, Mode.AUTOMATIC, True, 'operator request')]


def test_holding_a_button_does_not_retrigger():
    m = manager()
    held = sample(pressed=(TRIANGLE,))
    assert len(m.on_joy(*held, 0.0, False, False)) == 1  # refused: no estimate
    # Still held when the estimate becomes fresh: no new request, so still manual.
    for k in range(1, 5):
        assert m.on_joy(*held, 0.01 * k, True, False) == []
    assert m.mode is Mode.MANUAL
    m.on_joy(*sample(), 0.1, True, False)  # release
    assert [t.accepted for t in m.on_joy(*held, 0.11, True, False)] == [True]
    assert m.mode is Mode.AUTOMATIC
    # Held cross: one transition only.
    cross = sample(pressed=(CROSS,))
    assert len(m.on_joy(*cross, 0.2, True, False)) == 1
    assert m.mode is Mode.MANUAL
    assert m.on_joy(*cross, 0.21, True, False) == []
    assert m.on_joy(*cross, 0.22, True, False) == []


@pytest.mark.parametrize('bad', [
    {'surge': math.nan}, {'sway': math.inf}, {'yaw': -math.inf},
    {'surge': 1.5}, {'sway': -1.01}, {'yaw': 1.0 + 1e-5},
])
def test_bad_axis_rejects_the_whole_sample(bad):
    m = manager()
    m.on_joy(*sample(surge=0.3), 0.0, True, False)
    before = m.tau_manual.copy()
    # A bad axis with triangle pressed: neither the force nor the mode changes.
    args = {'surge': 0.9, 'sway': 0.9, 'yaw': 0.9, **bad}
    out = m.on_joy(*sample(pressed=(TRIANGLE,), **args), 0.1, True, False)
    assert out == [] and m.rejected_samples == 1
    assert m.mode is Mode.MANUAL
    np.testing.assert_array_equal(m.tau_manual, before)
    # As if it never arrived: the next valid sample with triangle is the rising edge...
    out = m.on_joy(*sample(surge=0.3, pressed=(TRIANGLE,)), 0.2, True, False)
    assert [t.requested for t in out if t.accepted] == [Mode.AUTOMATIC]
    # ... and it does not keep the joystick alive.
    m2 = manager(joy_timeout=0.5)
    m2.on_joy(*sample(), 0.0, True, False)
    for k in range(1, 10):
        m2.on_joy(*sample(**args), 0.1 * k, True, False)
    assert m2.rejected_samples == 9
    lost = m2.check(0.6, True)
    assert lost is not None and lost.reason == 'joystick lost'


def test_too_few_axes_or_buttons_rejected():
    m = manager()
    m.on_joy(*sample(surge=0.5), 0.0, True, False)
    axes, buttons = sample(surge=0.9, pressed=(TRIANGLE,))
    assert m.on_joy(axes[:3], buttons, 0.1, True, False) == []  # no axis 3 (yaw)
    assert m.rejected_samples == 1
    assert m.on_joy(axes, buttons[:3], 0.2, True, False) == []  # no button 3 (square)
    assert m.rejected_samples == 2
    assert m.on_joy([], [], 0.3, True, False) == []
    assert m.rejected_samples == 3
    assert m.mode is Mode.MANUAL
    assert m.tau_manual == pytest.approx([0.5, 0.0, 0.0])
    # Exactly enough (axes 0..3, buttons 0..3) is fine.
    assert len(m.on_joy(axes[:4], buttons[:4], 0.4, True, False)) == 1
    assert m.mode is Mode.AUTOMATIC and m.rejected_samples == 3
    assert m.tau_manual == pytest.approx([0.9, 0.0, 0.0])


def test_joystick_lost_falls_back_to_manual_with_zero_force():
    m = manager(joy_timeout=0.5)
    m.on_joy(*sample(surge=0.8, yaw=-0.5), 10.0, True, False)
    press(m, TRIANGLE, 10.1)
    m.on_joy(*sample(surge=0.8, yaw=-0.5), 10.2, True, False)
    assert m.mode is Mode.AUTOMATIC and np.any(m.tau_manual)
    assert m.check(10.5, True) is None
    assert m.check(10.7, True) is None    # exactly joy_timeout: not yet
    t = m.check(10.71, True)
    assert t == Transition(Mode.MANUAL, Mode.AUTOMATIC, True, 'joystick lost')
    assert m.mode is Mode.MANUAL
    assert m.tau_manual.tolist() == [0.0, 0.0, 0.0]
    assert m.check(20.0, True) is None  # reported once
    # The joystick comes back: the sticks act again.
    m.on_joy(*sample(surge=0.1), 21.0, True, False)
    assert m.tau_manual == pytest.approx([0.1, 0.0, 0.0])
    # Lost in manual too: zero force (the last stick must not stay applied).
    t = m.check(21.6, True)
    assert t is not None and t.accepted and t.previous is Mode.MANUAL
    assert m.tau_manual.tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize('mode_button, path', [(TRIANGLE, False), (SQUARE, True)])
def test_stale_estimate_outside_manual_falls_back(mode_button, path):
    m = manager()
    m.on_joy(*sample(sway=0.6), 0.0, True, path)
    press(m, mode_button, 0.05, path=path)
    m.on_joy(*sample(sway=0.6), 0.1, True, path)
    assert m.mode is not Mode.MANUAL
    assert m.check(0.15, estimate_fresh=True) is None
    t = m.check(0.2, estimate_fresh=False)
    assert t is not None and t.accepted and t.requested is Mode.MANUAL
    assert t.reason == 'pose estimate stale'
    assert m.mode is Mode.MANUAL and m.tau_manual.tolist() == [0.0, 0.0, 0.0]
    # In manual a stale estimate is no reason for anything.
    assert m.check(0.25, estimate_fresh=False) is None


@pytest.mark.parametrize('mode_button, path', [(TRIANGLE, False), (SQUARE, True)])
def test_no_guidance_reference_outside_manual_falls_back(mode_button, path):
    m = manager()
    m.on_joy(*sample(sway=0.6), 0.0, True, path)
    press(m, mode_button, 0.05, path=path)
    assert m.check(0.15, True, reference_fresh=True) is None
    t = m.check(0.2, True, reference_fresh=False)
    assert t is not None and t.accepted and t.requested is Mode.MANUAL
    assert t.reason == 'no guidance reference'
    assert m.mode is Mode.MANUAL and m.tau_manual.tolist() == [0.0, 0.0, 0.0]
    assert m.check(0.25, True, reference_fresh=False) is None  # in manual: nothing to do


def test_mapping_validation():
    DS4.validate()
    with pytest.raises(ValueError, match='mode buttons must differ'):
        dataclasses.replace(DS4, button_automatic=1, button_guidance=1).validate()
    with pytest.raises(ValueError, match='mode buttons must differ'):
        ModeManager(dataclasses.replace(DS4, button_manual=2), TAU_MAX)  # = triangle
    with pytest.raises(ValueError, match='axis_yaw must be >= 0'):
        dataclasses.replace(DS4, axis_yaw=-1).validate()
    with pytest.raises(ValueError, match='button_guidance must be >= 0'):
        ModeManager(dataclasses.replace(DS4, button_guidance=-3), TAU_MAX)
    for deadzone in (-0.01, 1.0, 1.5):
        with pytest.raises(ValueError, match='deadzone'):
            dataclasses.replace(DS4, deadzone=deadzone).validate()
    # Another valid mapping is used as given.
    m = ModeManager(JoyMapping(axis_surge=4, axis_sway=5, axis_yaw=6, button_automatic=7,
                               button_guidance=8, button_manual=9, deadzone=0.0),
                    TAU_MAX)
    axes, buttons = [0.0] * N_AXES, [0] * N_BUTTONS
    axes[4], axes[5], axes[6] = 0.01, -0.5, 0.2
    buttons[7] = 1
    out = m.on_joy(axes, buttons, 0.0, True, False)
    assert [t.requested for t in out] == [Mode.AUTOMATIC] and out[0].accepted
    assert m.tau_manual == pytest.approx([0.01, -1.0, 0.1])


def test_manual_button_wins_when_pressed_with_another():
    """Cross together with triangle or square means manual: the safe request wins."""
    from enbarr_core.control.modes import ModeManager
    mm = ModeManager(DS4, TAU_MAX)
    axes = [0.0] * 8
    mm.on_joy(axes, [0, 0, 1, 0] + [0] * 9, 0.0, True, True)   # triangle
    assert mm.mode is Mode.AUTOMATIC
    mm.on_joy(axes, [0] * 13, 0.1, True, True)                  # release
    out = mm.on_joy(axes, [1, 0, 0, 1] + [0] * 9, 0.2, True, True)  # cross + square
    assert mm.mode is Mode.MANUAL
    assert [t.requested for t in out] == [Mode.MANUAL]


# -- boundaries the mutation run found unpinned (docs/testing.md) ------------------------------

def test_default_joystick_timeout_is_half_a_second():
    m = ModeManager(DS4, TAU_MAX)
    m.on_joy(*sample(surge=0.5), 1.0, True, False)
    assert m.check(1.5, True) is None                   # exactly 0.5 s: not yet
    t = m.check(1.5 + 1e-6, True)
    assert t is not None and t.reason == 'joystick lost'


def test_stick_at_the_tolerance_edge_is_accepted_and_clamped():
    """|axis| up to 1 + 1e-6 is a full stick (drivers overshoot by rounding), clamped to 1;
    beyond it the sample is rejected."""
    m = manager()
    edge = 1.0 + 1e-6
    assert m.on_joy(*sample(surge=edge, sway=-edge, yaw=-edge), 0.0, True, False) == []
    assert m.rejected_samples == 0
    assert m.tau_manual.tolist() == [TAU_MAX[0], -TAU_MAX[1], -TAU_MAX[2]]
    m.on_joy(*sample(surge=-(edge + 1e-9)), 0.1, True, False)
    assert m.rejected_samples == 1


def test_a_button_held_in_the_first_sample_is_a_press():
    """No earlier sample means every button was up: holding cross at start asks for manual
    (refused, already manual), holding triangle asks for automatic."""
    m = manager()
    out = m.on_joy(*sample(pressed=(CROSS,)), 0.0, True, False)
    assert out == [Transition(Mode.MANUAL, Mode.MANUAL, False, 'already manual')]
    m = manager()
    out = m.on_joy(*sample(pressed=(TRIANGLE,)), 0.0, True, False)
    assert out == [Transition(Mode.AUTOMATIC, Mode.MANUAL, True, 'operator request')]


@pytest.mark.parametrize('mode_button, path, mode', [(TRIANGLE, False, Mode.AUTOMATIC),
                                                     (SQUARE, True, Mode.GUIDANCE)])
def test_fallback_transitions_name_the_mode_left(mode_button, path, mode):
    for fresh, reference, reason in ((False, True, 'pose estimate stale'),
                                     (True, False, 'no guidance reference')):
        m = manager()
        m.on_joy(*sample(), 0.0, True, path)
        press(m, mode_button, 0.05, path=path)
        t = m.check(0.1, fresh, reference_fresh=reference)
        assert t == Transition(Mode.MANUAL, mode, True, reason)


# -- the joystick-loss rule of a driver that publishes only on change ----------------------------

def connected_manager(joy_timeout: float = 0.5) -> ModeManager:
    return ModeManager(DS4, TAU_MAX, joy_timeout, loss_rule='connection')


def test_connection_rule_resting_stick_stays_automatic_for_many_timeouts():
    """ds4_driver sends nothing while the sticks rest: with heartbeats, automatic stays."""
    m = connected_manager(joy_timeout=0.5)
    assert m.on_connection(True, 0.0) is None
    m.on_joy(*sample(), 0.0, True, False)
    press(m, TRIANGLE, 0.1)
    assert m.mode is Mode.AUTOMATIC
    # 20 s without a joystick sample (40 timeouts), heartbeats every 0.2 s.
    for k in range(1, 101):
        now = 0.2 + 0.2 * k
        assert m.on_connection(True, now) is None
        assert m.check(now + 0.1, True) is None
    assert m.mode is Mode.AUTOMATIC


def test_connection_rule_held_stick_keeps_its_force():
    m = connected_manager()
    m.on_connection(True, 0.0)
    m.on_joy(*sample(surge=0.8, yaw=-0.4), 0.0, True, False)
    for k in range(1, 51):  # held still for 10 s: no sample, heartbeats only
        m.on_connection(True, 0.2 * k)
        assert m.check(0.2 * k + 0.1, True) is None
    assert m.tau_manual == pytest.approx([0.8, 0.0, -0.2])


def test_connection_rule_disconnect_is_manual_zero_force_at_once():
    m = connected_manager()
    m.on_connection(True, 0.0)
    m.on_joy(*sample(sway=0.5), 0.0, True, False)
    press(m, TRIANGLE, 0.1)
    t = m.on_connection(False, 0.15)
    assert t == Transition(Mode.MANUAL, Mode.AUTOMATIC, True, 'joystick disconnected')
    assert m.mode is Mode.MANUAL and m.tau_manual.tolist() == [0.0, 0.0, 0.0]
    assert m.on_connection(False, 0.2) is None  # reported once
    # Samples while disconnected are not taken (a stale driver must not drive).
    assert m.on_joy(*sample(surge=1.0, pressed=(TRIANGLE,)), 0.3, True, False) == []
    assert m.unconnected_samples == 1 and m.tau_manual.tolist() == [0.0, 0.0, 0.0]
    # Reconnected: the sticks act again, the mode is the operator's to ask for again.
    m.on_connection(True, 1.0)
    m.on_joy(*sample(surge=0.3), 1.0, True, False)
    assert m.tau_manual == pytest.approx([0.3, 0.0, 0.0]) and m.mode is Mode.MANUAL


def test_connection_rule_heartbeat_loss_is_manual_zero_force():
    m = connected_manager(joy_timeout=0.5)
    m.on_connection(True, 10.0)
    m.on_joy(*sample(surge=0.6), 10.0, True, False)
    press(m, TRIANGLE, 10.05)
    assert m.check(10.5, True) is None          # exactly joy_timeout: not yet
    t = m.check(10.51, True)
    assert t == Transition(Mode.MANUAL, Mode.AUTOMATIC, True, 'joystick heartbeat lost')
    assert m.tau_manual.tolist() == [0.0, 0.0, 0.0] and not m.connected
    assert m.check(20.0, True) is None


def test_connection_rule_loss_in_manual_with_a_held_stick_zeroes_it():
    m = connected_manager()
    m.on_connection(True, 0.0)
    m.on_joy(*sample(surge=0.6), 0.0, True, False)
    t = m.check(0.6, True)
    assert t is not None and t.previous is Mode.MANUAL and t.reason == 'joystick heartbeat lost'
    assert m.tau_manual.tolist() == [0.0, 0.0, 0.0]


def test_timeout_rule_still_judges_by_the_sample_rate():
    """A steady-rate driver keeps the old rule: heartbeats are ignored, silence is loss."""
    m = manager(joy_timeout=0.5)
    m.on_joy(*sample(surge=0.6), 0.0, True, False)
    press(m, TRIANGLE, 0.05)
    assert m.on_connection(True, 0.5) is None   # not listened to
    assert m.on_connection(False, 0.5) is None  # nor this
    assert m.mode is Mode.AUTOMATIC
    t = m.check(0.57, True)  # the release at 0.06 s was the last sample
    assert t is not None and t.reason == 'joystick lost'


def test_timeout_rule_a_republished_sample_is_a_sign_of_life():
    m = manager(joy_timeout=0.5)
    m.on_joy(*sample(surge=0.6), 0.0, True, False)
    for k in range(1, 20):
        m.on_repeat(0.1 * k)
        assert m.check(0.1 * k + 0.05, True) is None
    assert m.tau_manual == pytest.approx([0.6, 0.0, 0.0])
    assert m.check(1.9 + 0.51, True) is not None


def test_contested_joystick_is_manual_zero_force_under_either_rule():
    for m in (manager(), connected_manager()):
        m.on_connection(True, 0.0)
        m.on_joy(*sample(surge=0.6), 0.0, True, False)
        press(m, TRIANGLE, 0.05)
        t = m.joystick_contested()
        assert t is not None and t.reason == 'joystick contested'
        assert m.mode is Mode.MANUAL and m.tau_manual.tolist() == [0.0, 0.0, 0.0]


def test_unknown_loss_rule_is_refused():
    with pytest.raises(ValueError, match='loss_rule'):
        ModeManager(DS4, TAU_MAX, loss_rule='rate')


def test_signs_flip_an_axis():
    m = ModeManager(dataclasses.replace(DS4, signs=(1.0, -1.0, -1.0)), TAU_MAX)
    m.on_joy(*sample(surge=0.5, sway=0.5, yaw=0.5), 0.0, True, False)
    assert m.tau_manual == pytest.approx([0.5, -1.0, -0.25])
    with pytest.raises(ValueError, match='signs'):
        dataclasses.replace(DS4, signs=(1.0, 0.5, 1.0)).validate()
