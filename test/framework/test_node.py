"""Node tests: EnbarrNode's public views of its sources."""

from __future__ import annotations

from enbarr_core.framework.node import EnbarrNode


def test_rate_loops_are_listed_in_creation_order_read_only(context):
    node = EnbarrNode('loops', context=context)
    try:
        assert node.rate_loops == ()
        first = node.create_rate_loop(10.0, lambda: None)
        second = node.create_rate_loop(20.0, lambda: None)
        assert node.rate_loops == (first, second)
        assert not any(loop.running for loop in node.rate_loops)  # not started yet
        assert isinstance(node.rate_loops, tuple)  # a view: nothing to append to
    finally:
        node.stop()
        node.destroy_node()


# -- the process's one supervision timer (Ticker) ------------------------------------------------
import pytest  # noqa: E402

from enbarr_core.framework.node import Ticker, TICK  # noqa: E402


def _timers(*nodes):
    return sum(len(list(n.timers)) for n in nodes)


def test_checks_of_every_node_share_one_timer_and_run_at_their_periods(context):
    a, b = EnbarrNode('ticker_a', context=context), EnbarrNode('ticker_b', context=context)
    try:
        calls = []
        a.create_periodic(TICK, lambda: calls.append('a'))
        b.create_periodic(3 * TICK, lambda: calls.append('b'))
        b.create_periodic(1.0, lambda: calls.append('b1'))
        assert _timers(a, b) == 1          # one executor timer for the whole process
        ticker = Ticker.of(context)
        for _ in range(10):
            ticker.tick()
        assert calls.count('a') == 10 and calls.count('b') == 3 and calls.count('b1') == 1
        assert calls[:3] == ['a', 'a', 'a'] and calls[3] == 'b'  # first call after a period
    finally:
        b.destroy_node()
        a.destroy_node()


def test_a_failing_check_is_counted_and_the_others_still_run(context):
    a, b = EnbarrNode('ticker_fail', context=context), EnbarrNode('ticker_ok', context=context)
    try:
        ran = []
        bad = a.create_periodic(TICK, lambda: 1 / 0)
        b.create_periodic(TICK, lambda: ran.append(1))
        for _ in range(3):
            Ticker.of(context).tick()
        assert bad.errors == 3 and len(ran) == 3
    finally:
        b.destroy_node()
        a.destroy_node()


def test_the_timer_moves_when_its_host_node_is_destroyed(context):
    a, b = EnbarrNode('ticker_host', context=context), EnbarrNode('ticker_next', context=context)
    ran = []
    try:
        a.create_periodic(TICK, lambda: ran.append('a'))
        b.create_periodic(TICK, lambda: ran.append('b'))
        ticker = Ticker.of(context)
        assert ticker.host is a and _timers(a, b) == 1
        a.destroy_node()
        assert ticker.host is b and _timers(b) == 1
        ticker.tick()
        assert ran == ['b']                # the destroyed node's check is gone with it
    finally:
        b.destroy_node()
    assert ticker.host is None


def test_the_timer_really_drives_the_checks(context, executor):
    from test.conftest import spin_until
    node = EnbarrNode('ticker_spun', context=context)
    executor.add_node(node)
    ran = []
    node.create_periodic(TICK, lambda: ran.append(1))
    assert spin_until(executor, lambda: len(ran) >= 3, timeout=10.0)


@pytest.mark.parametrize('period', [0.0, 0.05, 0.25, -1.0])
def test_a_period_off_the_tick_is_refused(context, period):
    node = EnbarrNode('ticker_bad', context=context)
    try:
        with pytest.raises(ValueError, match='whole multiple'):
            node.create_periodic(period, lambda: None)
    finally:
        node.destroy_node()


def test_a_cancelled_check_is_not_called(context):
    node = EnbarrNode('ticker_cancel', context=context)
    try:
        ran = []
        node.create_periodic(TICK, lambda: ran.append(1)).cancel()
        Ticker.of(context).tick()
        assert ran == []
    finally:
        node.destroy_node()


