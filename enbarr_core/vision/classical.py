"""The classical detector: coloured blobs of a buoy's shape, by HSV thresholds and contours.

Pure (OpenCV and numpy, no ROS). Per frame: a Gaussian blur (the water's ripples and the
sensor's noise are finer than a buoy), BGR -> HSV, one mask per class from its HSV box
(``ColourClass``; a hue range whose low end is above its high end wraps through 0, as red
does on OpenCV's 0..179 hue circle), an opening (drops specks) and a closing (fills the
specular highlight and the shaded side's gaps), then the outer contours of each mask. A
contour is an object of that class when its shape passes ``ShapeLimits``:

- area (of the contour) at least ``min_area`` px^2: far or tiny blobs are not located well;
- aspect (box height / box width) within ``min_aspect .. max_aspect``: a buoy floats upright
  (a cylinder seen from the side is a rectangle with rounded ends, a sphere a circle: both
  about as tall as wide or taller); a reflection or a painted stripe on a wall is flat;
- solidity (contour area / its convex hull's) at least ``min_solidity``: a buoy is convex;
  water glitter and ragged shadows are not;
- extent (contour area / box area) at least ``min_extent``: an ellipse fills pi/4 of its box,
  a cylinder nearly all; a diagonal streak fills little.

The score is the solidity (1 for a convex blob): a ranking among what passed, not a probability.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
from cv2.typing import MatLike
import numpy as np
from numpy.typing import NDArray

from enbarr_core.vision.detection import Detection

#: Gaussian blur and morphology kernel size [px] for a 640 x 480 image (odd).
BLUR = 5
KERNEL = 5


@dataclass(frozen=True)
class ColourClass:
    """One class: its name and its HSV box (OpenCV's ranges: H 0..179, S and V 0..255)."""

    name: str
    hsv_low: tuple[int, int, int]
    hsv_high: tuple[int, int, int]

    def validate(self) -> None:
        """Raise ``ValueError`` for a box outside OpenCV's HSV ranges, or empty in S or V.

        The message starts with the parameter at fault, ``hsv_lower`` or ``hsv_upper``.
        """
        for i, top in enumerate((179, 255, 255)):
            for bound, v in (('hsv_lower', self.hsv_low[i]), ('hsv_upper', self.hsv_high[i])):
                if not 0 <= v <= top:
                    raise ValueError(f'{bound}: class {self.name!r}: {"HSV"[i]} value {v} is '
                                     f'outside 0..{top}')
        for i in (1, 2):
            if self.hsv_low[i] > self.hsv_high[i]:
                raise ValueError(f'hsv_lower: class {self.name!r}: {"HSV"[i]} low '
                                 f'{self.hsv_low[i]} > high {self.hsv_high[i]}')


@dataclass(frozen=True)
class ShapeLimits:
    """What a blob's contour must be to count (module docstring)."""

    min_area: float = 150.0       # [px^2]
    min_aspect: float = 0.6       # box height / width
    max_aspect: float = 4.0
    min_solidity: float = 0.8     # contour area / hull area
    min_extent: float = 0.5       # contour area / box area

    def validate(self) -> None:
        """Raise ``ValueError('field: reason')`` when the limits do not hold together."""
        if self.min_aspect > self.max_aspect:
            raise ValueError(f'min_aspect: {self.min_aspect} > max_aspect {self.max_aspect}')


def mask(hsv: MatLike, c: ColourClass) -> MatLike:
    """Return the pixels of ``hsv`` in the class's box (255); hue wraps through 0 if low > high."""
    lo, hi = np.array(c.hsv_low, np.uint8), np.array(c.hsv_high, np.uint8)
    if c.hsv_low[0] <= c.hsv_high[0]:
        return cv2.inRange(hsv, lo, hi)
    upper = cv2.inRange(hsv, lo, np.array((179, hi[1], hi[2]), np.uint8))
    lower = cv2.inRange(hsv, np.array((0, lo[1], lo[2]), np.uint8), hi)
    return cv2.bitwise_or(upper, lower)


class ClassicalDetector:
    """Colour and shape detector; ``detect(bgr)`` gives the objects of one frame."""

    def __init__(self, classes: Sequence[ColourClass], shape: ShapeLimits) -> None:
        self.classes = tuple(classes)
        self.shape = shape
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (KERNEL, KERNEL))

    def detect(self, image: NDArray[np.uint8]) -> list[Detection]:
        """Return the objects of a BGR image, best score first (boxes in its pixels)."""
        hsv = cv2.cvtColor(cv2.GaussianBlur(image, (BLUR, BLUR), 0), cv2.COLOR_BGR2HSV)
        found: list[Detection] = []
        for class_id, c in enumerate(self.classes):
            m = mask(hsv, c)
            m = cv2.morphologyEx(m, cv2.MORPH_OPEN, self._kernel)
            m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, self._kernel)
            contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            for contour in contours:
                d = self._judge(contour, class_id)
                if d is not None:
                    found.append(d)
        found.sort(key=lambda d: -d.score)
        return found

    def _judge(self, contour: MatLike, class_id: int) -> Detection | None:
        s = self.shape
        area = float(cv2.contourArea(contour))
        if area < s.min_area:
            return None
        x, y, w, h = cv2.boundingRect(contour)
        if not s.min_aspect <= h / w <= s.max_aspect:
            return None
        hull = float(cv2.contourArea(cv2.convexHull(contour)))
        solidity = area / hull if hull > 0.0 else 0.0
        if solidity < s.min_solidity or area / (w * h) < s.min_extent:
            return None
        # boundingRect counts pixels (x .. x + w - 1): its corners are pixel edges here.
        return Detection(class_id, min(1.0, solidity), float(x), float(y), float(x + w),
                         float(y + h))
