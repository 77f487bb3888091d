"""The vessel's frame tree: where every sensor sits, declared once in the profile.

A profile's ``frames`` section names each frame with its parent and its pose in that parent
(REP-103: x forward, y left, z up; translation [m], rotation as roll-pitch-yaw [rad] about
the parent's fixed x, y, z axes, as URDF and tf2's ``setRPY``, or as a unit quaternion
``[x, y, z, w]``)::

    frames:
      odom: {}                                        # the root: the world frame (ENU)
      base_link: {parent: odom, pose: observer/odometry}   # dynamic: the pose estimate
      laser: {parent: base_link, xyz: [0.0, 0.0, 0.12]}
      camera_link: {parent: base_link, xyz: [-0.06, 0.0, 0.2]}
      camera_optical_frame: {parent: camera_link, rpy: [-1.5707963267948966, 0.0,
                                                         -1.5707963267948966]}

A frame with ``pose`` is dynamic: its transform is not in the profile but in the messages of
that topic (``nav_msgs/Odometry``: the pose; ``sensor_msgs/Imu``: the orientation only), which
the recorder writes to bags as ``/tf`` and the frame publisher sends on DDS. Every other frame
is static (``/tf_static``). The tree has exactly one root; a profile without a ``frames``
section has the tree ``DEFAULT_TREE``, ``base_link`` alone.

``FrameTree.lookup(target, source)`` composes static transforms as tf2's ``lookupTransform``
does: the result maps coordinates in ``source`` to coordinates in ``target`` (and is the pose of
``source`` in ``target``). A path through a dynamic frame needs that frame's present
transform, given in ``poses``.

Conventions said once (``docs/interfaces.md``, "Frames and conventions"): the 3-DOF model and
every topic are in ROS's ENU/FLU frames (REP-103, REP-105), eta = [x east, y north, psi
counter-clockwise from east]; the CS Saucer manual writes the same model in Fossen's NED
(eta = [N, E, psi], psi clockwise from north): ``ned_to_enu`` and ``enu_to_ned`` convert, and
``compass_heading_deg`` gives what a person reads (0 = north, clockwise, degrees).

Pure: no rclpy here (the per-process tree and its ROS side are in ``framework.node`` and
``framework.frame_sources``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
import math
import re
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from enbarr_core.framework.errors import FrameError, ProfileError
from enbarr_core.framework.kinematics import (quat_conjugate, quat_from_euler, quat_multiply,
                                              quat_to_euler, quat_to_rotmat, ssa)

#: A frame id as tf2 accepts it (no leading slash) and as a YAML key reads.
FRAME_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
#: How far from unit a profile's quaternion may be (typed digits: 0.7071 is 1e-5 short).
QUATERNION_TOLERANCE = 1e-3
FRAME_KEYS = ('parent', 'xyz', 'rpy', 'quaternion', 'pose')


@dataclass(frozen=True)
class Transform:
    """A rigid transform: rotation ``rotation`` (``[x, y, z, w]``) then ``translation`` [m].

    As a pose of frame B in frame A it maps coordinates in B to coordinates in A:
    p_A = R p_B + t.
    """

    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    @classmethod
    def from_rpy(cls, xyz: ArrayLike = (0.0, 0.0, 0.0),
                 rpy: ArrayLike = (0.0, 0.0, 0.0)) -> Transform:
        """Build from ``xyz`` [m] and roll, pitch, yaw [rad]: R = Rz(yaw) Ry(pitch) Rx(roll)."""
        r, p, y = (float(a) for a in np.asarray(rpy, dtype=float))
        return cls(_triple(xyz), _quad(quat_from_euler(r, p, y)))

    @classmethod
    def planar(cls, x: float, y: float, yaw: float) -> Transform:
        """Build a pose in the plane: ``x``, ``y`` [m], ``yaw`` [rad] about z."""
        return cls.from_rpy((x, y, 0.0), (0.0, 0.0, yaw))

    @property
    def rpy(self) -> tuple[float, float, float]:
        """Roll, pitch, yaw [rad] of the rotation (``from_rpy``'s convention)."""
        return quat_to_euler(self.rotation)

    @property
    def rotation_matrix(self) -> NDArray[np.float64]:
        """R, 3x3: a vector in the child frame -> the same vector in the parent frame."""
        return quat_to_rotmat(self.rotation)

    @property
    def matrix(self) -> NDArray[np.float64]:
        """The homogeneous 4x4 matrix [[R, t], [0, 1]]."""
        m = np.eye(4)
        m[:3, :3] = self.rotation_matrix
        m[:3, 3] = self.translation
        return m

    def __matmul__(self, other: Transform) -> Transform:
        """Composition ``self @ other``: ``other`` applied first (T_AC = T_AB @ T_BC)."""
        t = self.rotation_matrix @ np.asarray(other.translation) + np.asarray(self.translation)
        q = quat_multiply(self.rotation, other.rotation)
        return Transform(_triple(t), _quad(q / np.linalg.norm(q)))

    def inverse(self) -> Transform:
        """T^-1: p_B = R^T (p_A - t)."""
        q = quat_conjugate(self.rotation)
        t = -(quat_to_rotmat(q) @ np.asarray(self.translation))
        return Transform(_triple(t), _quad(q))

    def apply(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map points (shape (3,) or (N, 3)) [m] from the child frame into the parent frame."""
        p = np.asarray(points, dtype=float)
        out: NDArray[np.float64] = p @ self.rotation_matrix.T + np.asarray(self.translation)
        return out

    def is_close(self, other: Transform, tol: float = 1e-9) -> bool:
        """Whether both transforms map every point alike (q and -q are the same rotation)."""
        dq = abs(float(np.dot(self.rotation, other.rotation)))
        return (bool(np.allclose(self.translation, other.translation, atol=tol))
                and dq > 1.0 - tol)


IDENTITY = Transform()


@dataclass(frozen=True)
class StampedTransform:
    """A ``geometry_msgs/TransformStamped``: the pose of ``child`` in ``parent`` at a time."""

    stamp_ns: int
    parent: str
    child: str
    transform: Transform


@dataclass(frozen=True)
class Frame:
    """One frame of the tree: its parent and its pose there (static), or its pose source."""

    name: str
    parent: str | None = None        # None: the root
    transform: Transform = IDENTITY  # pose in ``parent``; identity for the root and dynamic
    pose: str = ''                   # topic of a dynamic frame's pose; '' for a static one

    @property
    def dynamic(self) -> bool:
        """Whether the frame moves in its parent (its pose comes from ``pose``)."""
        return bool(self.pose)


@dataclass(frozen=True)
class FrameTree:
    """A validated tree of frames (see the module docstring); immutable.

    Construct with ``FrameTree.of(frames)`` (or ``parse_frames`` from a profile): it checks that
    names are valid and unique, parents known, there is exactly one root and no cycle.
    """

    frames: Mapping[str, Frame]
    root: str
    _paths: Mapping[str, tuple[str, ...]] = field(repr=False, compare=False)

    @classmethod
    def of(cls, frames: Iterable[Frame]) -> FrameTree:
        """Build and check a tree; ``FrameError`` naming the frame at fault."""
        by_name: dict[str, Frame] = {}
        for f in frames:
            if not FRAME_NAME.match(f.name):
                raise FrameError(f'frame {f.name!r}: a frame name is letters, digits and _, '
                                 'starting with a letter')
            if f.name in by_name:
                raise FrameError(f'frame {f.name!r} is declared twice')
            by_name[f.name] = f
        roots = sorted(n for n, f in by_name.items() if f.parent is None)
        if not roots:
            raise FrameError('no root frame (a frame without parent): every frame has a '
                             'parent, so they form a cycle')
        if len(roots) > 1:
            raise FrameError(f'two roots: {", ".join(roots)} have no parent; one frame is '
                             'the root, every other one names its parent')
        for f in by_name.values():
            if f.parent is not None and f.parent not in by_name:
                raise FrameError(f'frame {f.name!r}: unknown parent {f.parent!r}; frames: '
                                 f'{", ".join(sorted(by_name))}')
            if f.dynamic and f.parent is None:
                raise FrameError(f'frame {f.name!r}: the root cannot have a pose source')
        paths: dict[str, tuple[str, ...]] = {}
        for name in by_name:
            chain = [name]
            while by_name[chain[-1]].parent is not None:
                nxt = by_name[chain[-1]].parent
                assert nxt is not None
                if nxt in chain:
                    cycle = ' -> '.join([*chain[chain.index(nxt):], nxt])
                    raise FrameError(f'frame {name!r}: its parents form a cycle: {cycle}')
                chain.append(nxt)
            paths[name] = tuple(chain)  # the frame, its parent, ..., the root
        return cls(dict(by_name), roots[0], paths)

    # -- queries ----------------------------------------------------------------------------
    def __contains__(self, name: object) -> bool:
        return name in self.frames

    def names(self) -> list[str]:
        """Every frame name, parents before children (then by name)."""
        return sorted(self.frames, key=lambda n: (len(self._paths[n]), n))

    def frame(self, name: str) -> Frame:
        """Return the frame ``name``; ``FrameError`` listing the frames if there is none."""
        try:
            return self.frames[name]
        except KeyError:
            raise FrameError(f'no frame {name!r} in the tree; frames: '
                             f'{", ".join(self.names())}') from None

    def static_edges(self) -> list[Frame]:
        """List the static frames but the root (what ``/tf_static`` carries), parents first."""
        return [self.frames[n] for n in self.names()
                if self.frames[n].parent is not None and not self.frames[n].dynamic]

    def static_transforms(self, stamp_ns: int) -> list[StampedTransform]:
        """Every static frame in its parent, stamped ``stamp_ns`` (what ``/tf_static`` holds)."""
        return [StampedTransform(stamp_ns, f.parent, f.name, f.transform)
                for f in self.static_edges() if f.parent is not None]

    def dynamic_frames(self) -> list[Frame]:
        """List the frames whose pose comes from a topic (``/tf``), parents first."""
        return [self.frames[n] for n in self.names() if self.frames[n].dynamic]

    def lookup(self, target: str, source: str,
               poses: Mapping[str, Transform] | None = None) -> Transform:
        """T_target_source: maps coordinates in ``source`` to ``target`` (tf2's order).

        Only the path between the two frames counts: two sensors on ``base_link`` are related
        by static transforms even when ``base_link`` moves. ``poses`` gives the present pose
        of each dynamic frame on that path in its parent, by frame name.
        """
        poses = poses or {}
        up_t, up_s = self._paths[self.frame(target).name], self._paths[self.frame(source).name]
        common = next(n for n in up_t if n in up_s)
        # Compose only below the common ancestor: a dynamic frame above it does not matter.
        below_t = self._chain(up_t[:up_t.index(common)], poses)
        below_s = self._chain(up_s[:up_s.index(common)], poses)
        return below_t.inverse() @ below_s

    def _chain(self, names: Sequence[str], poses: Mapping[str, Transform]) -> Transform:
        """Pose of ``names[0]`` in the parent of ``names[-1]`` (``names`` child to ancestor)."""
        t = IDENTITY
        for n in names:
            f = self.frames[n]
            if f.dynamic:
                pose = poses.get(n)
                if pose is None:
                    raise FrameError(
                        f'{f.parent} -> {n} is dynamic (its pose comes from {f.pose}): give '
                        f'it in poses to look up through it')
                t = pose @ t
            else:
                t = f.transform @ t
        return t

    def transform_points(self, target: str, source: str, points: ArrayLike,
                         poses: Mapping[str, Transform] | None = None) -> NDArray[np.float64]:
        """Points (shape (3,) or (N, 3)) [m] in ``source`` expressed in ``target``."""
        return self.lookup(target, source, poses).apply(points)

    # -- calibration writes back here -------------------------------------------------------
    def with_transform(self, name: str, transform: Transform) -> FrameTree:
        """Return the tree with static frame ``name`` at ``transform`` (a calibration)."""
        f = self.frame(name)
        if f.parent is None or f.dynamic:
            raise FrameError(f'frame {name!r} is the root or dynamic: it has no static pose')
        frames = dict(self.frames)
        frames[name] = Frame(name, f.parent, transform)
        return FrameTree.of(frames.values())

    def to_profile(self) -> dict[str, dict[str, Any]]:
        """Return the tree as a profile's ``frames`` section (what calibration writes)."""
        out: dict[str, dict[str, Any]] = {}
        for n in self.names():
            f = self.frames[n]
            entry: dict[str, Any] = {}
            if f.parent is not None:
                entry['parent'] = f.parent
            if f.dynamic:
                entry['pose'] = f.pose
            elif f.parent is not None:
                entry['xyz'] = list(f.transform.translation)
                entry['quaternion'] = list(f.transform.rotation)
            out[n] = entry
        return out


#: The tree of a profile without a ``frames`` section: the body frame alone.
DEFAULT_TREE = FrameTree.of([Frame('base_link')])


# -- the profile's section ---------------------------------------------------------------------
def parse_frames(raw: Any, where: Callable[[str], str] | str = '') -> FrameTree:
    """Check a profile's ``frames`` section and build its tree (None: ``DEFAULT_TREE``).

    ``where(key)`` names the file that set ``key`` (a dotted key such as ``frames.laser.rpy``);
    every refusal is a ``ProfileError`` naming that file and key.
    """
    def locate(key: str) -> str:
        return where(key) if callable(where) else where

    def refuse(message: str, key: str) -> ProfileError:
        return ProfileError(message, path=locate(key), key=key)

    if raw is None:
        return DEFAULT_TREE
    if not isinstance(raw, dict):
        raise refuse(f'expected a mapping of frame names, got {type(raw).__name__}', 'frames')
    if not raw:
        return DEFAULT_TREE
    frames = []
    for name, entry in raw.items():
        key = f'frames.{name}'
        if not isinstance(name, str) or not FRAME_NAME.match(name):
            raise refuse('a frame name is letters, digits and _, starting with a letter (a '
                         'tf2 frame id: no leading slash)', key)
        if entry is None:
            entry = {}
        if not isinstance(entry, dict):
            raise refuse(f'expected a mapping ({", ".join(FRAME_KEYS)}), got '
                         f'{type(entry).__name__}', key)
        for k in entry:
            if k not in FRAME_KEYS:
                raise refuse(f'unknown key; expected one of: {", ".join(FRAME_KEYS)}',
                             f'{key}.{k}')
        parent = entry.get('parent')
        if parent is not None and (not isinstance(parent, str) or not parent):
            raise refuse('expected the name of another frame', f'{key}.parent')
        pose = entry.get('pose', '')
        if not isinstance(pose, str):
            raise refuse('expected a topic name (nav_msgs/Odometry or sensor_msgs/Imu)',
                         f'{key}.pose')
        if 'rpy' in entry and 'quaternion' in entry:
            raise refuse('give the rotation as rpy or as quaternion, not both', f'{key}.rpy')
        if pose and any(k in entry for k in ('xyz', 'rpy', 'quaternion')):
            raise refuse(f'a dynamic frame (pose: {pose}) has no static xyz/rpy/quaternion',
                         f'{key}.pose')
        xyz = _numbers(entry.get('xyz', (0.0, 0.0, 0.0)), 3, refuse, f'{key}.xyz')
        if 'quaternion' in entry:
            q = np.array(_numbers(entry['quaternion'], 4, refuse, f'{key}.quaternion'))
            norm = float(np.linalg.norm(q))
            if abs(norm - 1.0) > QUATERNION_TOLERANCE:
                raise refuse(f'not a unit quaternion [x, y, z, w]: its norm is {norm:.6g}',
                             f'{key}.quaternion')
            transform = Transform(_triple(xyz), _quad(q / norm))
        else:
            rpy = _numbers(entry.get('rpy', (0.0, 0.0, 0.0)), 3, refuse, f'{key}.rpy')
            transform = Transform.from_rpy(xyz, rpy)
        frames.append(Frame(name, parent, transform, pose))
    try:
        return FrameTree.of(frames)
    except FrameError as err:
        # Blame the frame the message names first (every message starts with it when any).
        named = re.match(r"frame '([A-Za-z0-9_]+)'", str(err))
        key = f'frames.{named.group(1)}' if named else 'frames'
        raise refuse(str(err), key) from None


def _numbers(value: Any, n: int, refuse: Callable[[str, str], ProfileError],
             key: str) -> tuple[float, ...]:
    if (not isinstance(value, (list, tuple)) or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise refuse(f'expected a list of {n} numbers, got {value!r}', key)
    out = tuple(float(v) for v in value)
    if not all(math.isfinite(v) for v in out):
        raise refuse(f'expected finite numbers, got {list(out)}', key)
    return out


def _triple(v: ArrayLike) -> tuple[float, float, float]:
    a, b, c = (float(x) for x in np.asarray(v, dtype=float))
    return a, b, c


def _quad(v: ArrayLike) -> tuple[float, float, float, float]:
    a, b, c, d = (float(x) for x in np.asarray(v, dtype=float))
    return a, b, c, d


# -- NED (the manual, Fossen) and ENU (ROS, this package); the compass ---------------------------
def ned_to_enu(eta_ned: ArrayLike) -> NDArray[np.float64]:
    """[N, E, psi] (NED, psi clockwise from north) -> [x east, y north, yaw CCW from east].

    x = E, y = N, yaw = pi/2 - psi (wrapped to [-pi, pi)); body FRD -> FLU flips sway and
    yaw rate alike (v -> -v, r -> -r), which the model's symmetric matrices leave unchanged.
    """
    n, e, psi = np.asarray(eta_ned, dtype=float)
    return np.array([e, n, ssa(0.5 * math.pi - psi)])


def enu_to_ned(eta_enu: ArrayLike) -> NDArray[np.float64]:
    """[x east, y north, yaw] (ENU) -> [N, E, psi] (NED, psi in [-pi, pi))."""
    x, y, yaw = np.asarray(eta_enu, dtype=float)
    return np.array([y, x, ssa(0.5 * math.pi - yaw)])


def compass_heading_deg(yaw: float | NDArray[np.float64]) -> Any:
    """Compass heading [deg] in [0, 360): 0 = north, 90 = east (clockwise), of ENU ``yaw``."""
    return np.mod(90.0 - np.degrees(yaw), 360.0)


def compass_error_deg(yaw: float | NDArray[np.float64],
                      yaw_ref: float | NDArray[np.float64]) -> Any:
    """Heading minus its reference in compass degrees, wrapped to [-180, 180): + is clockwise."""
    return np.degrees(ssa(np.asarray(yaw_ref) - np.asarray(yaw)))


def format_heading(yaw: float) -> str:
    """``'heading 045 deg (compass)'`` for an ENU ``yaw`` [rad] (log lines say it this way)."""
    h = float(compass_heading_deg(yaw))
    return f'heading {round(h) % 360:03d} deg (compass)'
