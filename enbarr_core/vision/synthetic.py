"""Synthetic camera frames of buoys on water, with their true boxes: for tests and the bench.

Drawn with OpenCV from a seeded generator: textured water (swell as sums of sinusoids,
sensor noise, sun glitter), a far wall and a white boat as distractors, and buoys as upright
cylinders (a body shaded across its width as a lit cylinder is, Lambert's cosine, an
elliptical top) or as spheres (an ellipse shaded radially). Colours are BGR picked by eye for
red, green, yellow and orange buoys, independent of any detector's thresholds.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import cv2
import numpy as np
from numpy.typing import NDArray

#: BGR of a fully lit buoy of each colour, and their class order.
COLOURS = {'red': (35, 35, 205), 'green': (50, 165, 45), 'yellow': (30, 205, 230),
           'orange': (10, 105, 245)}
CLASSES = tuple(COLOURS)


@dataclass(frozen=True)
class TrueBox:
    """Where a buoy was drawn: its colour's index in ``CLASSES`` and box corners [px]."""

    class_id: int
    x_min: int
    y_min: int
    x_max: int     # one past the last column drawn
    y_max: int


def water(width: int, height: int, rng: np.random.Generator) -> NDArray[np.uint8]:
    """Textured water: a blue-grey gradient, swell, noise and a few glints."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    swell = np.zeros((height, width), np.float32)
    for _ in range(4):
        k, phase = rng.uniform(0.03, 0.15), rng.uniform(0.0, 2.0 * math.pi)
        theta = rng.uniform(-0.4, 0.4)
        swell += np.sin(k * (x * math.sin(theta) + y * math.cos(theta)) + phase)
    shade = (0.75 + 0.25 * (y / height) + 0.05 * swell
             + 0.03 * rng.standard_normal(swell.shape, dtype=np.float32))
    base = np.array((125, 95, 45), np.float32)   # BGR: blue-green water
    img: NDArray[np.uint8] = np.clip(shade[..., None] * base, 0, 255).astype(np.uint8)
    for _ in range(int(rng.integers(10, 40))):  # sun glitter: small, unsaturated, bright
        cx, cy = int(rng.integers(0, width)), int(rng.integers(height // 3, height))
        cv2.ellipse(img, (cx, cy), (int(rng.integers(1, 4)), 1), 0, 0, 360,
                    (235, 235, 235), -1)
    return img


def distractors(img: NDArray[np.uint8], rng: np.random.Generator) -> TrueBox:
    """Draw a grey basin wall along the top with a red stripe, a white boat with a red boot top.

    The red parts are buoy-coloured but flat: only a shape test tells them from a buoy.
    Returns the boat's box (class -1), which ``scene`` keeps its buoys clear of.
    """
    h, w = img.shape[:2]
    top = int(rng.integers(h // 8, h // 4))
    img[:top] = (150, 150, 145)
    cv2.line(img, (0, top), (w, top), (90, 90, 90), 2)
    cv2.rectangle(img, (w // 3, top - 14), (w // 3 + 160, top - 6), COLOURS['red'], -1)
    bx, by = int(rng.integers(0, w - 140)), int(rng.integers(top + 10, h // 2))
    hull = np.array([(bx, by), (bx + 130, by), (bx + 110, by + 25), (bx + 15, by + 25)],
                    np.int32)
    cv2.fillPoly(img, [hull], (235, 235, 230))
    cv2.rectangle(img, (bx + 13, by + 19), (bx + 112, by + 25), COLOURS['red'], -1)
    return TrueBox(-1, bx, by - 20, bx + 131, by + 26)
    cv2.rectangle(img, (bx + 40, by - 20), (bx + 80, by), (70, 70, 70), -1)


def cylinder(img: NDArray[np.uint8], x0: int, y0: int, w: int, h: int,
             bgr: tuple[int, int, int], light: float) -> None:
    """Draw an upright cylinder filling ``x0 .. x0 + w``, ``y0 .. y0 + h`` (top cap inside)."""
    cap = max(2, w // 5)
    u = (np.arange(w) + 0.5) / w * 2.0 - 1.0          # -1 .. 1 across the body
    normal = np.arcsin(np.clip(u, -1.0, 1.0))          # surface normal's angle to the view
    lit = 0.35 + 0.65 * np.clip(np.cos(normal - light), 0.0, 1.0)
    body = lit[None, :, None] * np.array(bgr, np.float32)[None, None, :]
    img[y0 + cap // 2:y0 + h, x0:x0 + w] = np.clip(body, 0, 255).astype(np.uint8)
    top = tuple(int(min(255, 1.1 * c)) for c in bgr)
    cv2.ellipse(img, (x0 + w // 2, y0 + cap // 2), (w // 2, cap // 2), 0, 0, 360, top, -1)
    # a specular highlight, narrow and less saturated, where the light faces the viewer
    sx = x0 + int((0.5 + 0.35 * math.sin(light)) * w)
    cv2.line(img, (sx, y0 + cap), (sx, y0 + h - 2),
             tuple(int(0.5 * c + 0.5 * 255) for c in bgr), 1)


def sphere(img: NDArray[np.uint8], x0: int, y0: int, d: int, bgr: tuple[int, int, int],
           light: float) -> None:
    """Draw a sphere (a shaded disc) in the square ``x0 .. x0 + d``, ``y0 .. y0 + d``."""
    y, x = np.mgrid[0:d, 0:d].astype(np.float32) + 0.5
    r = d / 2.0
    nx, ny = (x - r) / r, (y - r) / r
    inside = nx * nx + ny * ny <= 1.0
    nz = np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 0.0, 1.0))
    lx, lz = math.sin(light), math.cos(light)
    lit = 0.35 + 0.65 * np.clip(nx * lx - ny * 0.3 + nz * lz, 0.0, 1.0)
    patch = img[y0:y0 + d, x0:x0 + d]
    shaded = np.clip(lit[..., None] * np.array(bgr, np.float32), 0, 255).astype(np.uint8)
    patch[inside] = shaded[inside]


def scene(rng: np.random.Generator, width: int = 640, height: int = 480,
          buoys: int | None = None) -> tuple[NDArray[np.uint8], list[TrueBox]]:
    """Return a frame and the true box of each buoy in it (1 to 4, apart and clear of the boat).

    Apart: a buoy drawn against another or against the boat's red stripe is one blob with it,
    whose true box would be a matter of opinion.
    """
    img = water(width, height, rng)
    boat = distractors(img, rng)
    truth: list[TrueBox] = []
    light = float(rng.uniform(-0.8, 0.8))
    for _ in range(int(rng.integers(1, 5)) if buoys is None else buoys):
        for _attempt in range(50):
            class_id = int(rng.integers(0, len(CLASSES)))
            bgr = COLOURS[CLASSES[class_id]]
            round_buoy = bool(rng.random() < 0.3)
            w = int(rng.integers(16, 70))
            h = w if round_buoy else int(w * rng.uniform(1.2, 2.5))
            x0 = int(rng.integers(0, width - w))
            y0 = int(rng.integers(height // 4, height - h))
            box = TrueBox(class_id, x0, y0, x0 + w, y0 + h)
            if any(_overlap(box, t) for t in (*truth, boat)):
                continue
            if round_buoy:
                sphere(img, x0, y0, w, bgr, light)
            else:
                cylinder(img, x0, y0, w, h, bgr, light)
            truth.append(box)
            break
    noise = 3.0 * rng.standard_normal(img.shape, dtype=np.float32)
    return np.clip(img.astype(np.float32) + noise, 0, 255).astype(np.uint8), truth


def _overlap(a: TrueBox, b: TrueBox, margin: int = 8) -> bool:
    return not (a.x_max + margin <= b.x_min or b.x_max + margin <= a.x_min
                or a.y_max + margin <= b.y_min or b.y_max + margin <= a.y_min)
