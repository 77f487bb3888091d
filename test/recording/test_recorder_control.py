"""The recorder's start and stop (``recorder/control``): each stop leaves a bag that rosbags
reads, holding exactly the messages of its interval, and the status on ``/diagnostics`` says
whether it records, which bag, its size and the free space."""

from __future__ import annotations

from pathlib import Path
import shutil
from typing import Any

import pytest
from rclpy.parameter import Parameter
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores
from std_msgs.msg import String

from enbarr_core.recording.recorder_node import bag_bytes, next_bag_path, RecorderNode
from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import LinkBus
from support.nodes import add, probe, TIMEOUT

pytestmark = pytest.mark.node


def values_in(bag: Path) -> dict[str, list[Any]]:
    """Topic -> decoded messages, read with rosbags (not the project's own reader)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    out: dict[str, list[Any]] = {}
    with Reader(bag) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(store.deserialize_cdr(raw, conn.msgtype))
    return out


def test_next_bag_path_takes_the_first_free_name(tmp_path):
    taken = {tmp_path / 'bag_1', tmp_path / 'bag_2'}
    assert next_bag_path(tmp_path / 'bag', taken.__contains__) == tmp_path / 'bag_3'
    assert next_bag_path(tmp_path / 'bag') == tmp_path / 'bag_1'


def test_stop_and_start_make_readable_bags_of_their_intervals(context, executor, spin,
                                                              tmp_path):
    rec = add(executor, RecorderNode(context=context, parameter_overrides=[
        Parameter('path', value=str(tmp_path / 'bag')), Parameter('flush_seconds', value=0.1)]))
    source = probe(context, executor, 'source')
    io = source.create_topic_publisher(topics.IO_STATE)
    mode = source.create_topic_publisher(topics.MODE)
    control = source.create_topic_publisher(topics.RECORDER_CONTROL)
    status: list[dict[str, str]] = []
    source.create_subscription(
        topics.DIAGNOSTICS.msg_type, topics.DIAGNOSTICS.name,
        lambda m: status.extend({kv.key: kv.value for kv in s.values} | {'_': s.message}
                                for s in m.status if s.name == '/recorder'),
        topics.DIAGNOSTICS.qos)
    LinkBus.of(context).connect()
    rec.start()
    sent = iter(range(1, 10_000))

    def publish(offset: int) -> None:
        io.publish(topics.IO_STATE.msg_type(
            name='n', value=convert.python_to_parameter_value(offset + next(sent))))

    def record(offset: int, count: int) -> None:
        goal = rec.written + count
        assert spin(executor, lambda: (publish(offset), rec.written >= goal)[1], TIMEOUT)

    mode.publish(String(data='automatic'))
    record(0, 3)
    control.publish(String(data='stop'))
    assert spin(executor, lambda: rec.paused, TIMEOUT)
    for _ in range(5):
        publish(1000)   # while stopped: in no bag
    assert spin(executor, lambda: bag_bytes(tmp_path / 'bag') > 0
                and status and status[-1]['recording'] == 'false', TIMEOUT)
    # Refused words change nothing and say why.
    control.publish(String(data='stop'))
    assert spin(executor, lambda: 'not recording' in rec.last_control_refusal, TIMEOUT)
    assert rec.control('pause') == "unknown word 'pause': one of start, stop"
    control.publish(String(data='start'))
    assert spin(executor, lambda: not rec.paused, TIMEOUT)
    assert rec.bag == tmp_path / 'bag_1'
    assert rec.control('start') == f'already recording to {tmp_path / "bag_1"}'
    record(2000, 3)
    assert spin(executor, lambda: status and status[-1]['recording'] == 'true'
                and status[-1]['bag'] == str(tmp_path / 'bag_1'), TIMEOUT)
    assert rec.control('stop') == ''
    # The status: the last bag, its size on disk, the free space where it is.
    assert spin(executor, lambda: status[-1]['recording'] == 'false'
                and int(status[-1]['bag_bytes']) > 0, TIMEOUT)
    last = status[-1]
    assert last['bag'] == str(tmp_path / 'bag_1') and last['_'] == 'stopped (recorder/control)'
    assert int(last['bag_bytes']) == bag_bytes(tmp_path / 'bag_1')
    assert 0 < int(last['free_bytes']) <= shutil.disk_usage(tmp_path).total

    first, second = values_in(tmp_path / 'bag'), values_in(tmp_path / 'bag_1')
    one = [m.value.integer_value for m in first['/io_state']]
    two = [m.value.integer_value for m in second['/io_state']]
    assert one and all(v < 1000 for v in one) and one == sorted(one)
    assert two and all(v > 2000 for v in two) and two == sorted(two)
    # The latched mode starts the new bag too.
    assert [m.data for m in second['/mode']] == ['automatic']
    executor.remove_node(rec)
    rec.destroy_node()