def test_a_check_added_later_counts_its_period_from_then(context):
    node = EnbarrNode('ticker_late', context=context)
    try:
        ticker, calls = Ticker.of(context), []
        node.create_periodic(TICK, lambda: None)
        ticker.tick()                              # tick 1
        node.create_periodic(2 * TICK, lambda: calls.append(ticker.count))
        for _ in range(4):
            ticker.tick()                          # ticks 2..5
        assert calls == [3, 5]                     # 2 ticks after it was added, not at even ticks
    finally:
        node.destroy_node()


def test_now_ns_reads_the_node_clock_simulated_time_included(context):
    import time

    from rclpy.time import Time
    from rclpy.time_source import TimeSource
    from rosgraph_msgs.msg import Clock
    node = EnbarrNode('clock_reader', context=context)
    try:
        assert abs(node.now_ns() - time.time_ns()) < 50_000_000     # system time by default
        source = TimeSource()            # as scenarios do, and use_sim_time with /clock
        source.ros_time_is_active = True
        source.attach_clock(node.get_clock())
        source.clock_callback(Clock(clock=Time(nanoseconds=1_234_000_000).to_msg()))
        assert node.now_ns() == 1_234_000_000 == node.get_clock().now().nanoseconds
    finally:
        node.destroy_node()


# -- source timers: between start and stop only ---------------------------------------------------
from test.conftest import spin_until  # noqa: E402


def _spin_for(executor, seconds):
    """Spin for ``seconds``: to see that nothing comes (what comes is awaited by spin_until)."""
    import time
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.02)


@pytest.mark.parametrize('events', [False, True], ids=['single_threaded', 'events'])
def test_a_source_timer_runs_between_start_and_stop_only(context, executor, events):
    from enbarr_core.bringup.compose import make_executor
    ex = make_executor(context) if events else executor
    node = EnbarrNode('source_timer', context=context)
    try:
        ex.add_node(node)
        calls = []
        timer = node.create_source_timer(0.01, lambda: calls.append(1))
        _spin_for(ex, 0.3)
        assert calls == [] and timer.is_canceled()       # not started: no call, no wake-up
        node.start()
        assert spin_until(ex, lambda: len(calls) >= 5) and not timer.is_canceled()
        node.stop()
        stopped_at = len(calls)
        _spin_for(ex, 0.3)
        assert len(calls) == stopped_at and timer.is_canceled()
        node.start()                                      # a restart runs it again
        assert spin_until(ex, lambda: len(calls) > stopped_at)
    finally:
        node.stop()
        ex.remove_node(node)
        node.destroy_node()
        if events:
            ex.shutdown()


def test_a_source_timer_made_after_start_runs_at_once(context, executor):
    node = EnbarrNode('source_timer_late', context=context)
    executor.add_node(node)
    node.start()
    calls = []
    timer = node.create_source_timer(0.01, lambda: calls.append(1))
    assert not timer.is_canceled()
    assert spin_until(executor, lambda: len(calls) >= 5)
    node.stop()


class _Refused(EnbarrNode):
    """A node refused after the rcl node exists (as a missing parameter refuses one)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('refused_at_construction', **kwargs)
        raise ValueError('refused')


class _RefusedDeeper(_Refused):
    """The refusal two constructors down: only the outermost cleans up, once."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)


@pytest.mark.parametrize('cls', [_Refused, _RefusedDeeper])
def test_a_node_refused_at_construction_leaves_the_graph(context, cls):
    # The error's traceback keeps the half-built node alive (as pytest.raises keeps it):
    # without the clean-up its name stayed on the graph, answering nothing, and a later run
    # in the same domain met it (a /pwm refused a vessel's start).
    watcher = EnbarrNode('watcher', context=context)
    with pytest.raises(ValueError, match='refused') as info:
        cls(context=context)
    assert info.value is not None
    assert 'refused_at_construction' not in watcher.get_node_names()
    watcher.destroy_node()


def test_a_node_built_fine_stays_on_the_graph(context):
    # the check above can fail: a node of the same context is on the graph at once
    watcher = EnbarrNode('watcher', context=context)
    node = EnbarrNode('built_fine', context=context)
    assert 'built_fine' in watcher.get_node_names()
    node.destroy_node()
    watcher.destroy_node()
