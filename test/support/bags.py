"""Read back what a run recorded, for tests (the project's own reader, plus stamps), and what
a bag says of itself: its ``metadata.yaml`` and, file by file, its mcap summaries."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import yaml

from enbarr_core.recording.bag import read_bag

__all__ = ['mcap_messages', 'metadata', 'read_bag', 'stamp']


def stamp(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def metadata(bag: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of ``bag``'s metadata.yaml."""
    return yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


def mcap_messages(bag: Path) -> list[tuple[str, int]]:
    """(topic, log time) of every message of ``bag``, decoded by mcap file by file in the
    order metadata.yaml lists the files; each file's summary must count what metadata.yaml
    says it holds."""
    info = metadata(bag)
    found = []
    for name, finfo in zip(info['relative_file_paths'], info['files']):
        with open(bag / name, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            assert summary is not None and summary.statistics is not None
            assert summary.statistics.message_count == finfo['message_count']
            found += [(ch.topic, m.log_time) for _, ch, m, _ in reader.iter_decoded_messages()]
    return found
