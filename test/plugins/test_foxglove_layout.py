"""The Foxglove layout shipped for the CS Saucer (docs/foxglove_saucer_layout.json) names
what exists: every panel it places is configured, every topic it reads is one of the
contract's (or the frame tree's), every frame it follows is one of saucer_core.yaml's.
A renamed topic then fails here, not silently in an operator's empty panel.
"""

from __future__ import annotations

import json
from pathlib import Path
import re
from typing import Any

import pytest
import yaml

from enbarr_interfaces import topics

pytestmark = pytest.mark.unit

ROOT = Path(__file__).parents[2]
LAYOUT = ROOT / 'docs' / 'foxglove_saucer_layout.json'
#: The panel kinds the layout uses (Foxglove's panel type ids, before the '!').
KINDS = {'3D', 'Plot', 'RawMessages', 'Image'}


def _panels(tree: Any) -> list[str]:
    """The panel ids of a mosaic layout tree (leaves are ids, nodes have first/second)."""
    if isinstance(tree, str):
        return [tree]
    assert tree['direction'] in ('row', 'column')
    assert 0 < tree['splitPercentage'] < 100
    return _panels(tree['first']) + _panels(tree['second'])


def _topics_read(config: dict[str, Any]) -> set[str]:
    """The topics a panel's configuration names."""
    named = set(config.get('topics', {}))
    named.update(re.match(r'(/[\w/]+)', p['value']).group(1)  # type: ignore[union-attr]
                 for p in config.get('paths', []))
    for key in ('topicPath',):
        if key in config:
            named.add(config[key])
    named.update(config.get('imageMode', {}).get(k) for k in ('imageTopic', 'calibrationTopic')
                 if k in config.get('imageMode', {}))
    return named


@pytest.fixture(scope='module')
def layout() -> dict[str, Any]:
    return json.loads(LAYOUT.read_text())


def test_every_placed_panel_is_configured_and_every_configured_one_placed(layout):
    placed = _panels(layout['layout'])
    assert sorted(placed) == sorted(layout['configById'])
    assert {p.split('!')[0] for p in placed} == KINDS
    assert set(layout) >= {'configById', 'globalVariables', 'userNodes', 'layout'}


def test_every_topic_it_reads_is_a_topic_of_the_contract(layout):
    contract = {'/' + spec.name.lstrip('/') for spec in topics.ALL_TOPICS} | {topics.TF_TOPIC,
                                                                   topics.TF_STATIC_TOPIC}
    read = set().union(*(_topics_read(c) for c in layout['configById'].values()))
    assert read, 'the layout reads no topic'
    assert read <= contract, sorted(read - contract)
    assert {'/scan', '/obstacles/markers', '/mode', '/diagnostics',
            '/camera/image_raw/compressed', '/observer/odometry'} <= read


def test_the_frames_it_follows_are_the_saucers(layout):
    frames = set(yaml.safe_load((ROOT / 'params' / 'saucer_core.yaml').read_text())['frames'])
    three_d = layout['configById']['3D!saucer']
    used = {three_d['followTf']} | {layer['frameId'] for layer in three_d['layers'].values()}
    assert used <= frames, sorted(used - frames)
