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
