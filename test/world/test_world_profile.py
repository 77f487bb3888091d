"""A profile's ``world`` section (enbarr_core.world.parse through load_profile): what it
builds, how includes merge it, and each refusal with the file and key that set it."""

from __future__ import annotations

from pathlib import Path
import textwrap

import pytest

from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import ProfileError
from enbarr_core.world.model import (Circle, ConstantVelocity, Polygon, Static, Walls,
                                     Waypoints)
from enbarr_core.world.parse import parse_world

HEAD = 'nodes: {recorder: {plugin: recorder}}\n'


def write(path: Path, text: str) -> str:
    path.write_text(textwrap.dedent(text).lstrip('\n'), encoding='utf-8')
    return str(path)


def refusal(tmp_path: Path, world: str) -> ProfileError:
    path = write(tmp_path / 'w.yaml', HEAD + 'world:\n' + textwrap.indent(
        textwrap.dedent(world).strip('\n'), '  ') + '\n')
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    assert info.value.path == path
    return info.value


def test_a_world_section_builds_every_kind_and_motion(tmp_path: Path) -> None:
    path = write(tmp_path / 'p.yaml', """
        nodes: {recorder: {plugin: recorder}}
        world:
          basin: {kind: walls, points: [[-20, -3.225], [20, -3.225], [20, 3.225],
                                        [-20, 3.225]], closed: true}
          buoy: {kind: circle, center: [3.0, 1.0], radius: 0.3}
          pier: {kind: polygon, points: [[5, 3.225], [6, 3.225], [6, 2.0]]}
          drifter: {kind: circle, center: [8, -1], radius: 0.4, velocity: [-0.1, 0.0]}
          ferry: {kind: circle, center: [-5, 0], radius: 0.5, waypoints: [[5, 0], [5, 2]],
                  speed: 0.3, loop: true}
        """)
    world = load_profile(path).world
    assert world.names == ('basin', 'buoy', 'pier', 'drifter', 'ferry')
    basin, buoy, pier, drifter, ferry = world.obstacles
    assert basin.shape == Walls(((-20.0, -3.225), (20.0, -3.225), (20.0, 3.225),
                                 (-20.0, 3.225)), closed=True)
    assert (buoy.shape, buoy.motion) == (Circle((3.0, 1.0), 0.3), Static())
    assert pier.shape == Polygon(((5.0, 3.225), (6.0, 3.225), (6.0, 2.0)))
    assert drifter.motion == ConstantVelocity((-0.1, 0.0))
    assert ferry.motion == Waypoints(((-5.0, 0.0), (5.0, 0.0), (5.0, 2.0)), 0.3, loop=True)


def test_height_and_colour_are_given_or_the_kinds() -> None:
    """A buoy, a hull and walls without a look get their kind's; given ones are kept (a
    colour by name or as [r, g, b])."""
    world = parse_world({
        'basin': {'kind': 'walls', 'points': [[0, 0], [1, 0]]},
        'buoy': {'kind': 'circle', 'center': [0, 0], 'radius': 0.2},
        'hull': {'kind': 'polygon', 'points': [[0, 0], [1, 0], [1, 1]]},
        'red_buoy': {'kind': 'circle', 'center': [0, 0], 'radius': 0.2, 'height': 1.2,
                     'colour': 'red'},
        'boat': {'kind': 'circle', 'center': [0, 0], 'radius': 0.2, 'colour': [1, 2, 3]}})
    looks = {o.name: (o.height, o.colour) for o in world.obstacles}
    assert looks == {'basin': (1.0, (150, 150, 145)), 'buoy': (0.5, (255, 110, 0)),
                     'hull': (0.4, (225, 225, 220)), 'red_buoy': (1.2, (220, 30, 30)),
                     'boat': (0.5, (1, 2, 3))}


def test_no_world_is_an_empty_world(tmp_path: Path) -> None:
    assert not load_profile(write(tmp_path / 'p.yaml', HEAD)).world
    assert not parse_world(None) and not parse_world({})


def test_an_include_merges_the_world_key_by_key(tmp_path: Path) -> None:
    write(tmp_path / 'base.yaml', """
        nodes: {recorder: {plugin: recorder}}
        world:
          buoy: {kind: circle, center: [3.0, 1.0], radius: 0.3}
          old: {kind: walls, points: [[0, 0], [1, 0]]}
        """)
    child = write(tmp_path / 'child.yaml', """
        include: [base.yaml]
        world:
          buoy: {radius: 0.5}
          old: {enabled: false}
          new: {kind: circle, center: [0, 0], radius: 1.0}
        """)
    world = load_profile(child).world
    assert world.names == ('buoy', 'new')
    assert world.obstacles[0].shape == Circle((3.0, 1.0), 0.5)


def test_an_error_names_the_file_that_set_the_key(tmp_path: Path) -> None:
    base = write(tmp_path / 'base.yaml', """
        nodes: {recorder: {plugin: recorder}}
        world:
          buoy: {kind: circle, center: [3.0, 1.0], radius: -0.3}
        """)
    child = write(tmp_path / 'child.yaml', """
        include: [base.yaml]
        world:
          buoy: {center: [3.0, 2.0]}
        """)
    with pytest.raises(ProfileError) as info:
        load_profile(child)
    assert str(info.value) == f'{base}: world.buoy.radius: expected a radius > 0 [m], got -0.3'


