"""The mark pairs of manual 4.2 (enbarr_core.vision.marks): still poses from scans of a known
world, the region filter, the pairing of images by stamp, the blob and the click picker, each
against an answer written out in the test."""

from __future__ import annotations

import math

import matplotlib
import numpy as np
import pytest

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.vision import marks
from enbarr_core.world.model import Circle, Obstacle, Walls, World

pytestmark = pytest.mark.unit

RAYS = 360
ANGLES = -math.pi + np.arange(RAYS) * (2.0 * math.pi / RAYS)
WALL = Obstacle('wall', Walls(((4.0, -3.0), (4.0, 3.0)), closed=False))
REGION = (0.5, 3.0, -1.0, 1.0)
SEC = 1_000_000_000


def ranges(*centres: tuple[float, float], radius: float = 0.1) -> np.ndarray:
    """Ranges of a noise-free scan from (0, 0): the wall 4 m ahead and poles at ``centres``."""
    world = World([WALL] + [Obstacle(f'p{i}', Circle(c, radius)) for i, c in enumerate(centres)])
    return world.raycast((0.0, 0.0), ANGLES, 0.0)


def image(pixel: tuple[float, float]) -> np.ndarray:
    """A stand-in image whose 'blob' is at ``pixel`` (read back by ``pixel_of``)."""
    return np.array(pixel, dtype=float).reshape(1, 1, 2)


def pixel_of(img: np.ndarray) -> tuple[float, float]:
    return float(img[0, 0, 0]), float(img[0, 0, 1])


def timeline(collector: marks.PairCollector, path: list[tuple[float, tuple[float, float]]],
             pixel: dict[tuple[float, float], tuple[float, float]],
             lag: int = 0) -> list[marks.MarkPose]:
    """Scans at 5 Hz, images at 10 Hz along ``path``; each image arrives ``lag`` scans late
    (a camera pipeline slower than the lidar's), stamped when it was taken."""
    late: list[tuple[int, np.ndarray]] = []
    for k, (t, c) in enumerate(path):
        stamp = int(round(t * SEC))
        collector.add_scan(stamp, ranges(c), -math.pi, 2 * math.pi / RAYS)
        late += [(stamp + int(dt * SEC), image(pixel[c])) for dt in (0.0, 0.1)]
        while len(late) > 2 * lag:
            collector.add_image(*late.pop(0))
    for stamp, img in late:
        collector.add_image(stamp, img)
    return collector.finish()


def hold_and_move() -> tuple[list, dict]:
    """Held at A for 2 s, moving 0.4 s, held at B for 2 s, then gone (moving away)."""
    a, b = (1.5, 0.4), (2.5, -0.5)
    moving = [(1.7, 0.2), (2.0, 0.0), (2.3, -0.3)]
    path = ([(0.2 * k, a) for k in range(11)]
            + [(2.2 + 0.2 * k, m) for k, m in enumerate(moving)]
            + [(2.8 + 0.2 * k, b) for k in range(11)]
            + [(5.0, (2.9, 0.9))])
    pixel = {a: (100.0, 250.0), b: (500.0, 245.0), (2.9, 0.9): (50.0, 240.0)}
    pixel.update({m: (300.0, 100.0) for m in moving})   # far off: a moving frame must not count
    return path, pixel


def test_two_still_places_give_two_pairs_with_their_own_images() -> None:
    path, pixel = hold_and_move()
    c = marks.PairCollector(marks.MarkSettings(region=REGION, radius=0.1, min_still=1.0),
                            pixel_of)
    poses = timeline(c, path, pixel)
    assert len(poses) == 2
    a, b = poses
    # the poles' centres, fitted behind the near-side points with the known radius
    assert a.centre == pytest.approx([1.5, 0.4], abs=2e-3)
    assert b.centre == pytest.approx([2.5, -0.5], abs=2e-3)
    # arriving and leaving scans left out: 9 of the 11 at each place
    assert (a.scans, b.scans) == (9, 9)
    assert (a.start_ns, a.end_ns) == (int(0.2 * SEC), int(1.8 * SEC))
    # only the images stamped within each still time, none of the moving ones
    assert a.images == len(a.pixels) == 17
    marks.colour_pixels(poses)
    assert a.pixel == pytest.approx((100.0, 250.0))
    assert b.pixel == pytest.approx((500.0, 245.0))


def test_images_arriving_after_the_scans_still_pair_by_their_stamps() -> None:
    path, pixel = hold_and_move()
    c = marks.PairCollector(marks.MarkSettings(region=REGION, radius=0.1), pixel_of)
    poses = timeline(c, path, pixel, lag=3)
    assert [p.images for p in poses] == [17, 17]
    marks.colour_pixels(poses)
    assert [p.pixel for p in poses] == [(100.0, 250.0), (500.0, 245.0)]


def test_a_mark_held_too_briefly_is_no_pair() -> None:
    path, pixel = hold_and_move()
    # held 2 s, less the two edge scans: 1.6 s of stillness at each place
    c = marks.PairCollector(marks.MarkSettings(region=REGION, min_still=1.7), pixel_of)
    assert timeline(c, path, pixel) == []
    c = marks.PairCollector(marks.MarkSettings(region=REGION, min_still=1.5), pixel_of)
    assert len(timeline(c, path, pixel)) == 2


