"""The recorder node: what it records (link-bus topics, graph topics, a selection), how it
refuses a bad bag directory, and its typed settings.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.parameter import Parameter

from enbarr_core.framework.errors import ConfigurationError
from enbarr_core.recording.recorder import Recorder
from enbarr_core.recording.recorder_node import RecorderNode, RecorderSettings
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from support.bags import read_bag
from support.nodes import TIMEOUT, add, probe


def recorder(context: Any, executor: Any, bag: Path, *selected: str) -> RecorderNode:
    params = [Parameter('path', value=str(bag))]
    if selected:
        params.append(Parameter('topics', value=list(selected)))
    return add(executor, RecorderNode(context=context, parameter_overrides=params))


def close(executor: Any, rec: RecorderNode) -> dict[str, list[Any]]:
    """Take the recorder down (the bag is complete then) and read the bag back."""
    executor.remove_node(rec)
    rec.destroy_node()
    return read_bag(rec.settings.path)


def io_message() -> ParameterMsg:
    return ParameterMsg(name='gpio_12', value=convert.python_to_parameter_value(True))


def record_while_publishing(context: Any, executor: Any, spin: Any, rec: RecorderNode,
                            *specs: topics.TopicSpec, count: int = 3) -> None:
    """Publish on every topic of ``specs`` until the recorder wrote ``count`` messages."""
    source = probe(context, executor, 'source')
    pubs = [source.create_topic_publisher(s) for s in specs]
    LinkBus.of(context).connect()
    rec.start()

    def publish_and_check() -> bool:
        for pub in pubs:
            pub.publish(io_message())
        return rec.written >= count

    assert spin(executor, publish_and_check, TIMEOUT), f'{rec.written} written'


def test_records_a_fast_topic_from_the_link_bus(context, executor, spin, tmp_path) -> None:
    rec = recorder(context, executor, tmp_path / 'bag')
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE)
    msgs = close(executor, rec)
    assert len(msgs['/io_state']) >= 3
    assert msgs['/io_state'][0][1].name == 'gpio_12'


def test_records_a_topic_seen_in_the_graph(context, executor, spin, tmp_path) -> None:
    assert not topics.SURFACE_IO.fast  # travels over DDS, found by graph discovery
    rec = recorder(context, executor, tmp_path / 'bag')
    record_while_publishing(context, executor, spin, rec, topics.SURFACE_IO)
    msgs = close(executor, rec)
    assert len(msgs['/surface_command/io']) >= 3


def test_topics_selects_what_is_recorded(context, executor, spin, tmp_path) -> None:
    rec = recorder(context, executor, tmp_path / 'bag', '/io_state')
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE, topics.SURFACE_IO,
                            count=20)
    msgs = close(executor, rec)
    assert set(msgs) == {'/io_state'}


def test_settings_are_typed(context, executor, tmp_path) -> None:
    rec = recorder(context, executor, tmp_path / 'bag', '/io_state')
    assert rec.settings == RecorderSettings(path=str(tmp_path / 'bag'),
                                            topics=frozenset({'/io_state'}),
                                            flush_seconds=1.0)


def test_is_a_recorder_for_bringup(context, executor, tmp_path) -> None:
    assert isinstance(recorder(context, executor, tmp_path / 'bag'), Recorder)


def test_without_a_path_is_refused(context) -> None:
    with pytest.raises(ConfigurationError, match="node 'recorder': parameter path is not set"
                       ) as info:
        RecorderNode(context=context)
    assert info.value.parameter == 'path'


def test_a_bag_directory_in_use_is_refused(context, tmp_path) -> None:
    (tmp_path / 'bag').mkdir()
    (tmp_path / 'bag' / 'other.txt').write_text('not ours')
    with pytest.raises(ConfigurationError, match="node 'recorder': ") as info:
        RecorderNode(context=context,
                     parameter_overrides=[Parameter('path', value=str(tmp_path / 'bag'))])
    assert info.value.parameter == 'path'


def test_empty_topic_names_mean_all() -> None:
    settings = RecorderSettings.from_params({'path': 'bag', 'topics': [''],
                                             'flush_seconds': 1.0, 'segment_seconds': 0.0,
                                             'split_size': 0.0, 'split_seconds': 0.0,
                                             'min_free_space': 64.0, 'max_queued': 20000})
    assert settings.topics == frozenset()


def test_segment_seconds_is_the_old_name_of_flush_seconds() -> None:
    settings = RecorderSettings.from_params({'path': 'bag', 'topics': [],
                                             'flush_seconds': 1.0, 'segment_seconds': 0.25,
                                             'split_size': 0.0, 'split_seconds': 0.0,
                                             'min_free_space': 64.0, 'max_queued': 20000})
    assert settings.flush_seconds == 0.25


def test_stamps_follow_the_node_clock_under_sim_time(context, executor, spin, tmp_path) -> None:
    """Receive stamps come from the node's clock: with use_sim_time and no /clock yet it
    reads 0 (the system clock would give ~1.7e18 ns), and back on the system clock after."""
    from rosbags.rosbag2 import Reader
    bag = tmp_path / 'bag'
    rec = add(executor, RecorderNode(context=context, parameter_overrides=[
        Parameter('path', value=str(bag)), Parameter('use_sim_time', value=True)]))
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE, count=3)
    rec.set_parameters([Parameter('use_sim_time', value=False)])
    before = rec.written
    record_while_publishing(context, executor, spin, rec, topics.IO_STATE,
                            count=before + 3)
    close(executor, rec)
    with Reader(bag) as reader:
        stamps = [t for _, t, _ in reader.messages()]
    assert stamps[:3] == [0, 0, 0]
    assert stamps[-1] > 1_600_000_000 * 10 ** 9
