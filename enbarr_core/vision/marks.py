"""The manual's lidar-camera mark pairs, collected from scans and images (no ROS).

CS Saucer manual, section 4.2: marks at the lidar's height are seen by both sensors; each
gives a pair (the lidar point [m] in the laser frame, the pixel where the mark is seen) for
``extrinsics.solve_pnp``. The manual picks both by hand (a laser point in RViz, then its pixel
in a window); here a mark is a pole (or a post with a band of tape) held still at one place
after another, and the pairs come out of the scans and images of that time:

- the lidar side (``MarkFinder``): in each scan, the clusters of the adaptive breakpoint
  detector (``perception.segmentation``) that lie inside ``region`` (laser frame) and within
  ``max_range``, no wider than ``max_width``; exactly one such cluster is the mark (none or
  several: no mark in that scan, and the run of scans ends). A run of consecutive scans whose
  mark stays within ``tolerance`` of the run's mean is the mark held still; its first and last
  scans are left out (the mark may be arriving or leaving), and what remains must span
  ``min_still`` seconds. The mark's centre pools the run's points: with the mark's ``radius``
  known, the circle of that radius through them (``perception.fitting.refine_circle``: a
  ray hits the near side of a pole, not its axis); with radius 0, their mean.
- the image side: the images stamped within the still run (by header stamp, the time each was
  taken, not the time it arrived). With a colour (``blob_centre``): the centroid of the largest
  blob of that colour in each image, averaged; the pixel of the lidar's height is the blob's
  centroid when the coloured part is centred on that height (a band of tape there, or a pole
  twice as tall as the lidar stands above the water). By click (``ClickPicker``): the image
  nearest the run's middle, shown in a matplotlib window, the user clicks the mark.

``PairCollector`` takes scans and images one at a time in any interleaving (a bag's order or
a live subscription's), so a long bag is never held in memory: images are kept only while a
run that may contain them is open.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from enbarr_core.framework.errors import CalibrationError
from enbarr_core.perception.fitting import refine_circle
from enbarr_core.perception.scan_geometry import RangeNoise, scan_points, ScanPoints
from enbarr_core.perception.segmentation import BreakpointSettings, clusters
from enbarr_core.vision.classical import ColourClass, mask

Array = NDArray[np.float64]
Pixel = tuple[float, float]

#: The RPLidar A1's range noise, CS Saucer manual Table 1.1 (one standard deviation): 1 %
#: below 3 m, 2 % to 5 m, 2.5 % beyond. Sets the breakpoint detector's allowance.
A1_NOISE = RangeNoise((3.0, 5.0), (0.01, 0.02, 0.025))
#: The breakpoint detector's shallowest incidence for one surface: a pole is seen head on.
BREAKPOINT_LAMBDA = math.radians(10.0)
#: Named colours (OpenCV HSV boxes: H 0..179, S, V 0..255): the classical detector's default
#: classes (detector_node's hsv_lower/hsv_upper), so a mark painted like a buoy is found.
COLOURS: dict[str, ColourClass] = {
    'red': ColourClass('red', (170, 100, 50), (7, 255, 255)),
    'green': ColourClass('green', (45, 100, 50), (85, 255, 255)),
    'yellow': ColourClass('yellow', (19, 100, 50), (35, 255, 255)),
    'orange': ColourClass('orange', (8, 100, 50), (18, 255, 255)),
}


@dataclass(frozen=True)
class MarkSettings:
    """Where the mark may be and when it counts as held still (module docstring)."""

    region: tuple[float, float, float, float] | None = None   # xmin, xmax, ymin, ymax [m]
    max_range: float = 5.0        # [m]
    max_width: float = 0.3        # [m]: a cluster wider than this is a wall or a hull
    radius: float = 0.0           # [m] of the mark; 0: the points' mean
    tolerance: float = 0.08       # [m]: a scan's mark this far from the run's mean moved
    min_still: float = 1.0        # [s]

    def validate(self) -> None:
        """Raise ``CalibrationError`` naming the option at fault."""
        if self.region is not None:
            x0, x1, y0, y1 = self.region
            if not (x0 < x1 and y0 < y1):
                raise CalibrationError(f'--region {x0:g},{x1:g},{y0:g},{y1:g}: expected '
                                       'xmin < xmax and ymin < ymax [m] in the laser frame')
        for name, v in (('--max-range', self.max_range), ('--max-width', self.max_width),
                        ('--tolerance', self.tolerance), ('--min-still', self.min_still)):
            if not v > 0.0:
                raise CalibrationError(f'{name}: expected a value > 0, got {v:g}')
        if not self.radius >= 0.0:
            raise CalibrationError(f'--mark-radius: expected >= 0 [m], got {self.radius:g}')


def candidates(scan: ScanPoints, s: MarkSettings) -> list[Array]:
    """Return the points (N, 2) of each cluster of ``scan`` that may be the mark."""
    out = []
    for idx in clusters(scan, BreakpointSettings(BREAKPOINT_LAMBDA, 1, A1_NOISE)):
        pts = scan.laser[idx]
        if np.any(np.hypot(pts[:, 0], pts[:, 1]) > s.max_range):
            continue
        if s.region is not None:
            x0, x1, y0, y1 = s.region
            inside = (pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)
            if not np.all(inside):
                continue
        if float(np.linalg.norm(pts[-1] - pts[0])) > s.max_width:
            continue
        out.append(pts)
    return out


def mark_centre(points: Array, radius: float) -> Array:
    """Return the mark's centre [m] from its points: the circle of ``radius`` (0: the mean).

    A ray meets the near side of a round mark, so the mean lies short of the axis; the centre
    starts ``radius`` beyond the mean along the line of sight and is fitted from there. Under
    the A1's noise this fit of the points' distances comes out a few millimetres short at 2
    to 3 m; that is the way the image's error goes too (a pixel shows the mark's near face),
    and a fit to the ranges, unbiased, gave the worse calibration (docs/benchmarks.md,
    "Camera-lidar marks").
    """
    mean = points.mean(axis=0)
    if radius <= 0.0:
        out: Array = mean
        return out
    start: Array = mean + radius * mean / max(float(np.linalg.norm(mean)), 1e-9)
    fit = refine_circle(points, float(start[0]), float(start[1]), radius, fixed_radius=True,
                        iterations=30)
    if fit is None:
        return start
    return np.array([fit[0], fit[1]], dtype=np.float64)


def blob_centre(image: NDArray[np.uint8], colour: ColourClass, *, min_area: float = 30.0,
                near: Pixel | None = None) -> Pixel | None:
    """Return the centroid [px] of the largest blob of ``colour`` in a BGR image, or None.

    ``near``: the blob nearest this pixel instead of the largest. Specks are opened away
    (3 x 3); blobs under ``min_area`` px are ignored. Pixel centres are at whole numbers, as
    in OpenCV's projections.
    """
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    m = cv2.morphologyEx(mask(hsv, colour), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, _, stats, centroids = cv2.connectedComponentsWithStats(m)
    best: tuple[float, int] | None = None
    for i in range(1, n):
        area = float(stats[i, cv2.CC_STAT_AREA])
        if area < min_area:
            continue
        key = (-area if near is None
               else math.hypot(centroids[i][0] - near[0], centroids[i][1] - near[1]))
        if best is None or key < best[0]:
            best = (key, i)
    if best is None:
        return None
    return float(centroids[best[1]][0]), float(centroids[best[1]][1])


@dataclass
class MarkPose:
    """The mark held still once: its centre, the scans and images of that time, its pixel."""

    start_ns: int
    end_ns: int
    centre: Array                 # (2,) [m] in the laser frame
    scans: int
    pixels: list[Pixel] = field(default_factory=list)    # colour: one per image with a blob
    images: int = 0               # images stamped within the pose
    image: NDArray[np.uint8] | None = None                # click: the image nearest the middle
    pixel: Pixel | None = None    # the pair's pixel, once picked


@dataclass
class _Scan:
    stamp_ns: int
    points: Array
    centre: Array


class PairCollector:
    """Scans and images in, ``MarkPose`` s out (module docstring).

    ``pixel_of``: the colour picker (an image to its blob's pixel or None), or None to keep
    one image per pose for clicking.
    """

    def __init__(self, settings: MarkSettings,
                 pixel_of: Callable[[NDArray[np.uint8]], Pixel | None] | None) -> None:
        settings.validate()
        self.settings = settings
        self.pixel_of = pixel_of
        self.poses: list[MarkPose] = []
        self.scans = 0
        self.images = 0
        self.ambiguous = 0        # scans with more than one candidate in the region
        self.with_mark = 0        # scans with exactly one
        self._run: list[_Scan] = []
        self._pending: list[MarkPose] = []
        self._images: list[tuple[int, Any]] = []   # (stamp, pixel or image)
        self._last_image_ns = -1

    @property
    def places(self) -> int:
        """How many places the mark was held still at so far (closed runs)."""
        return len(self.poses) + len(self._pending)

    # -- input ----------------------------------------------------------------------------
    def add_scan(self, stamp_ns: int, ranges: Sequence[float] | Array, angle_min: float,
                 angle_increment: float) -> None:
        """One revolution: its stamp [ns] and its ranges (REP-117 values allowed)."""
        self.scans += 1
        scan = scan_points(np.asarray(ranges, dtype=float), angle_min, angle_increment)
        found = candidates(scan, self.settings)
        if len(found) != 1:
            self.ambiguous += len(found) > 1
            self._close()
            return
        self.with_mark += 1
        pts = found[0]
        now = _Scan(stamp_ns, pts, pts.mean(axis=0))
        if self._run:
            ref = np.mean([s.centre for s in self._run], axis=0)
            if float(np.linalg.norm(now.centre - ref)) > self.settings.tolerance:
                self._close()
        self._run.append(now)

    def add_image(self, stamp_ns: int, image: NDArray[np.uint8]) -> None:
        """One BGR image and its stamp [ns]."""
        self.images += 1
        obs = self.pixel_of(image) if self.pixel_of is not None else image
        self._images.append((stamp_ns, obs))
        self._last_image_ns = max(self._last_image_ns, stamp_ns)
        self._settle(final=False)

    def finish(self) -> list[MarkPose]:
        """End the input: close the open run; return every pose, in time order."""
        self._close()
        self._settle(final=True)
        return self.poses

    # -- internals ------------------------------------------------------------------------
    def _close(self) -> None:
        """End the present run: keep it as a pose when it was still long enough."""
        run, self._run = self._run[1:-1], []   # arriving and leaving scans left out
        if len(run) >= 2 and run[-1].stamp_ns - run[0].stamp_ns >= self.settings.min_still * 1e9:
            points = np.concatenate([s.points for s in run])
            self._pending.append(MarkPose(run[0].stamp_ns, run[-1].stamp_ns,
                                          mark_centre(points, self.settings.radius), len(run)))
        self._settle(final=False)

    def _settle(self, final: bool) -> None:
        """Give each closed pose the images of its time once no earlier image can come."""
        while self._pending and (final or self._pending[0].end_ns < self._last_image_ns):
            pose = self._pending.pop(0)
            mine = [(t, o) for t, o in self._images if pose.start_ns <= t <= pose.end_ns]
            pose.images = len(mine)
            if self.pixel_of is not None:
                pose.pixels = [o for _, o in mine if o is not None]
            elif mine:
                middle = (pose.start_ns + pose.end_ns) / 2
                pose.image = min(mine, key=lambda to: abs(to[0] - middle))[1]
            self.poses.append(pose)
        # an image older than every pose still to come is of no further use
        keep_from = min([p.start_ns for p in self._pending]
                        + ([self._run[0].stamp_ns] if self._run else [self._last_image_ns]))
        self._images = [(t, o) for t, o in self._images if t >= keep_from]


def colour_pixels(poses: Sequence[MarkPose]) -> None:
    """Set each colour pose's pixel: the mean of its images' blob centroids (none: None)."""
    for p in poses:
        p.pixel = (tuple(float(c) for c in np.mean(p.pixels, axis=0))  # type: ignore[assignment]
                   if p.pixels else None)


# -- picking by click -------------------------------------------------------------------------
class ClickPicker:
    """A matplotlib Axes showing one image: a left click picks a pixel, a key skips or quits.

    ``s``, ``n`` or space skips this mark; ``q`` or escape ends the picking. The figure is
    closed once decided. Pixel centres are whole numbers (``imshow``'s default extent), the
    convention of OpenCV's projections.
    """

    SKIP_KEYS = ('s', 'n', ' ')
    QUIT_KEYS = ('q', 'escape')

    def __init__(self, figure: Any, axes: Any) -> None:
        self.figure = figure
        self.axes = axes
        self.pixel: Pixel | None = None
        self.skipped = False
        self.quit = False
        figure.canvas.mpl_connect('button_press_event', self.on_click)
        figure.canvas.mpl_connect('key_press_event', self.on_key)

    @property
    def done(self) -> bool:
        """Whether a pixel was picked, or the mark skipped, or the picking ended."""
        return self.pixel is not None or self.skipped or self.quit

    def on_click(self, event: Any) -> None:
        """Pick the pixel of a left click inside the image; ignore anything else."""
        if (self.done or event.inaxes is not self.axes or event.button != 1
                or event.xdata is None or event.ydata is None):
            return
        self.pixel = (float(event.xdata), float(event.ydata))
        self._close()

    def on_key(self, event: Any) -> None:
        """Skip or quit on their keys; other keys (matplotlib's own zoom, pan) pass."""
        if self.done:
            return
        if event.key in self.SKIP_KEYS:
            self.skipped = True
        elif event.key in self.QUIT_KEYS:
            self.quit = True
        else:
            return
        self._close()

    def _close(self) -> None:
        import matplotlib.pyplot as plt
        plt.close(self.figure)


def show_for_click(image: NDArray[np.uint8], title: str, guess: Pixel | None) -> ClickPicker:
    """Show ``image`` (BGR) with the lidar's guess marked; block until decided."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(10, 7.5))
    ax.imshow(image[:, :, ::-1])
    if guess is not None:
        ax.plot([guess[0]], [guess[1]], marker='+', color='cyan', markersize=20, mew=1.5)
    ax.set_title(title + "\nclick the mark at the lidar's height; s: skip, q: stop",
                 fontsize=10)
    picker = ClickPicker(fig, ax)
    plt.show(block=True)
    if not picker.done:   # the window was closed: as a skip
        picker.skipped = True
    return picker
