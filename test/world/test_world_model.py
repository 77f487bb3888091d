"""The world model (enbarr_core.world.model): ray casts, distances and motions, each against
an answer computed by hand (the geometry is written out in each test)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.world.model import (Circle, ConstantVelocity, EMPTY_WORLD, Obstacle, Polygon,
                                     Walls, Waypoints, World)

BASIN = Walls(((-20.0, -3.225), (20.0, -3.225), (20.0, 3.225), (-20.0, 3.225)), closed=True)
EAST, NORTH, WEST, SOUTH = 0.0, math.pi / 2, math.pi, -math.pi / 2


def test_a_circle_ahead_at_a_known_distance() -> None:
    world = World([Obstacle('buoy', Circle((5.0, 0.0), 0.5))])
    # centre 5 m east, radius 0.5: the near surface 4.5 m away
    assert world.raycast((0.0, 0.0), [EAST])[0] == pytest.approx(4.5)
    # from (1, 2) towards (5, 0): the centre is sqrt(4^2 + 2^2) away, the surface 0.5 nearer
    bearing = math.atan2(-2.0, 4.0)
    assert world.raycast((1.0, 2.0), [bearing])[0] == pytest.approx(math.sqrt(20.0) - 0.5)


def test_a_ray_grazing_a_circle_off_axis() -> None:
    # circle at (3, 1), r = 1: the ray along y = 0 touches it at (3, 0) (tangent)
    world = World([Obstacle('c', Circle((3.0, 1.0), 1.0))])
    assert world.raycast((0.0, 0.0), [EAST])[0] == pytest.approx(3.0, abs=1e-6)
    # along y = 0.5: x = 3 - sqrt(1 - 0.5^2)
    assert world.raycast((0.0, 0.5), [EAST])[0] == pytest.approx(3.0 - math.sqrt(0.75))


def test_a_ray_that_misses_is_inf() -> None:
    world = World([Obstacle('buoy', Circle((5.0, 0.0), 0.5)),
                   Obstacle('quay', Walls(((0.0, 2.0), (4.0, 2.0))))])
    r = world.raycast((0.0, 0.0), [WEST, SOUTH, math.atan2(0.6, 5.0)])
    assert np.isinf(r).all()  # behind, below, and just above the buoy (0.6 > 0.5 off axis)
    assert np.isinf(EMPTY_WORLD.raycast((0.0, 0.0), [EAST, NORTH])).all()


def test_a_wall_at_an_angle() -> None:
    # the wall x + y = 4 (from (4, 0) to (0, 4)); from the origin along 45 deg it is 4/sqrt(2)
    # away, along east 4 m, along north 4 m
    world = World([Obstacle('w', Walls(((4.0, 0.0), (0.0, 4.0))))])
    r = world.raycast((0.0, 0.0), [math.pi / 4, EAST, NORTH, 3 * math.pi / 4])
    assert r[:3] == pytest.approx([4.0 / math.sqrt(2.0), 4.0, 4.0])
    assert math.isinf(r[3])  # parallel to the wall


def test_the_basin_from_its_centre() -> None:
    world = World([Obstacle('basin', BASIN)])
    r = world.raycast((0.0, 0.0), [EAST, NORTH, WEST, SOUTH, math.atan2(3.225, 20.0)])
    assert r == pytest.approx([20.0, 3.225, 20.0, 3.225, math.hypot(20.0, 3.225)])
    # from (10, 1) looking north-east at 45 deg: the north wall is 2.225 m up
    assert world.raycast((10.0, 1.0), [math.pi / 4])[0] == pytest.approx(2.225 * math.sqrt(2))


def test_occlusion_the_nearest_surface_wins() -> None:
    world = World([Obstacle('basin', BASIN), Obstacle('far', Circle((8.0, 0.0), 1.0)),
                   Obstacle('near', Circle((4.0, 0.0), 0.5)),
                   Obstacle('pier', Polygon(((6.0, -1.0), (7.0, -1.0), (7.0, 1.0),
                                             (6.0, 1.0))))])
    hits = world.cast((0.0, 0.0), [EAST, WEST])
    assert hits.ranges == pytest.approx([3.5, 20.0])
    assert [world.names[i] for i in hits.obstacle] == ['near', 'basin']
    # declaration order does not matter: the same world reversed
    rev = World(list(reversed(world.obstacles)))
    assert rev.raycast((0.0, 0.0), [EAST])[0] == pytest.approx(3.5)
    # from beyond the small buoy, the pier's west face is next (x = 6)
    assert world.raycast((5.0, 0.0), [EAST])[0] == pytest.approx(1.0)


def test_a_ray_from_inside_a_solid_meets_it_from_within() -> None:
    world = World([Obstacle('c', Circle((0.0, 0.0), 2.0))])
    assert world.raycast((0.5, 0.0), [EAST, WEST]) == pytest.approx([1.5, 2.5])


def test_a_moving_circle_at_t() -> None:
    # starts at (10, 0), moves west at 0.5 m/s: at t = 8 s its centre is at (6, 0)
    world = World([Obstacle('boat', Circle((10.0, 0.0), 0.5), ConstantVelocity((-0.5, 0.0)))])
    assert world.raycast((0.0, 0.0), [EAST], t=0.0)[0] == pytest.approx(9.5)
    assert world.raycast((0.0, 0.0), [EAST], t=8.0)[0] == pytest.approx(5.5)
    assert world.shapes_at(8.0)[0] == Circle((6.0, 0.0), 0.5)
    assert world.velocity('boat', 8.0) == (-0.5, 0.0)
    assert world.distance((0.0, 0.0), 8.0)[0] == pytest.approx(5.5)


def test_a_moving_polygon_keeps_its_shape() -> None:
    square = Polygon(((1.0, -1.0), (2.0, -1.0), (2.0, 1.0), (1.0, 1.0)))
    world = World([Obstacle('raft', square, ConstantVelocity((0.0, 1.0)))])
    # at t = 2 s the square spans y in [1, 3]: the ray east along y = 0 misses it,
    # along y = 2 it meets x = 1
    assert math.isinf(world.raycast((0.0, 0.0), [EAST], 2.0)[0])
    assert world.raycast((0.0, 2.0), [EAST], 2.0)[0] == pytest.approx(1.0)


def test_waypoints_stop_at_the_end_or_loop() -> None:
    # from (0, 0) east to (4, 0), then north to (4, 3) at 1 m/s: legs of 4 m and 3 m
    stop = Waypoints(((0.0, 0.0), (4.0, 0.0), (4.0, 3.0)), 1.0, loop=False)
    assert stop.position(2.0) == pytest.approx((2.0, 0.0))
    assert stop.velocity(2.0) == pytest.approx((1.0, 0.0))
    assert stop.position(5.0) == pytest.approx((4.0, 1.0))
    assert stop.velocity(5.0) == pytest.approx((0.0, 1.0))
    assert stop.position(100.0) == pytest.approx((4.0, 3.0))
    assert stop.velocity(100.0) == (0.0, 0.0)
    assert stop.position(-1.0) == (0.0, 0.0)
    # looping adds the leg back to the start (5 m, the 3-4-5 triangle): 12 m a round
    loop = Waypoints(((0.0, 0.0), (4.0, 0.0), (4.0, 3.0)), 2.0, loop=True)
    assert loop.length == pytest.approx(12.0)
    assert loop.position(6.0 + 1.0) == pytest.approx((2.0, 0.0))  # 14 m = one round + 2
    # on the way back, 2 m along the 5 m leg from (4, 3) towards (0, 0): (4, 3) - 2 (4, 3)/5
    assert loop.position(4.5) == pytest.approx((4.0 - 1.6, 3.0 - 1.2))
    assert loop.velocity(4.5) == pytest.approx((-1.6, -1.2))


def test_an_obstacle_on_waypoints_moves_its_shape() -> None:
    circle = Circle((0.0, 5.0), 1.0)
    world = World([Obstacle('ferry', circle,
                            Waypoints((circle.reference, (10.0, 5.0)), 2.0))])
    assert world.shapes_at(3.0)[0] == Circle((6.0, 5.0), 1.0)
    assert world.velocities(3.0).tolist() == [[2.0, 0.0]]
    # from (6, 0) looking north: the circle at (6, 5) r 1 is 4 m away
    assert world.raycast((6.0, 0.0), [NORTH], 3.0)[0] == pytest.approx(4.0)


def test_signed_distance_to_each_obstacle() -> None:
    world = World([Obstacle('basin', BASIN), Obstacle('buoy', Circle((3.0, 1.0), 0.3)),
                   Obstacle('pier', Polygon(((5.0, 3.225), (6.0, 3.225), (6.0, 2.0),
                                             (5.0, 2.0))))])
    d = world.distance((0.0, 0.0))
    # basin: the nearest wall is the north or south one, 3.225 m; buoy: sqrt(10) - 0.3;
    # pier: its nearest corner (5, 2) is sqrt(29) away
    assert d == pytest.approx([3.225, math.sqrt(10.0) - 0.3, math.sqrt(29.0)])
    inside_pier = world.distance((5.5, 3.0))
    assert inside_pier[2] == pytest.approx(-0.225)  # 0.225 below the pier's north edge
    assert world.distance((3.0, 1.1))[1] == pytest.approx(-0.2)  # inside the buoy
    # inside the basin's walls is free water: never negative
    assert world.distance((19.0, 3.0))[0] == pytest.approx(0.225)
    assert world.nearest((3.0, 1.1)) == ('buoy', pytest.approx(-0.2))
    assert EMPTY_WORLD.nearest((0.0, 0.0)) == ('', math.inf)


def test_names_are_ids_and_must_be_unique() -> None:
    world = World([Obstacle('a', Circle((0.0, 0.0), 1.0)), Obstacle('b', BASIN)])
    assert world.names == ('a', 'b') and world.index('b') == 1
    with pytest.raises(KeyError, match="no obstacle 'c'; obstacles: a, b"):
        world.index('c')
    with pytest.raises(ValueError, match='a repeated'):
        World([Obstacle('a', Circle((0.0, 0.0), 1.0)), Obstacle('a', BASIN)])


def test_the_vectorised_cast_agrees_with_a_ray_by_ray_cast() -> None:
    """A second formulation: each ray marched against each shape in plain Python."""
    rng = np.random.default_rng(3)
    world = World([Obstacle('basin', BASIN), Obstacle('b1', Circle((3.0, 1.0), 0.3)),
                   Obstacle('b2', Circle((-4.0, -1.0), 0.8), ConstantVelocity((0.2, 0.1))),
                   Obstacle('pier', Polygon(((5.0, 3.225), (6.0, 3.225), (6.0, 2.0))))])
    bearings = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    for _ in range(5):
        o = rng.uniform([-15.0, -3.0], [15.0, 3.0])
        t = float(rng.uniform(0.0, 10.0))
        got = world.raycast(o, bearings, t)
        for k, b in enumerate(bearings):
            assert got[k] == pytest.approx(_slow_cast(world, o, b, t), rel=1e-9), (o, b, t)


def _slow_cast(world: World, o: np.ndarray, b: float, t: float) -> float:
    best = math.inf
    d = (math.cos(b), math.sin(b))
    for shape in world.shapes_at(t):
        if isinstance(shape, Circle):
            fx, fy = o[0] - shape.center[0], o[1] - shape.center[1]
            bb = fx * d[0] + fy * d[1]
            disc = bb * bb - (fx * fx + fy * fy - shape.radius ** 2)
            if disc >= 0:
                for root in (-bb - math.sqrt(disc), -bb + math.sqrt(disc)):
                    if root > 1e-9:
                        best = min(best, root)
                        break
        else:
            for (ax, ay), (bx, by) in shape.segments():
                ex, ey = bx - ax, by - ay
                den = d[0] * ey - d[1] * ex
                if den == 0:
                    continue
                tt = ((ax - o[0]) * ey - (ay - o[1]) * ex) / den
                u = ((ax - o[0]) * d[1] - (ay - o[1]) * d[0]) / den
                if tt > 1e-9 and 0 <= u <= 1:
                    best = min(best, tt)
    return best


def test_waypoints_with_a_dwell_stop_at_each_waypoint() -> None:
    # 4 m east then 3 m north at 1 m/s, 2 s stopped at each waypoint: arrive at (4, 0) at 4 s,
    # leave at 6 s, arrive at (4, 3) at 9 s and stay
    wp = Waypoints(((0.0, 0.0), (4.0, 0.0), (4.0, 3.0)), 1.0, loop=False, dwell=2.0)
    assert wp.position(3.0) == pytest.approx((3.0, 0.0))
    assert wp.velocity(3.0) == pytest.approx((1.0, 0.0))
    assert wp.position(4.5) == pytest.approx((4.0, 0.0))
    assert wp.position(5.9) == pytest.approx((4.0, 0.0))
    assert wp.velocity(5.0) == (0.0, 0.0)
    assert wp.position(7.0) == pytest.approx((4.0, 1.0))
    assert wp.velocity(7.0) == pytest.approx((0.0, 1.0))
    assert wp.position(10.0) == pytest.approx((4.0, 3.0))
    assert wp.position(100.0) == pytest.approx((4.0, 3.0))
    # looping: the 5 m leg home, 2 s there too: a round is 12 m / 2 m/s + 3 x 2 s = 12 s
    loop = Waypoints(((0.0, 0.0), (4.0, 0.0), (4.0, 3.0)), 2.0, loop=True, dwell=2.0)
    assert loop.position(2.0 + 1.0) == pytest.approx((4.0, 0.0))     # stopped at (4, 0)
    assert loop.position(4.0 + 1.0) == pytest.approx((4.0, 2.0))     # 1 s into the north leg
    assert loop.position(11.0) == pytest.approx((0.0, 0.0))          # home, stopped
    assert loop.velocity(11.0) == (0.0, 0.0)
    assert loop.position(12.0 + 1.0) == pytest.approx((2.0, 0.0))    # round two
