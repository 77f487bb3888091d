"""A profile's ``world`` section, checked and built into a ``World`` (no ROS).

The section maps obstacle names to their description (``docs/profiles.md``)::

    world:
      basin:   {kind: walls, points: [[-20, -3.225], [20, -3.225], [20, 3.225], [-20, 3.225]],
                closed: true}
      buoy:    {kind: circle, center: [3.0, 1.0], radius: 0.3, height: 0.6, colour: red}
      pier:    {kind: polygon, points: [[5, 3.225], [6, 3.225], [6, 2.0], [5, 2.0]]}
      drifter: {kind: circle, center: [8, -1], radius: 0.4, velocity: [-0.1, 0.0]}
      ferry:   {kind: circle, center: [-5, 0], radius: 0.5, waypoints: [[5, 0], [5, 2]],
                speed: 0.3, loop: true}
      old:     {enabled: false}        # drops an obstacle an included profile declared

``height`` [m] above the water and ``colour`` (a name of ``COLOURS`` or [r, g, b], 0..255)
are how the simulated camera draws the obstacle; without them, its kind's defaults
(``model.DEFAULT_HEIGHT``, ``model.DEFAULT_COLOUR``).

Profiles merge key by key (``include``), so a scenario can move or resize an obstacle of the
profile it includes. Every refusal is a ``ProfileError`` naming the file that set the key and
the key itself (``world.buoy.radius``).
"""

from __future__ import annotations

from collections.abc import Callable
import math
import re
from typing import Any

from enbarr_core.framework.errors import ProfileError
from enbarr_core.framework.registry import did_you_mean
from enbarr_core.world.model import (Circle, Colour, ConstantVelocity, EMPTY_WORLD, Motion,
                                     Obstacle, Point, Polygon, Shape, Static, Walls, Waypoints,
                                     World)

KINDS = ('circle', 'polygon', 'walls')
#: Keys every obstacle may have, then the keys of each kind.
COMMON_KEYS = ('kind', 'enabled', 'velocity', 'waypoints', 'speed', 'loop', 'dwell',
               'height', 'colour')
KIND_KEYS = {'circle': ('center', 'radius'), 'polygon': ('points',),
             'walls': ('points', 'closed')}
ALL_KEYS = COMMON_KEYS + ('center', 'radius', 'points', 'closed')
#: Fewest points of a shape.
MIN_POINTS = {'polygon': 3, 'walls': 2}
#: Colours by name (r, g, b): buoys' and hulls' usual ones.
COLOURS: dict[str, Colour] = {
    'red': (220, 30, 30), 'green': (30, 160, 60), 'yellow': (250, 210, 20),
    'orange': (255, 110, 0), 'white': (235, 235, 230), 'black': (25, 25, 25),
    'grey': (150, 150, 145), 'blue': (30, 70, 200)}
_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')

Refuse = Callable[[str, str], ProfileError]


def parse_world(raw: Any, where: Callable[[str], str] | str = '') -> World:
    """Check a profile's ``world`` section and build its ``World`` (None: ``EMPTY_WORLD``).

    ``where(key)`` names the file that set ``key`` (a dotted key such as
    ``world.buoy.radius``); every refusal is a ``ProfileError`` naming that file and key.
    """
    def refuse(message: str, key: str) -> ProfileError:
        return ProfileError(message, path=where(key) if callable(where) else where, key=key)

    if raw is None:
        return EMPTY_WORLD
    if not isinstance(raw, dict):
        raise refuse(f'expected a mapping of obstacle names, got {_kind(raw)}', 'world')
    obstacles = []
    for name, entry in raw.items():
        key = f'world.{name}'
        if not isinstance(name, str) or not _NAME.match(name):
            raise refuse('an obstacle name is letters, digits and _, starting with a letter',
                         key)
        if not isinstance(entry, dict):
            raise refuse(f'expected a mapping (kind: {" | ".join(KINDS)}, ...), got '
                         f'{_kind(entry)}', key)
        enabled = entry.get('enabled', True)
        if not isinstance(enabled, bool):
            raise refuse(f'expected true or false, got {enabled!r}', f'{key}.enabled')
        if not enabled:
            continue
        obstacles.append(_obstacle(name, entry, key, refuse))
    return World(obstacles) if obstacles else EMPTY_WORLD


