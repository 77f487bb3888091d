"""The time policy of stamped inputs (``framework/stamps.py``), in integer nanoseconds.

Every limit is checked at its boundary: a stamp exactly ``max_future`` ahead is accepted and
1 ns more is refused; the only stamps that become the stream's time base are accepted ones.
"""

from __future__ import annotations

import random

import pytest

from enbarr_core.framework.stamps import StampGate, StampPolicy, StampVerdict

A = StampVerdict.ACCEPTED
MS = 1_000_000
S = 1_000_000_000
NOW = 100 * S


def gate(max_future: float = 0.02, max_age: float | None = None) -> StampGate:
    return StampGate(StampPolicy(max_future=max_future, max_age=max_age))


def test_future_limit_is_inclusive_to_the_nanosecond() -> None:
    g = gate(0.02)
    assert g.check(NOW + 20 * MS, NOW) is A
    assert g.check(NOW + 20 * MS + 1, NOW) is StampVerdict.FUTURE


def test_a_future_sample_never_becomes_the_time_base() -> None:
    """The case that made the policy: one sample 20 s ahead, then the good ones go on."""
    g = gate(0.02)
    period = 2_500_000  # 400 Hz
    assert g.offer(NOW, NOW) is A
    assert g.offer(NOW + 20 * S, NOW + period) is StampVerdict.FUTURE
    assert g.last_ns == NOW
    verdicts = [g.offer(NOW + k * period, NOW + k * period) for k in range(2, 50)]
    assert verdicts == [A] * 48  # one bad sample cost exactly itself
    assert g.counts[StampVerdict.FUTURE] == 1 and g.refused == 1


def test_a_sample_within_tolerance_costs_at_most_the_tolerance() -> None:
    """A sample accepted +max_future ahead refuses good ones for at most max_future."""
    g = gate(0.01)
    period = 2_500_000
    assert g.offer(NOW + 10 * MS, NOW) is A
    refused = [k for k in range(1, 20)
               if g.offer(NOW + k * period, NOW + k * period) is not A]
    assert refused == [1, 2, 3, 4]  # stamps up to NOW + 10 ms: 4 samples of 2.5 ms


@pytest.mark.parametrize('stamp', [NOW, NOW - 1, NOW - 5 * S])
def test_repeats_and_out_of_order_samples_are_refused(stamp: int) -> None:
    g = gate()
    g.offer(NOW, NOW)
    assert g.offer(stamp, NOW + MS) is StampVerdict.NOT_NEWER
    assert g.last_ns == NOW


def test_max_age_is_inclusive_and_optional() -> None:
    g = gate(max_age=0.5)
    assert g.check(NOW - S // 2, NOW) is A
    assert g.check(NOW - S // 2 - 1, NOW) is StampVerdict.STALE
    assert gate().check(NOW - 3600 * S, NOW) is A  # no max_age: the age is judged elsewhere


def test_a_clock_that_goes_back_restarts_the_stream() -> None:
    """A restarted simulation: the clock is the reference, not the last stamp."""
    g = gate(0.02)
    g.offer(NOW, NOW)
    back = NOW - 10 * S
    assert g.offer(back, back) is A
    assert g.clock_resets == 1 and g.last_ns == back
    # ... but a clock a little behind the last stamp (within max_future) is not a reset.
    g2 = gate(0.02)
    g2.offer(NOW + 10 * MS, NOW)
    assert g2.offer(NOW + 5 * MS, NOW + MS) is StampVerdict.NOT_NEWER
    assert g2.clock_resets == 0


def test_policy_swap_keeps_the_stream_and_refuses_bad_values() -> None:
    g = gate(0.02)
    g.offer(NOW, NOW)
    g.policy = StampPolicy(max_future=0.0)
    assert g.last_ns == NOW
    assert g.check(NOW + 2, NOW + 1) is StampVerdict.FUTURE
    for bad in (StampPolicy(max_future=-0.1), StampPolicy(max_future=float('nan')),
                StampPolicy(max_age=0.0), StampPolicy(max_age=float('inf'))):
        with pytest.raises(ValueError, match='max_'):
            g.policy = bad
    assert g.policy == StampPolicy(max_future=0.0)


def test_reset_forgets_the_last_stamp() -> None:
    g = gate()
    g.offer(NOW, NOW)
    g.reset()
    assert g.offer(NOW - MS, NOW) is A


@pytest.mark.parametrize('policy', [StampPolicy(max_future=0.002),
                                    StampPolicy(max_future=0.0, max_age=0.005)])
def test_offer_judges_as_check_does_and_counts_every_verdict(policy: StampPolicy) -> None:
    """``offer`` inlines ``check`` (the hot path): both must agree on every kind of sample."""
    rng = random.Random(7)
    g = StampGate(policy)
    now, expected = NOW, {v: 0 for v in StampVerdict}
    for _ in range(4000):
        now += rng.choice((0, MS, 3 * MS, -20 * MS))  # a clock that also goes back
        stamp = now + rng.randint(-8 * MS, 4 * MS)
        last, resets = g.last_ns, g.clock_resets
        verdict = g.check(stamp, now)
        assert g.offer(stamp, now) is verdict
        expected[verdict] += 1
        if verdict is A:
            assert g.last_ns == stamp
            assert g.clock_resets == resets + (last is not None and stamp <= last)
        else:
            assert (g.last_ns, g.clock_resets) == (last, resets)
    assert g.counts == expected
    exercised = {v for v, n in expected.items() if n}
    assert exercised == set(StampVerdict) - ({StampVerdict.STALE} if policy.max_age is None
                                             else set())
    assert g.refused == sum(expected.values()) - expected[A]
