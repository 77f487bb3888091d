"""What a camera on the vessel sees of a simulated world, one frame at a time (no ROS).

The camera is a pinhole with lens distortion (``PinholeModel``: the ROS camera_info's K and D,
OpenCV's plumb_bob or rational_polynomial model), mounted on the vessel at ``mount`` (the
frame tree's ``base_link -> camera_optical_frame``, REP-103: z ahead, x right, y down). The
world's obstacles are vertical prisms standing on the water (z = 0 in odom) up to their
``height``, in their ``colour``: a circle is a cylinder (a buoy), a polygon a solid hull or
pier, walls are upright panels. Below the horizon is the water, a plane textured with a
deterministic noise fixed in odom (it moves in the image as the vessel moves); above it a sky.
The vessel's base_link is taken at the waterline (its truth's z, 0 for the 3-DOF simulator),
an assumption of the surface simulation.

How a frame is made, and why this way: the scene is rendered on an undistorted pinhole canvas
(same focal lengths, wide enough to hold every pixel of the distorted image), then remapped
through the distortion with one ``cv2.remap`` whose map is computed once from the model. On a
pinhole canvas of a level camera every column is one vertical plane through the camera, so a
column is one 2D ray in the world's plan: a ray meets each prism's wall at one forward depth
``Z`` and the prism covers the rows of heights 0..``height`` at that depth. Occlusion is then
exact per column (a depth buffer over the primitives, nearest wins), with one 2D ray cast per
column instead of one 3D ray per pixel. A distorted image has no such structure (its columns
are curves), and projecting the obstacles' outlines through ``cv2.projectPoints`` would bend
straight edges only at their sampled vertices and leave occlusion to a painter's order, which
walls around the vessel break. The map of the remap is the inverse of OpenCV's forward model
(``cv2.undistortPoints`` iterated to convergence), so a point lands where
``cv2.projectPoints`` puts it; the tests check that against ``projectPoints``.

The camera must be level (its optical y axis straight down in ``base_link``): the manual's
camera looks ahead along surge (section 1.5), and the simulated vessel neither rolls nor
pitches. A tilted mount is refused rather than drawn wrong.

Labels: each frame comes with a label image of what every pixel shows (the obstacle's index in
``World.obstacles``, ``WATER`` or ``SKY``), the ground truth a detector can be tested against.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from enbarr_core.framework.frames import Transform
from enbarr_core.vision.camera import PinholeCamera
from enbarr_core.world.model import Circle, Polygon, Walls, World

#: Labels of the pixels that show no obstacle.
WATER, SKY = -1, -2
#: Distortion models this renderer draws (OpenCV's distCoeffs: 5 and 8 coefficients).
DISTORTION_MODELS = ('plumb_bob', 'rational_polynomial')
#: The pinhole canvas may be at most this many times the image in each direction: a lens that
#: needs more (a fisheye) is not the model here.
MAX_CANVAS_SCALE = 3.0
#: Nearest forward depth drawn [m]: nearer surfaces are clipped (the lens's own housing).
NEAR = 0.02
#: Texture coordinates stay within this [texture px] (remap's fixed-point maps hold 32767).
TEXTURE_REACH = 30000.0
#: The distortion map must land within this of every pixel through the forward model [px].
MAP_TOLERANCE = 0.01
#: A level camera's optical y axis is within this of straight down (cosine).
LEVEL_TOLERANCE = 1e-6

FloatArray = NDArray[np.float64]


class PinholeModel(PinholeCamera):
    """The intrinsics the renderer draws: a ``PinholeCamera`` of known size.

    Its distortion is one of ``DISTORTION_MODELS`` (plumb_bob or rational_polynomial).
    """

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f'image size must be positive, got {self.width}x{self.height}')
        if len(self.k) != 9 or not (self.k[0] > 0.0 and self.k[4] > 0.0):
            raise ValueError(f'K: expected 9 numbers with fx, fy > 0, got {self.k}')
        if self.distortion_model not in DISTORTION_MODELS:
            raise ValueError(f'distortion model {self.distortion_model!r}: the simulated '
                             f'camera draws {", ".join(DISTORTION_MODELS)}')
        if len(self.d) not in (4, 5, 8):
            raise ValueError(f'D: expected 4, 5 or 8 coefficients, got {len(self.d)}')
        super().__post_init__()


@dataclass(frozen=True)
class Look:
    """Light and surfaces of the scene (RGB colours, 0..255)."""

    sun_azimuth: float = math.radians(135.0)   # [rad] in odom, CCW from +x (east)
    sun_elevation: float = math.radians(40.0)  # [rad]
    ambient: float = 0.45                      # share of the light that is not the sun's
    water: tuple[int, int, int] = (40, 90, 110)
    water_contrast: float = 28.0               # texture amplitude (0..255 units)
    texture_period: float = 4.0                # [m]: the water's noise repeats this often
    sky_horizon: tuple[int, int, int] = (205, 218, 230)
    sky_zenith: tuple[int, int, int] = (105, 150, 210)
    fog_distance: float = 40.0                 # [m]: far things fade to the horizon's colour
    seed: int = 1


class Frame(NamedTuple):
    """One rendered frame: ``image`` (H, W, 3) uint8 BGR, ``labels`` (H, W) int16."""

    image: NDArray[np.uint8]
    labels: NDArray[np.int16]


def level_axes(mount: Transform) -> tuple[FloatArray, FloatArray, float]:
    """Return the camera's forward and right axes (unit, in base_link's xy) and its height.

    ``mount``: the optical frame's pose in base_link. ``ValueError`` if the camera is not level
    (its y axis, down in REP-103, not along -z of base_link).
    """
    r = mount.rotation_matrix
    if r[2, 1] > -1.0 + LEVEL_TOLERANCE:
        raise ValueError('the simulated camera must be level: its optical y axis (down, '
                         'REP-103) along -z of base_link; the mount is rolled or pitched')
    fwd, right = r[:2, 2].copy(), r[:2, 0].copy()
    return fwd / np.hypot(*fwd), right / np.hypot(*right), float(mount.translation[2])


def water_texture(seed: int, size: int = 256) -> NDArray[np.float32]:
    """Return a periodic noise tile (size x size, zero mean, unit std): ripples, seeded."""
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    fx, fy = np.meshgrid(f, f * 2.5)  # longer along x: wind ripples, not isotropic grain
    spectrum = np.exp(-np.hypot(fx, fy) * 30.0) * np.fft.fft2(rng.standard_normal((size,
                                                                                     size)))
    tile = np.real(np.fft.ifft2(spectrum))
    tile = (tile - tile.mean()) / tile.std()
    out: NDArray[np.float32] = tile.astype(np.float32)
    return out


class SimulatedCamera:
    """Renders a ``World`` as the camera at ``mount`` on the vessel sees it.

    ``model``: the intrinsics; ``mount``: the optical frame's pose in base_link
    (``T_base_optical``, the frame tree's ``lookup('base_link', 'camera_optical_frame')``).
    The distortion map and the canvas are computed once here.
    """

    def __init__(self, model: PinholeModel, mount: Transform, look: Look = Look()) -> None:
        self.model = model
        self.look = look
        self.fwd_b, self.right_b, self.height_b = level_axes(mount)
        self.mount_xy = (float(mount.translation[0]), float(mount.translation[1]))
        k = model.matrix
        fx, fy = k[0, 0], k[1, 1]
        # normalized (undistorted) coordinates of every pixel centre of the image
        u, v = np.meshgrid(np.arange(model.width, dtype=float),
                           np.arange(model.height, dtype=float))
        pts = np.stack((u.ravel(), v.ravel()), axis=1)
        xy = model.normalized(pts).reshape(model.height, model.width, 2)
        # the map must invert OpenCV's forward model over the whole image: a distortion that
        # folds over (not monotonic, as a strong barrel towards the corners) has no inverse
        back = model.project(np.concatenate((xy.reshape(-1, 2), np.ones(
            (xy.shape[0] * xy.shape[1], 1))), axis=1))
        miss = float(np.abs(back.reshape(-1, 2) - pts.reshape(-1, 2)).max())
        if not miss < MAP_TOLERANCE:
            raise ValueError(f'the distortion {model.d} cannot be inverted over the image '
                             f'(off by {miss:.2g} px): not a lens this renderer draws')
        cx, cy = k[0, 2], k[1, 2]
        # the canvas is the ideal pinhole image of the same K, shifted so that it holds every
        # pixel: canvas pixel (i, j) is the pinhole's (v, u) = (i + v0, j + u0), integers, so
        # that without distortion the map is the identity
        ui, vi = xy[..., 0] * fx + cx, xy[..., 1] * fy + cy
        self.u0 = math.floor(float(ui.min())) - 2
        self.v0 = math.floor(float(vi.min())) - 2
        cw = math.ceil(float(ui.max())) + 3 - self.u0
        ch = math.ceil(float(vi.max())) + 3 - self.v0
        if cw > MAX_CANVAS_SCALE * model.width or ch > MAX_CANVAS_SCALE * model.height:
            raise ValueError(f'the distortion {model.d} widens the view to {cw}x{ch} px, more '
                             f'than {MAX_CANVAS_SCALE:g} times the image: not a lens this '
                             'renderer draws')
        self.map_x = (ui - self.u0).astype(np.float32)
        self.map_y = (vi - self.v0).astype(np.float32)
        self.xn = (np.arange(cw) + self.u0 - cx) / fx  # (W,) per canvas column
        self.yn = (np.arange(ch) + self.v0 - cy) / fy  # (H,) per canvas row
        self.fy, self.row0 = fy, cy - self.v0  # canvas row of the principal point
        self._texture = water_texture(look.seed)
        self._sky = self._sky_rows()
        self._haze = np.array(look.sky_horizon[::-1], dtype=float)  # far things' colour
        self._still_cache: _Still | None = None
        s = look
        self._sun = np.array([math.cos(s.sun_azimuth) * math.cos(s.sun_elevation),
                              math.sin(s.sun_azimuth) * math.cos(s.sun_elevation)])
        self._sun_up = math.sin(s.sun_elevation)

    @property
    def canvas_size(self) -> tuple[int, int]:
        """(width, height) of the pinhole canvas [px]."""
        return len(self.xn), len(self.yn)

    def _sky_rows(self) -> FloatArray:
        """(H, 3) the sky's colour by row: the horizon's at and below it, to the zenith's."""
        s = self.look
        up = np.clip(-self.yn, 0.0, None)
        w = (1.0 - np.exp(-up * 3.0))[:, None]
        out: FloatArray = (np.array(s.sky_horizon, float) * (1.0 - w)
                           + np.array(s.sky_zenith, float) * w)
        return out

    def _shade(self, nx: FloatArray, ny: FloatArray) -> FloatArray:
        """Lambert's light on a vertical surface of normal (nx, ny) (unit, odom)."""
        a = self.look.ambient
        out: FloatArray = a + (1.0 - a) * np.maximum(0.0, nx * self._sun[0] + ny * self._sun[1])
        return out

    def render(self, world: World, x: float, y: float, psi: float, t: float,
               z: float = 0.0, labels: bool = True) -> Frame:
        """Render ``world`` at time ``t`` [s] from the vessel at (x, y, z) [m], heading ``psi``.

        The vessel's pose in odom (ENU); z of base_link above the water (0: at the waterline).
        ``labels``: make the label image too (else ``Frame.labels`` is empty).
        """
        c, s = math.cos(psi), math.sin(psi)
        rot = np.array([[c, -s], [s, c]])
        mx, my = self.mount_xy
        cam = np.array([x + c * mx - s * my, y + s * mx + c * my])
        zc = z + self.height_b  # the lens's height above the water [m]
        fwd, right = rot @ self.fwd_b, rot @ self.right_b
        # one 2D ray per canvas column: cam + Z (fwd + xn right), Z the forward depth [m]
        d = fwd[None, :] + self.xn[:, None] * right[None, :]  # (W, 2)
        canvas, label = self._background(cam, zc, d)
        depth = np.full(canvas.shape[:2], np.inf, dtype=np.float32)
        for i, (obstacle, shape) in enumerate(zip(world.obstacles, world.shapes_at(t))):
            bgr = np.array(obstacle.colour[::-1], dtype=np.float32)
            for zz, shade, cap in self._faces(shape, cam, d, zc, obstacle.height):
                top = zc - obstacle.height  # below the lens: > 0
                lo, hi = self._rows(zz, top), self._rows(zz, zc)
                if cap is not None:  # a top seen from above: from its far edge to its near
                    lo, hi = self._rows(cap, top), self._rows(zz, top)
                self._draw(canvas, label, depth, zz, lo, hi, i, bgr, shade)
        image = cv2.remap(canvas, self.map_x, self.map_y, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
        if not labels:
            return Frame(image, np.empty((0, 0), np.int16))
        return Frame(image, cv2.remap(label, self.map_x, self.map_y, cv2.INTER_NEAREST,
                                      borderMode=cv2.BORDER_REPLICATE))

    def _rows(self, zz: FloatArray, dz: float) -> FloatArray:
        """Return the canvas row of ``dz`` below the lens at forward depth ``zz`` (yn = dz/Z)."""
        with np.errstate(divide='ignore', invalid='ignore'):
            out: FloatArray = dz / zz * self.fy + self.row0
        return out

    def _still(self, zc: float) -> _Still:
        """Return the background's parts that depend on the lens's height only (cached)."""
        if self._still_cache is not None and self._still_cache.zc == zc:
            return self._still_cache
        s = self.look
        w_cols = len(self.xn)
        sky = np.broadcast_to(self._sky[:, None, ::-1], (len(self.yn), w_cols, 3))
        sky_u8 = np.clip(sky + 0.5, 0, 255).astype(np.uint8)
        first = int(np.searchsorted(self.yn, 0.0, side='right')) if zc > 0.0 else len(self.yn)
        zw = zc / self.yn[first:]  # forward depth where each row meets the water [m]
        # |fwd + xn right| = sqrt(1 + xn^2): fwd and right are orthonormal
        dist = zw[:, None] * np.sqrt(1.0 + self.xn * self.xn)[None, :]
        far = (1.0 - np.exp(-dist / s.fog_distance))[..., None]
        base = (np.array(s.water[::-1], float) * (1.0 - far)
                + np.array(s.sky_horizon[::-1], float) * far)
        gain = s.water_contrast * (1.0 - far)
        # texture coordinates stay within what remap's fixed-point maps hold (+-32767): far
        # water, faded to the horizon's colour, takes the texture of a nearer ring
        scale = self._texture.shape[0] / s.texture_period
        reach = (TEXTURE_REACH - self._texture.shape[0]) / float(
            np.sqrt(1.0 + self.xn ** 2).max())
        # the water is shaded on every other row and column, then scaled up: smooth ripples
        # and fog lose nothing, and it is a quarter of the work
        self._still_cache = _Still(
            zc, first, sky_u8, base[::2, ::2].astype(np.float32),
            gain[::2, ::2].astype(np.float32),
            np.minimum(zw[::2] * scale, reach).astype(np.float32))
        return self._still_cache

    def _background(self, cam: FloatArray, zc: float, d: FloatArray
                    ) -> tuple[NDArray[np.uint8], NDArray[np.int16]]:
        """Return the canvas (BGR) and its labels: the water below the horizon, the sky above.

        The water is textured and fades with distance to the horizon's colour.
        """
        st = self._still(zc)
        canvas = st.sky.copy()
        label = np.full(canvas.shape[:2], SKY, dtype=np.int16)
        if st.first >= len(self.yn):
            return canvas, label
        n = self._texture.shape[0]
        scale = n / self.look.texture_period
        # where each pixel's ray meets the water, in texture pixels (the tile repeats)
        ox, oy = np.float32(cam[0] * scale % n), np.float32(cam[1] * scale % n)
        dx, dy = d[::2, 0].astype(np.float32), d[::2, 1].astype(np.float32)
        tx = st.zw_scaled[:, None] * dx[None, :]
        tx += ox
        ty = st.zw_scaled[:, None] * dy[None, :]
        ty += oy
        np.mod(tx, np.float32(n), out=tx)  # in the tile: remap's fast path
        np.mod(ty, np.float32(n), out=ty)
        ripple = cv2.remap(self._texture, tx, ty, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        water = st.base + st.gain * ripple[..., None]
        np.clip(water, 0.0, 255.0, out=water)
        canvas[st.first:] = cv2.resize(water.astype(np.uint8),
                                       (canvas.shape[1], canvas.shape[0] - st.first),
                                       interpolation=cv2.INTER_LINEAR)
        label[st.first:] = WATER
        return canvas, label

    def _faces(self, shape: object, cam: FloatArray, d: FloatArray, zc: float, height: float
               ) -> list[tuple[FloatArray, FloatArray, FloatArray | None]]:
        """Return each surface a column sees: (Z, light, far), arrays over the columns.

        Z: the forward depth [m] (inf: not seen); light: the shade (0..1); far: None, or for a
        top seen from above the depth of its far edge.
        """
        ox, oy = cam
        dx, dy = d[:, 0], d[:, 1]
        faces: list[tuple[FloatArray, FloatArray, FloatArray | None]] = []
        if isinstance(shape, Circle):
            # |o + Z d - c|^2 = r^2: a Z^2 + 2 b Z + c0 = 0
            cx, cy = shape.center
            a = dx * dx + dy * dy
            b = (ox - cx) * dx + (oy - cy) * dy
            c0 = (ox - cx) ** 2 + (oy - cy) ** 2 - shape.radius ** 2
            disc = b * b - a * c0
            root = np.sqrt(np.maximum(disc, 0.0))
            near, far = (-b - root) / a, (-b + root) / a
            hit = (disc >= 0.0) & (near > NEAR)
            zz = np.where(hit, near, np.inf)
            nx = (ox + near * dx - cx) / shape.radius
            ny = (oy + near * dy - cy) / shape.radius
            faces.append((zz, self._shade(nx, ny), None))
            if zc > height:
                top = self.look.ambient + (1.0 - self.look.ambient) * self._sun_up
                faces.append((zz, np.full_like(zz, top), np.where(hit, far, np.inf)))
            return faces
        assert isinstance(shape, (Polygon, Walls))
        hits = []
        for (ax, ay), (bx, by) in shape.segments():
            ex, ey = bx - ax, by - ay
            px, py = ax - ox, ay - oy
            denom = dx * ey - dy * ex
            with np.errstate(divide='ignore', invalid='ignore'):
                zz = (px * ey - py * ex) / denom
                u = (px * dy - py * dx) / denom
            ok = (denom != 0.0) & (zz > NEAR) & (u >= 0.0) & (u <= 1.0)
            zz = np.where(ok, zz, np.inf)
            length = math.hypot(ex, ey)
            nx, ny = ey / length, -ex / length
            toward = np.sign(-(nx * dx + ny * dy))  # the side the camera sees
            faces.append((zz, self._shade(nx * toward, ny * toward), None))
            hits.append(zz)
        if isinstance(shape, Polygon) and zc > height and hits:
            stack = np.vstack(hits)
            finite = np.isfinite(stack)
            near = stack.min(axis=0)
            far = np.where(finite, stack, -np.inf).max(axis=0)
            seen = finite.sum(axis=0) >= 2
            top = self.look.ambient + (1.0 - self.look.ambient) * self._sun_up
            faces.append((np.where(seen, near, np.inf), np.full(len(near), top),
                          np.where(seen, far, np.inf)))
        return faces

    def _draw(self, canvas: NDArray[np.uint8], label: NDArray[np.int16],
              depth: NDArray[np.float32], zz: FloatArray, lo: FloatArray, hi: FloatArray,
              index: int, bgr: NDArray[np.float32], shade: FloatArray) -> None:
        """Paint rows lo..hi of each column at depth ``zz`` where nothing nearer is."""
        cols = np.nonzero(np.isfinite(zz))[0]
        if not len(cols):
            return
        j0, j1 = int(cols[0]), int(cols[-1]) + 1
        z = zz[j0:j1]
        seen = np.isfinite(z)
        top = float(np.min(np.where(seen, lo[j0:j1], np.inf)))
        bottom = float(np.max(np.where(seen, hi[j0:j1], -np.inf)))
        i0, i1 = max(0, math.ceil(top)), min(canvas.shape[0], math.floor(bottom) + 1)
        if i1 <= i0:
            return
        block = np.arange(i0, i1, dtype=float)[:, None]
        mask = (block >= lo[None, j0:j1]) & (block <= hi[None, j0:j1]) & (
            z[None, :] < depth[i0:i1, j0:j1])
        if not mask.any():
            return
        far = (1.0 - np.exp(-np.where(seen, z, 0.0) / self.look.fog_distance))[:, None]
        lit = (bgr[None, :] * shade[j0:j1, None]) * (1.0 - far) + self._haze[None, :] * far
        lit_u8 = np.clip(lit + 0.5, 0, 255).astype(np.uint8)
        np.copyto(canvas[i0:i1, j0:j1], lit_u8[None, :, :], where=mask[..., None])
        np.copyto(depth[i0:i1, j0:j1], z[None, :].astype(np.float32), where=mask)
        np.copyto(label[i0:i1, j0:j1], np.int16(index), where=mask)


class _Still(NamedTuple):
    """The background's parts that depend on the lens's height only."""

    zc: float                        # [m]
    first: int                       # the first canvas row below the horizon
    sky: NDArray[np.uint8]           # (H, W, 3) BGR, the sky everywhere
    base: NDArray[np.float32]        # water without ripples, fogged: every other row, column
    gain: NDArray[np.float32]        # the ripples' amplitude there
    zw_scaled: NDArray[np.float32]   # water depth of every other row [texture px]
