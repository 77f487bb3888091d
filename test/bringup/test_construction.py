"""Building a profile's nodes publishes nothing.

``bringup --check`` and a run that the vessel guard refuses build nodes that must not act on
the graph: a latched ``mode: manual`` from a constructor switched a running vessel's guidance
to manual. Every node publishes its first state at ``start()``. This builds every runnable
profile's nodes (with a recorder) the way a check does and watches every publish.
"""

from __future__ import annotations

from typing import Any

import pytest
from rclpy.publisher import Publisher

from enbarr_core.bringup.compose import _safely, add_recorder, build_nodes
from enbarr_core.bringup.profile import load_profile, with_record
from enbarr_interfaces.links import LinkPublisher

#: What a test needs to build a profile at all: the keyboard's terminal (not stdin under pytest).
OVERRIDES = {'enbarr_teleop': ['keyboard.device=/dev/tty'],
             'enbarr_rov_topside_keyboard': ['keyboard.device=/dev/tty']}
RUNNABLE = ('enbarr_sim', 'enbarr_teleop', 'enbarr_rov', 'enbarr_rov_emulated',
            'enbarr_rov_topside', 'enbarr_rov_topside_keyboard', 'enbarr_rov_pad_sim', 'saucer',
            'saucer_sim', 'saucer_emulated', 'skiff_sim')


@pytest.mark.parametrize('name', RUNNABLE)
def test_building_a_profile_publishes_nothing(name: str, context: Any, tmp_path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    published: list[str] = []

    def spy(self: Any, msg: Any) -> None:
        # rclpy's own announcements of declared parameters are not a node's doing.
        if self.topic_name not in ('/parameter_events', '/rosout'):
            published.append(self.topic_name)
    for cls in (Publisher, LinkPublisher):
        monkeypatch.setattr(cls, 'publish', spy)
    profile = add_recorder(with_record(load_profile(name, OVERRIDES.get(name, [])),
                                       str(tmp_path / 'bag')))
    nodes = build_nodes(profile, context)
    try:
        assert len(nodes) == len(profile.nodes)
    finally:
        for n in reversed(nodes):
            _safely(n.destroy_node, 'destroying')
    assert published == []
    assert not (tmp_path / 'bag').exists()  # the recorder opens its bag at start