def _obstacle(name: str, entry: dict[str, Any], key: str, refuse: Refuse) -> Obstacle:
    for k in entry:
        if k not in ALL_KEYS:
            raise refuse(f'unknown key{did_you_mean(str(k), ALL_KEYS)}; expected one of: '
                         f'{", ".join(ALL_KEYS)}', f'{key}.{k}')
    kind = entry.get('kind')
    if kind is None:
        raise refuse(f'no kind; expected one of: {", ".join(KINDS)}', f'{key}.kind')
    if kind not in KINDS:
        raise refuse(f'unknown kind {kind!r}{did_you_mean(str(kind), KINDS)}; expected one '
                     f'of: {", ".join(KINDS)}', f'{key}.kind')
    for k in entry:
        if k in ALL_KEYS and k not in COMMON_KEYS and k not in KIND_KEYS[kind]:
            raise refuse(f'not a key of a {kind} (its keys: '
                         f'{", ".join(KIND_KEYS[kind] + COMMON_KEYS)})', f'{key}.{k}')
    shape: Shape
    if kind == 'circle':
        for k in ('center', 'radius'):
            if k not in entry:
                raise refuse(f'a circle needs its {k}', f'{key}.{k}')
        center = _point(entry['center'], refuse, f'{key}.center')
        radius = _number(entry['radius'], refuse, f'{key}.radius')
        if not radius > 0.0:
            raise refuse(f'expected a radius > 0 [m], got {radius}', f'{key}.radius')
        shape = Circle(center, radius)
    else:
        if 'points' not in entry:
            raise refuse(f'a {kind} needs its points: a list of [x, y] [m]', f'{key}.points')
        points = _points(entry['points'], refuse, f'{key}.points')
        if len(points) < MIN_POINTS[kind]:
            raise refuse(f'a {kind} needs at least {MIN_POINTS[kind]} points, got '
                         f'{len(points)}', f'{key}.points')
        if kind == 'polygon':
            shape = Polygon(points)
        else:
            closed = entry.get('closed', False)
            if not isinstance(closed, bool):
                raise refuse(f'expected true or false, got {closed!r}', f'{key}.closed')
            shape = Walls(points, closed)
    look: dict[str, Any] = {}  # what is not given is the kind's (Obstacle's defaults)
    if 'height' in entry:
        look['height'] = _number(entry['height'], refuse, f'{key}.height')
        if not look['height'] > 0.0:
            raise refuse(f'expected a height > 0 [m] above the water, got {look["height"]}',
                         f'{key}.height')
    if 'colour' in entry:
        look['colour'] = _colour(entry['colour'], refuse, f'{key}.colour')
    return Obstacle(name, shape, _motion(entry, shape, key, refuse), **look)


def _colour(v: Any, refuse: Refuse, key: str) -> Colour:
    if isinstance(v, str):
        if v not in COLOURS:
            raise refuse(f'unknown colour {v!r}{did_you_mean(v, tuple(COLOURS))}; a name ('
                         f'{", ".join(COLOURS)}) or [r, g, b] 0..255', key)
        return COLOURS[v]
    if (not isinstance(v, (list, tuple)) or len(v) != 3 or any(
            isinstance(c, bool) or not isinstance(c, int) or not 0 <= c <= 255 for c in v)):
        raise refuse(f'expected a colour name ({", ".join(COLOURS)}) or [r, g, b], integers '
                     f'0..255, got {v!r}', key)
    return int(v[0]), int(v[1]), int(v[2])


def _motion(entry: dict[str, Any], shape: Shape, key: str, refuse: Refuse) -> Motion:
    if 'velocity' in entry and 'waypoints' in entry:
        raise refuse('give a velocity or waypoints (with a speed), not both',
                     f'{key}.velocity')
    if 'velocity' in entry:
        for k in ('speed', 'loop', 'dwell'):
            if k in entry:
                raise refuse('only with waypoints (a velocity sets the speed)', f'{key}.{k}')
        v = _point(entry['velocity'], refuse, f'{key}.velocity')
        return ConstantVelocity(v) if v != (0.0, 0.0) else Static()
    if 'waypoints' not in entry:
        for k in ('speed', 'loop', 'dwell'):
            if k in entry:
                raise refuse('only with waypoints: the points [x, y] [m] the obstacle goes '
                             'through', f'{key}.{k}')
        return Static()
    points = _points(entry['waypoints'], refuse, f'{key}.waypoints')
    if not points:
        raise refuse('expected at least one waypoint [x, y] [m]', f'{key}.waypoints')
    if 'speed' not in entry:
        raise refuse('a moving obstacle needs its speed [m/s] along the waypoints',
                     f'{key}.speed')
    speed = _number(entry['speed'], refuse, f'{key}.speed')
    if not speed > 0.0:
        raise refuse(f'expected a speed > 0 [m/s], got {speed}', f'{key}.speed')
    loop = entry.get('loop', False)
    if not isinstance(loop, bool):
        raise refuse(f'expected true or false, got {loop!r}', f'{key}.loop')
    dwell = _number(entry.get('dwell', 0.0), refuse, f'{key}.dwell')
    if dwell < 0.0:
        raise refuse(f'expected a dwell >= 0 [s] at each waypoint, got {dwell}', f'{key}.dwell')
    return Waypoints((shape.reference, *points), speed, loop, dwell)


def _kind(v: Any) -> str:
    return 'nothing' if v is None else type(v).__name__


def _number(v: Any, refuse: Refuse, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise refuse(f'expected a number, got {v!r}', key)
    if not math.isfinite(v):
        raise refuse(f'expected a finite number, got {v!r}', key)
    return float(v)


def _point(v: Any, refuse: Refuse, key: str) -> Point:
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise refuse(f'expected [x, y] [m], got {v!r}', key)
    return _number(v[0], refuse, key), _number(v[1], refuse, key)


def _points(v: Any, refuse: Refuse, key: str) -> tuple[Point, ...]:
    if not isinstance(v, (list, tuple)):
        raise refuse(f'expected a list of points [x, y] [m], got {_kind(v)}', key)
    return tuple(_point(p, refuse, f'{key}[{i}]') for i, p in enumerate(v))