def test_a_mark_moving_slowly_is_not_still() -> None:
    # 5 cm a scan for 3 s: each scan close to the last, but it wanders off the run's mean
    path = [(0.2 * k, (1.5 + 0.05 * k, 0.0)) for k in range(16)]
    pixel = {c: (320.0, 240.0) for _, c in path}
    c = marks.PairCollector(marks.MarkSettings(region=REGION, tolerance=0.08), pixel_of)
    assert timeline(c, path, pixel) == []


def test_the_region_keeps_a_second_pole_out() -> None:
    # a buoy at (1.0, -2.0), outside the region, in every scan
    c = marks.MarkSettings(region=REGION)
    found = marks.candidates(_points(ranges((1.5, 0.4), (1.0, -2.0))), c)
    assert len(found) == 1 and found[0].mean(axis=0) == pytest.approx([1.41, 0.376], abs=0.02)
    # without a region both poles are candidates (the wall is too wide): no mark in that scan
    both = marks.candidates(_points(ranges((1.5, 0.4), (1.0, -2.0))), marks.MarkSettings())
    assert len(both) == 2
    col = marks.PairCollector(marks.MarkSettings(), pixel_of)
    for k in range(5):
        col.add_scan(k * SEC // 5, ranges((1.5, 0.4), (1.0, -2.0)), -math.pi,
                     2 * math.pi / RAYS)
    assert col.finish() == [] and col.ambiguous == 5


def test_max_range_leaves_out_a_far_pole() -> None:
    found = marks.candidates(_points(ranges((3.5, 0.0))), marks.MarkSettings(max_range=3.0))
    assert found == []


def _points(r: np.ndarray):
    from enbarr_core.perception.scan_geometry import scan_points
    return scan_points(r, -math.pi, 2 * math.pi / RAYS)


def test_mark_centre_fits_the_known_radius_and_the_mean_falls_short() -> None:
    # points on the near side of a circle of 0.1 m at (2, 0), seen from the origin
    phi = np.radians([150.0, 165.0, 180.0, 195.0, 210.0])
    pts = np.column_stack([2.0 + 0.1 * np.cos(phi), 0.1 * np.sin(phi)])
    assert marks.mark_centre(pts, 0.1) == pytest.approx([2.0, 0.0], abs=1e-6)
    mean = marks.mark_centre(pts, 0.0)
    assert mean[0] == pytest.approx(2.0 - 0.1 * np.cos(phi - math.pi).mean())
    assert mean[0] < 1.95


def test_settings_are_checked() -> None:
    with pytest.raises(CalibrationError, match='--region 2,1,0,1: expected xmin < xmax'):
        marks.MarkSettings(region=(2.0, 1.0, 0.0, 1.0)).validate()
    with pytest.raises(CalibrationError, match='--min-still: expected a value > 0'):
        marks.MarkSettings(min_still=0.0).validate()


# -- the image side ---------------------------------------------------------------------------
def test_blob_centre_is_the_largest_blob_of_the_colour() -> None:
    img = np.zeros((120, 160, 3), np.uint8)
    img[20:61, 30:41] = (60, 160, 30)      # green (BGR) rows 20..60, columns 30..40
    img[80:90, 100:104] = (60, 160, 30)    # a smaller green blob
    img[0:100, 120:150] = (30, 30, 220)    # a large red one
    green = marks.COLOURS['green']
    assert marks.blob_centre(img, green) == pytest.approx((35.0, 40.0))
    assert marks.blob_centre(img, green, near=(100.0, 80.0)) == pytest.approx((101.5, 84.5))
    assert marks.blob_centre(img, green, min_area=500) is None
    assert marks.blob_centre(img, marks.COLOURS['yellow']) is None


class _Event:
    """What matplotlib hands a handler (the attributes the picker reads)."""

    def __init__(self, inaxes=None, button=None, xdata=None, ydata=None, key=None) -> None:
        self.inaxes, self.button, self.xdata, self.ydata, self.key = (inaxes, button, xdata,
                                                                      ydata, key)


@pytest.fixture
def figure():
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    ax.imshow(np.zeros((48, 64, 3), np.uint8))
    yield fig, ax
    plt.close(fig)


def test_a_left_click_in_the_image_picks_its_pixel(figure) -> None:
    from matplotlib.backend_bases import MouseEvent
    fig, ax = figure
    picker = marks.ClickPicker(fig, ax)
    fig.canvas.draw()
    # a real event through the canvas: a right click is ignored, a left click picks
    x, y = ax.transData.transform((20.25, 30.5))
    fig.canvas.callbacks.process('button_press_event',
                                 MouseEvent('button_press_event', fig.canvas, x, y, button=3))
    assert not picker.done
    fig.canvas.callbacks.process('button_press_event',
                                 MouseEvent('button_press_event', fig.canvas, x, y, button=1))
    assert picker.pixel == pytest.approx((20.25, 30.5), abs=0.05)
    # once decided, a further click changes nothing
    picker.on_click(_Event(ax, 1, 5.0, 5.0))
    assert picker.pixel == pytest.approx((20.25, 30.5), abs=0.05)


def test_a_click_outside_the_image_is_ignored_and_keys_skip_or_quit(figure) -> None:
    fig, ax = figure
    picker = marks.ClickPicker(fig, ax)
    picker.on_click(_Event(None, 1, None, None))
    picker.on_key(_Event(key='z'))               # matplotlib's own keys pass
    assert not picker.done
    picker.on_key(_Event(key='s'))
    assert picker.skipped and picker.pixel is None and not picker.quit
    quitter = marks.ClickPicker(fig, ax)
    quitter.on_key(_Event(key='q'))
    assert quitter.quit and quitter.pixel is None
