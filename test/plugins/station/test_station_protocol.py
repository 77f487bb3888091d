"""The station's protocol rules, pure: input checks, the drive lease and its timeout, the Joy."""

from __future__ import annotations

import pytest

from enbarr_core.control.joy_layouts import get_layout
from enbarr_plugins.station.protocol import (
    DriveInput, DriveLease, InputError, joy_axes_buttons, parse_input, twist_of, Verdict)

pytestmark = pytest.mark.unit


def msg(seq: int = 1, t: float = 10.0, **kw: object) -> dict[str, object]:
    return {'type': 'input', 'seq': seq, 't': t, **kw}


def inp(seq: int = 1, t: float = 10.0, axes=(0.0, 0.0, 0.0, 0.0), buttons=()) -> DriveInput:
    return DriveInput(seq, t, axes, frozenset(buttons), False)


def test_a_full_input_is_parsed():
    got = parse_input(msg(axes={'surge': 0.5, 'yaw': -1.0}, buttons=['triangle'], lights=True))
    assert got == DriveInput(1, 10.0, (0.5, 0.0, 0.0, -1.0), frozenset({'triangle'}), True)


@pytest.mark.parametrize('bad, words', [
    (msg(seq=0), 'seq'), (msg(seq=True), 'seq'), (msg(seq='3'), 'seq'),
    (msg(t=float('nan')), 't must'), (msg(t=None), 't must'),
    (msg(axes={'surge': 1.5}), 'axes.surge'), (msg(axes={'yaw': float('inf')}), 'axes.yaw'),
    (msg(axes={'roll': 0.1}), 'keys among'), (msg(axes={'surge': True}), 'axes.surge'),
    (msg(buttons=['jump']), 'unknown buttons'), (msg(buttons='cross'), 'list'),
    (msg(lights=1), 'lights'),
])
def test_a_bad_input_is_refused_with_its_reason(bad, words):
    with pytest.raises(InputError, match=words):
        parse_input(bad)


def test_the_lease_is_live_until_the_inputs_stop_for_longer_than_the_timeout():
    lease = DriveLease(0.5)
    page = object()
    assert lease.offer(page, inp(1), now=100.0) == Verdict.TAKEN
    assert lease.live(100.5) and not lease.check(100.5)    # exactly the timeout: still live
    assert lease.offer(page, inp(2, t=60.0), now=100.4) == Verdict.TAKEN
    assert not lease.check(100.9)
    assert lease.check(100.95)                              # 0.55 s of silence: ends, once
    assert not lease.check(101.5) and lease.holder is None
    assert (lease.ended, lease.timeouts) == (1, 1)


def test_a_held_still_gamepad_is_no_silence():
    """Unchanged axes every tick keep the lease: it is the messages that count."""
    lease = DriveLease(0.5)
    page = object()
    for k in range(1, 200):
        now = 0.05 * k
        assert lease.offer(page, inp(k, t=50.0 * k, axes=(0.3, 0.0, 0.0, 0.0)), now) \
            == Verdict.TAKEN
        assert not lease.check(now + 0.01)
    assert lease.ended == 0


def test_closing_the_driving_page_ends_the_lease_and_another_page_may_then_drive():
    lease = DriveLease(0.5)
    a, b = object(), object()
    assert lease.offer(a, inp(1), 0.0) == Verdict.TAKEN
    assert lease.offer(b, inp(1), 0.1) == Verdict.NOT_HOLDER
    assert not lease.close(b)                    # a watching page leaving changes nothing
    assert lease.close(a) and lease.holder is None
    assert not lease.close(a)                    # once
    assert lease.offer(b, inp(1), 0.2) == Verdict.TAKEN


def test_a_replayed_or_reordered_input_is_refused():
    lease = DriveLease(0.5)
    page = object()
    assert lease.offer(page, inp(5, t=100.0), 0.0) == Verdict.TAKEN
    assert lease.offer(page, inp(5, t=150.0), 0.05) == Verdict.OLD
    assert lease.offer(page, inp(4, t=200.0), 0.05) == Verdict.OLD
    assert lease.offer(page, inp(6, t=99.0), 0.05) == Verdict.OLD
    assert lease.refused == 3
    # A refused input does not keep the lease alive.
    assert lease.check(0.51)


def test_the_timeout_must_be_positive():
    with pytest.raises(ValueError, match='input_timeout'):
        DriveLease(0.0)


def test_the_joy_of_an_input_in_the_enbarr_ds4_layout():
    """Indices typed from naoki-mizuno/ds4_driver's ``_status_to_joy_`` (humble-devel).

    axes [left_x, left_y, right_x, right_y, l2, r2], up/left +1; buttons [square, triangle,
    circle, cross, l1, l2, r1, r2, share, options, ps, trackpad, l3, r3, dpad left, up,
    right, down]. The Saucer profile: surge left_y, sway left_x, yaw right_x.
    """
    layout = get_layout('enbarr_ds4')
    axes_of = tuple(layout.axis(n) for n in ('left_y', 'left_x', 'right_x'))
    index = {b: i for i, b in enumerate(layout.buttons)}
    axes, buttons = joy_axes_buttons(inp(axes=(0.5, -0.25, 0.9, 0.75), buttons=('triangle',)),
                                     layout.rest, axes_of, len(layout.buttons), index)
    assert axes == [-0.25, 0.5, 0.75, 0.0, 0.0, 0.0]
    assert len(buttons) == 18 and buttons[1] == 1 and sum(buttons) == 1
    _, buttons = joy_axes_buttons(inp(buttons=('cross', 'square')), layout.rest, axes_of,
                                  len(layout.buttons), index)
    assert [i for i, b in enumerate(buttons) if b] == [0, 3]


def test_the_neutral_joy_is_the_layout_at_rest():
    layout = get_layout('joydev')     # released triggers read +1 on joydev
    axes_of = tuple(layout.axis(n) for n in ('left_y', 'left_x', 'right_x'))
    axes, buttons = joy_axes_buttons(None, layout.rest, axes_of, 13, {})
    assert axes == [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0] and buttons == [0] * 13


def test_a_signed_axis_name_flips_the_stick():
    layout = get_layout('enbarr_ds4')
    axes_of = (layout.axis('left_y'), layout.axis('left_x'), layout.axis('-right_x'))
    axes, _ = joy_axes_buttons(inp(axes=(0.0, 0.0, 0.0, 0.4)), layout.rest, axes_of, 18, {})
    assert axes[2] == -0.4


def test_the_twist_of_an_input():
    got = twist_of(inp(axes=(1.0, -0.5, 0.2, -1.0)), max_linear=0.4, max_angular=0.3)
    assert got == pytest.approx((0.4, -0.2, 0.08, 0.0, 0.0, -0.3))
    assert twist_of(None, 0.4, 0.3) == (0.0,) * 6
