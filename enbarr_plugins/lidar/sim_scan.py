"""What a Slamtec RPLidar A1 measures in a simulated world, one revolution at a time (no ROS).

The figures are the CS Saucer manual's (Table 1.1, "RPLidar A1"): 360 deg scan, 2000
samples/s, angular resolution 1 deg, effective range 12 m, range accuracy "1% < 3 m, 2% in
[3, 5] m, 2.5% > 5 m"; the nearest range, 0.15 m, is Slamtec's A1 datasheet's (the manual
gives none).

Reading of the accuracy (the manual does not say whether the percentages are a standard
deviation or a bound): here they are the standard deviation of a zero-mean Gaussian error
proportional to the range, sigma = p(r) r with p the band of the true range r. As a bound it
would be the looser reading, so a perception tested against this model is tested against
errors at least as large as the manual allows. ``noise_scale`` multiplies sigma (0: exact).

A revolution is ``samples`` samples at the A1's own clockwise angles ``i 360 / samples`` deg
(1 deg apart at the default 360: the manual's angular resolution), each ray-cast in the
``World`` from the lidar's pose at one instant, then given what the A1 would report:

- a return nearer than ``RANGE_MIN`` or beyond ``RANGE_MAX`` (after the error), and a
  sample lost at random (``dropout_probability``), is distance 0, the protocol's invalid
  measurement, as the emulator sends it;
- a distance is a multiple of 1/4 mm (the protocol's ``distance_q2``);
- a sample in a masked sector (the marker rods of manual section 1.5: mounted so that they
  leave the interval [-90 deg, 90 deg] clear, so a mask lies outside it) is what the A1
  reports when a rod stands there: ``mask_range`` [m], or 0 (no return) when the rod stands
  inside the A1's blind zone; nothing beyond a rod is seen.

The samples go through the real driver's ``scan.bin_revolution``, so the simulated scan has
the driver's rays and special values (REP-117) by construction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

from enbarr_core.framework.frames import Transform
from enbarr_core.world.model import World
from enbarr_plugins.lidar.scan import bearing, bin_revolution

#: Effective range [m] (manual Table 1.1) and the nearest measurable range [m] (the A1
#: datasheet): no return outside them.
RANGE_MIN, RANGE_MAX = 0.15, 12.0
#: Range accuracy (manual Table 1.1): (upper end of the band [m], fraction of the range).
ACCURACY = ((3.0, 0.01), (5.0, 0.02), (math.inf, 0.025))
#: The protocol's distance unit [mm] (distance_q2: quarter millimetres).
DISTANCE_STEP_MM = 0.25

FloatArray = NDArray[np.float64]


def range_sigma(r: FloatArray) -> FloatArray:
    """Return the standard deviation [m] of the range error at true ranges ``r`` [m]."""
    r = np.asarray(r, dtype=float)
    # below 3 m: 1 %; 3 to 5 m (both ends): 2 %; beyond 5 m: 2.5 %
    p = np.where(r < ACCURACY[0][0], ACCURACY[0][1],
                 np.where(r <= ACCURACY[1][0], ACCURACY[1][1], ACCURACY[2][1]))
    out: FloatArray = p * r
    return out


def in_sectors(bearing_deg: FloatArray, sectors: Sequence[tuple[float, float]]) -> NDArray[
        np.bool_]:
    """Whether each bearing [deg] in the laser frame lies in one of ``sectors``.

    A sector (start, end) [deg], bearings counter-clockwise in [-180, 180]: start <= b <=
    end, or, when start > end, the sector through 180 deg (b >= start or b <= end).
    """
    b = np.asarray(bearing_deg, dtype=float)
    hit = np.zeros(b.shape, dtype=bool)
    for lo, hi in sectors:
        hit |= ((b >= lo) & (b <= hi)) if lo <= hi else ((b >= lo) | (b <= hi))
    return hit


@dataclass(frozen=True)
class A1Model:
    """The error model and geometry of a simulated A1 (see the module docstring)."""

    samples: int = 360                                   # per revolution
    noise_scale: float = 1.0                             # x the manual's accuracy
    dropout_probability: float = 0.0                     # per sample
    mask_sectors: tuple[tuple[float, float], ...] = ()   # [deg] in the laser frame
    mask_range: float = 0.0                              # [m]; 0: no return there

    def angles_deg(self) -> FloatArray:
        """Return the A1's clockwise angles [deg] of one revolution's samples."""
        return np.arange(self.samples) * (360.0 / self.samples)


class SimulatedA1:
    """Measures revolutions of a ``World`` from a lidar mounted at ``mount`` on the vessel.

    ``mount``: the lidar frame's pose in the vessel's body frame (``T_base_laser``, the
    frame tree's ``lookup('base_link', 'laser')``); the scan plane is the laser frame's xy
    plane seen from above (a lidar mounted upside down turns the other way).
    """

    def __init__(self, world: World, mount: Transform, model: A1Model,
                 rng: np.random.Generator) -> None:
        self.world = world
        self.rng = rng
        self.mount_xy = (float(mount.translation[0]), float(mount.translation[1]))
        self._r2 = mount.rotation_matrix[:2, :2]
        self.model = model
        self.set_model(model)

    def set_model(self, model: A1Model) -> None:
        """Take a new model (live parameters); the sample bearings follow its ``samples``."""
        self.model = model
        self.angles = model.angles_deg()
        b = bearing(self.angles)  # in the laser frame [rad]
        d = self._r2 @ np.vstack((np.cos(b), np.sin(b)))
        self.body_bearings = np.arctan2(d[1], d[0])  # the same rays in the body frame
        self.masked = in_sectors(np.degrees(b), model.mask_sectors)

    def distances_mm(self, x: float, y: float, psi: float, t: float) -> FloatArray:
        """Return what the A1 reports [mm] (0: no return) at each angle of ``angles``.

        The vessel at (x, y) [m], heading ``psi`` [rad] in odom; the world at time ``t`` [s].
        """
        m = self.model
        c, s = math.cos(psi), math.sin(psi)
        mx, my = self.mount_xy
        origin = (x + c * mx - s * my, y + s * mx + c * my)
        r = self.world.raycast(origin, psi + self.body_bearings, t)
        if m.noise_scale > 0.0:
            finite = np.isfinite(r)
            noise = self.rng.standard_normal(r.shape)
            r = np.where(finite, r + m.noise_scale * range_sigma(np.where(finite, r, 0.0))
                         * noise, r)
        r = np.where(self.masked, m.mask_range, r)
        ok = (r >= RANGE_MIN) & (r <= RANGE_MAX)
        if m.dropout_probability > 0.0:
            ok &= self.rng.random(r.shape) >= m.dropout_probability
        mm = np.where(ok, np.round(r * 1000.0 / DISTANCE_STEP_MM) * DISTANCE_STEP_MM, 0.0)
        out: FloatArray = mm
        return out

    def scan(self, x: float, y: float, psi: float, t: float, bins: int) -> FloatArray:
        """Return one revolution as the driver publishes it: ``bins`` rays from -pi, CCW [m]."""
        return bin_revolution(self.angles, self.distances_mm(x, y, psi, t), bins, RANGE_MIN,
                              RANGE_MAX)
