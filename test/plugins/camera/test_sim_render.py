"""The simulated camera's rendering (sim_render): where things land in the image, against
numbers worked out by hand from the pinhole and plumb_bob equations (typed here, not read from
the code) and against OpenCV's own forward model (``cv2.projectPoints``); the distortion's
direction; occlusion; the horizon; the water; the light."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from enbarr_core.framework.frames import Transform
from enbarr_core.world.model import Circle, ConstantVelocity, Obstacle, Walls, World
from enbarr_plugins.camera.sim_render import (Look, PinholeModel, SimulatedCamera, SKY,
                                              WATER)

pytestmark = pytest.mark.unit

# The camera of these tests: 640 x 480, fx = fy = 500 px, principal point (319.5, 239.5) (the
# image's centre in OpenCV's pixel-centre convention), 0.25 m above the water, level, looking
# along base_link's x (REP-103 optical frame: rpy -90 deg, 0, -90 deg from a FLU link).
W, H, F, CX, CY, ZC = 640, 480, 500.0, 319.5, 239.5, 0.25
K = (F, 0.0, CX, 0.0, F, CY, 0.0, 0.0, 1.0)
LEVEL = Transform.from_rpy((0.0, 0.0, ZC), (-math.pi / 2, 0.0, -math.pi / 2))


def camera(d=(0.0, 0.0, 0.0, 0.0, 0.0), mount: Transform = LEVEL, **look) -> SimulatedCamera:
    return SimulatedCamera(PinholeModel(W, H, K, tuple(d)), mount, Look(**look))


def buoy(name: str, x: float, y: float, r: float = 0.2, h: float = 0.5, **kw) -> Obstacle:
    return Obstacle(name, Circle((x, y), r), height=h, **kw)


def centroid(mask: np.ndarray) -> tuple[float, float]:
    v, u = np.nonzero(mask)
    assert len(u), 'not in the image'
    return float(u.mean()), float(v.mean())


def test_a_buoy_straight_ahead_spans_the_rows_of_its_height() -> None:
    """A buoy 5 m ahead, radius 0.2, 0.5 m tall: its front face at Z = 4.8 m spans
    v = 239.5 + 500 (0.25 - z) / 4.8 for z in [0, 0.5]: rows 213.46 .. 265.54, centred on
    column 319.5."""
    f = camera().render(World([buoy('b', 5.0, 0.0)]), 0.0, 0.0, 0.0, 0.0)
    mask = f.labels == 0
    u, _ = centroid(mask)
    assert u == pytest.approx(319.5, abs=0.5)
    rows = np.nonzero(mask[:, 320])[0]
    assert (rows.min(), rows.max()) == (214, 265)
    # the tangent rays: half-width asin(0.2 / 5) = 2.29 deg, tan * 500 = 20.0 px each side
    cols = np.nonzero(mask[240])[0]
    assert cols.min() == pytest.approx(319.5 - 20.0, abs=1.0)
    assert cols.max() == pytest.approx(319.5 + 20.0, abs=1.0)


def test_the_distortion_pulls_a_point_in_by_the_plumb_bob_equation() -> None:
    """Barrel distortion k1 = -0.2: a point at x_n = 0.5, y_n = 0 lands at
    x_d = 0.5 (1 - 0.2 * 0.25) = 0.475, u = 319.5 + 500 * 0.475 = 557.0 (the pinhole's
    569.5: distortion in the wrong direction would put it beyond that)."""
    # a slim buoy 6 m ahead, 3 m to the right (y = -3 in FLU): x_n = 3 / 6 = 0.5; its middle
    # at the lens's height (0.5 tall, lens at 0.25): y_n = 0
    world = World([buoy('b', 6.0, -3.0, r=0.03)])
    u_pin, v_pin = centroid(camera().render(world, 0.0, 0.0, 0.0, 0.0).labels == 0)
    u, v = centroid(camera((-0.2, 0, 0, 0, 0)).render(world, 0.0, 0.0, 0.0, 0.0).labels == 0)
    assert u_pin == pytest.approx(569.5, abs=1.0)
    assert u == pytest.approx(557.0, abs=1.0)
    assert v == pytest.approx(239.5, abs=1.0) and v_pin == pytest.approx(239.5, abs=1.0)


@pytest.mark.parametrize('d', [(-0.25, 0.08, 0.001, -0.002, -0.01),
                               (0.1, -0.05, -0.003, 0.002, 0.0),
                               (-0.3, 0.1, 0.0, 0.0, -0.02, 0.05, 0.0, 0.0)])
@pytest.mark.parametrize('where', [(4.0, 1.5), (7.0, -3.0), (3.0, 1.6), (10.0, 0.0)])
def test_a_buoy_lands_where_opencv_projects_it(d, where) -> None:
    """The buoy's pixel centre against ``cv2.projectPoints`` of its front face's middle, with
    plumb_bob and rational_polynomial distortion, within a pixel."""
    x, y = where
    r, h = 0.04, 0.3
    f = camera(d).render(World([buoy('b', x, y, r=r, h=h)]), 0.0, 0.0, 0.0, 0.0)
    u, v = centroid(f.labels == 0)
    # the front face's middle: the axis point r nearer, h / 2 up; in the optical frame
    # (x right = -y, y down = zc - z, z ahead = x)
    dist = math.hypot(x, y)
    px, py = x - r * x / dist, y - r * y / dist
    p = np.array([[[-py, ZC - h / 2, px]]])
    (expected,), _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3),
                                       np.array(K).reshape(3, 3), np.array(d))
    assert (u, v) == pytest.approx(tuple(expected[0]), abs=1.0)


def test_the_horizon_is_the_principal_row_however_high_the_lens() -> None:
    """An empty sea, a level camera: rows above 239.5 are sky, rows below water, in every
    column; barrel distortion leaves the line y_n = 0 straight; yaw and height change
    nothing."""
    for d in [(0, 0, 0, 0, 0), (-0.2, 0.05, 0, 0, 0)]:
        cam = camera(d)
        for z, psi in [(0.0, 0.0), (0.75, 1.0)]:
            lab = cam.render(World(), 3.0, -1.0, psi, 0.0, z=z).labels
            assert np.all(lab[:240] == SKY)
            assert np.all(lab[240:] == WATER)


def test_a_near_buoy_hides_a_far_one_whatever_their_order() -> None:
    near, far = buoy('near', 3.0, 0.0, r=0.3), buoy('far', 6.0, 0.0, r=0.3)
    for world in (World([near, far]), World([far, near])):
        lab = camera().render(world, 0.0, 0.0, 0.0, 0.0).labels
        i_near, i_far = world.index('near'), world.index('far')
        assert np.count_nonzero(lab == i_near) > 1000
        assert np.count_nonzero(lab == i_far) == 0
    # a taller far one shows above the near one, and only there
    tall = buoy('far', 6.0, 0.0, r=0.3, h=2.0)
    lab = camera().render(World([near, tall]), 0.0, 0.0, 0.0, 0.0).labels
    rows = np.nonzero(lab[:, 320] == 1)[0]
    near_top = 239.5 + 500.0 * (0.25 - 0.5) / 2.7  # 193.2: the near buoy's top
    assert len(rows) and rows.max() < near_top
    assert rows.min() == math.ceil(239.5 + 500.0 * (0.25 - 2.0) / 5.7)  # 86.0 -> 86


def test_a_buoy_before_a_wall_that_comes_nearer_is_seen() -> None:
    """A wall along the right side, from 0.5 m ahead to 20 m, 1 m tall, and a buoy 3 m
    ahead 0.5 m right of the axis: the wall's nearest point is nearer than the buoy, yet
    the buoy stands in front of the wall where they overlap (a painter's order by nearest
    point gets this wrong)."""
    wall = Obstacle('wall', Walls(((0.5, -1.0), (20.0, -1.0))))
    world = World([wall, buoy('b', 3.0, -0.5, r=0.1)])
    lab = camera().render(world, 0.0, 0.0, 0.0, 0.0).labels
    u, v = centroid(lab == 1)
    assert u == pytest.approx(319.5 + 500.0 * 0.5 / 3.0, abs=1.0)  # 402.8
    assert np.count_nonzero(lab == 0) > 1000
    # the wall is behind the buoy there: around it, at the same rows, the wall
    assert lab[int(v), int(u) + 25] == 0


def test_a_wall_ahead_spans_the_rows_of_its_height() -> None:
    """A wall 4 m ahead across the view, 1 m tall: rows 239.5 + 500 (0.25 - z) / 4, from
    145.75 (z = 1) to 270.75 (the water)."""
    lab = camera().render(World([Obstacle('w', Walls(((4.0, -10.0), (4.0, 10.0))))]),
                          0.0, 0.0, 0.0, 0.0).labels
    rows = np.nonzero(lab[:, 100] == 0)[0]
    assert (rows.min(), rows.max()) == (146, 270)
    assert np.all(lab[:146, 100] == SKY) and np.all(lab[271:, 100] == WATER)


def test_a_moving_buoy_is_drawn_where_it_is_at_the_time() -> None:
    world = World([Obstacle('b', Circle((6.0, 0.0), 0.05), ConstantVelocity((0.0, -1.0)),
                            height=0.5)])
    u0, _ = centroid(camera().render(world, 0.0, 0.0, 0.0, 0.0).labels == 0)
    u2, _ = centroid(camera().render(world, 0.0, 0.0, 0.0, 2.0).labels == 0)
    assert u0 == pytest.approx(319.5, abs=1.0)
    assert u2 == pytest.approx(319.5 + 500.0 * 2.0 / 6.0, abs=1.0)  # 486.2: 2 m right


def test_the_vessel_pose_and_a_yawed_mount_move_the_view() -> None:
    """The vessel at (1, 2) heading north (90 deg) sees a buoy at (1, 7) straight ahead; a
    camera mounted looking left (yaw +90 deg on the link) sees one at (-4, 0) from the
    origin straight ahead."""
    f = camera().render(World([buoy('b', 1.0, 7.0, r=0.05)]), 1.0, 2.0, math.pi / 2, 0.0)
    assert centroid(f.labels == 0)[0] == pytest.approx(319.5, abs=1.0)
    left = Transform.from_rpy((0.0, 0.0, ZC), (-math.pi / 2, 0.0, 0.0))
    f = camera(mount=left).render(World([buoy('b', 0.0, 5.0, r=0.05)]), 0.0, 0.0, 0.0, 0.0)
    assert centroid(f.labels == 0)[0] == pytest.approx(319.5, abs=1.0)
    # a camera 1 m behind the CO, the vessel at (1, 2) heading north: the lens at (1, 1); a
    # buoy at (0.5, 7) is 6 m ahead and 0.5 m to the left (west): u = 319.5 - 500 * 0.5 / 6
    behind = Transform.from_rpy((-1.0, 0.0, ZC), (-math.pi / 2, 0.0, -math.pi / 2))
    f = camera(mount=behind).render(World([buoy('b', 0.5, 7.0, r=0.05)]), 1.0, 2.0,
                                    math.pi / 2, 0.0)
    assert centroid(f.labels == 0)[0] == pytest.approx(319.5 - 500.0 * 0.5 / 6.0, abs=1.0)


def test_a_tilted_mount_is_refused() -> None:
    tilted = Transform.from_rpy((0.0, 0.0, ZC), (-math.pi / 2 - 0.1, 0.0, -math.pi / 2))
    with pytest.raises(ValueError, match='must be level'):
        camera(mount=tilted)


def test_the_lit_side_of_a_buoy_is_the_suns() -> None:
    """The sun in the north (azimuth 90 deg): looking east, a buoy's left (north) half is
    brighter than its right half; from the west the other way round."""
    world = World([buoy('b', 4.0, 0.0, r=0.4, colour=(200, 200, 200))])
    for psi, brighter in [(0.0, 'left'), (math.pi, 'right')]:
        cam = camera(sun_azimuth=math.pi / 2)
        x = 8.0 if psi else 0.0
        f = cam.render(world, x, 0.0, psi, 0.0)
        mask = f.labels == 0
        grey = f.image.mean(axis=2)
        u, _ = centroid(mask)
        left = grey[mask & (np.arange(W)[None, :] < u)].mean()
        right = grey[mask & (np.arange(W)[None, :] > u)].mean()
        assert (left > right + 20) if brighter == 'left' else (right > left + 20)


def test_colours_go_out_as_bgr() -> None:
    """A red buoy (r, g, b = 220, 30, 30) lit head-on: its pixels' last channel (red in
    BGR) dominates."""
    f = camera(sun_azimuth=math.pi).render(
        World([buoy('b', 3.0, 0.0, colour=(220, 30, 30))]), 0.0, 0.0, 0.0, 0.0)
    b, g, r = f.image[f.labels == 0].mean(axis=0)
    assert r > 150 and g < 60 and b < 60


def test_the_water_is_textured_fixed_in_the_world_and_seeded() -> None:
    cam = camera()
    one = cam.render(World(), 0.0, 0.0, 0.0, 0.0).image
    water = one[300:]
    assert water.std() > 5.0  # ripples, not a flat colour
    assert np.array_equal(one, camera().render(World(), 0.0, 0.0, 0.0, 0.0).image)
    moved = cam.render(World(), 0.7, 0.0, 0.0, 0.0).image
    assert not np.array_equal(moved[300:], water)
    assert np.array_equal(moved[:200], one[:200])  # the sky does not move
    assert not np.array_equal(camera(seed=2).render(World(), 0.0, 0.0, 0.0, 0.0).image, one)


def test_a_fisheye_or_a_bad_model_is_refused() -> None:
    with pytest.raises(ValueError, match='distortion model'):
        PinholeModel(W, H, K, (0.1, 0.0, 0.0, 0.0), 'equidistant')
    with pytest.raises(ValueError, match='fx, fy > 0'):
        PinholeModel(W, H, (0.0,) * 9)
    with pytest.raises(ValueError, match='cannot be inverted'):
        camera((-0.9, 0.0, 0.0, 0.0, 0.0))