@pytest.mark.parametrize('world, key, message', [
    ('[1, 2]', 'world', 'expected a mapping of obstacle names, got list'),
    ('b-1: {kind: circle}', 'world.b-1', 'an obstacle name is letters, digits and _'),
    ('buoy: 3', 'world.buoy', 'expected a mapping (kind: circle | polygon | walls, ...), got int'),
    ('buoy: {center: [0, 0], radius: 1}', 'world.buoy.kind',
     'no kind; expected one of: circle, polygon, walls'),
    ('buoy: {kind: circel, center: [0, 0], radius: 1}', 'world.buoy.kind',
     "unknown kind 'circel' (did you mean 'circle'?); expected one of: circle, polygon, walls"),
    ('buoy: {kind: circle, centre: [0, 0], radius: 1}', 'world.buoy.centre',
     "unknown key (did you mean 'center'?); expected one of: kind, enabled, velocity"),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, points: [[0, 0], [1, 1]]}',
     'world.buoy.points', 'not a key of a circle (its keys: center, radius, kind'),
    ('buoy: {kind: circle, radius: 1}', 'world.buoy.center', 'a circle needs its center'),
    ('buoy: {kind: circle, center: [0, 0]}', 'world.buoy.radius', 'a circle needs its radius'),
    ('buoy: {kind: circle, center: [0, 0], radius: -1}', 'world.buoy.radius',
     'expected a radius > 0 [m], got -1.0'),
    ('buoy: {kind: circle, center: [0, 0], radius: 0}', 'world.buoy.radius',
     'expected a radius > 0 [m], got 0.0'),
    ('buoy: {kind: circle, center: [0, .nan], radius: 1}', 'world.buoy.center',
     'expected a finite number, got nan'),
    ('buoy: {kind: circle, center: [.inf, 0], radius: 1}', 'world.buoy.center',
     'expected a finite number, got inf'),
    ('buoy: {kind: circle, center: [0, 0, 0], radius: 1}', 'world.buoy.center',
     'expected [x, y] [m], got [0, 0, 0]'),
    ('buoy: {kind: circle, center: [0, 0], radius: big}', 'world.buoy.radius',
     "expected a number, got 'big'"),
    ('buoy: {kind: circle, center: [0, 0], radius: true}', 'world.buoy.radius',
     'expected a number, got True'),
    ('pier: {kind: polygon, points: [[0, 0], [1, 0]]}', 'world.pier.points',
     'a polygon needs at least 3 points, got 2'),
    ('quay: {kind: walls, points: [[0, 0]]}', 'world.quay.points',
     'a walls needs at least 2 points, got 1'),
    ('quay: {kind: walls}', 'world.quay.points', 'a walls needs its points'),
    ('quay: {kind: walls, points: [[0, 0], [1, .nan]]}', 'world.quay.points[1]',
     'expected a finite number, got nan'),
    ('quay: {kind: walls, points: [[0, 0], [1, 1]], closed: 1}', 'world.quay.closed',
     'expected true or false, got 1'),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, enabled: no}', 'world.buoy.enabled',
     "expected true or false, got 'no'"),
    ('boat: {kind: circle, center: [0, 0], radius: 1, waypoints: [[1, 1]]}', 'world.boat.speed',
     'a moving obstacle needs its speed [m/s] along the waypoints'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, waypoints: [[1, 1]], speed: 0}',
     'world.boat.speed', 'expected a speed > 0 [m/s], got 0.0'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, waypoints: [], speed: 1}',
     'world.boat.waypoints', 'expected at least one waypoint'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, speed: 1}', 'world.boat.speed',
     'only with waypoints'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, velocity: [1, 0], waypoints: [[1, 1]]}',
     'world.boat.velocity', 'give a velocity or waypoints (with a speed), not both'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, velocity: [1, 0], speed: 1}',
     'world.boat.speed', 'only with waypoints (a velocity sets the speed)'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, velocity: [1, .inf]}',
     'world.boat.velocity', 'expected a finite number, got inf'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, waypoints: [[1, 1]], speed: 1, '
     'loop: 2}', 'world.boat.loop', 'expected true or false, got 2'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, waypoints: [[1, 1]], speed: 1, '
     'dwell: -1}', 'world.boat.dwell', 'expected a dwell >= 0 [s] at each waypoint, got -1.0'),
    ('boat: {kind: circle, center: [0, 0], radius: 1, dwell: 2}', 'world.boat.dwell',
     'only with waypoints'),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, height: 0}', 'world.buoy.height',
     'expected a height > 0 [m] above the water, got 0.0'),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, height: tall}', 'world.buoy.height',
     "expected a number, got 'tall'"),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, colour: orang}', 'world.buoy.colour',
     "unknown colour 'orang' (did you mean 'orange'?)"),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, colour: [255, 0]}', 'world.buoy.colour',
     'expected a colour name (red, green'),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, colour: [256, 0, 0]}',
     'world.buoy.colour', 'integers 0..255, got [256, 0, 0]'),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, colour: [1.5, 0, 0]}',
     'world.buoy.colour', 'integers 0..255, got [1.5, 0, 0]'),
    ('buoy: {kind: circle, center: [0, 0], radius: 1, color: red}', 'world.buoy.color',
     "unknown key (did you mean 'colour'?)"),
])
def test_each_bad_world_is_refused_with_its_key(tmp_path: Path, world: str, key: str,
                                                message: str) -> None:
    err = refusal(tmp_path, world)
    assert err.key == key
    assert message in str(err)
    assert str(err).startswith(f'{err.path}: {key}: ')
