"""Simulated RPLidar A1 (``sim_lidar``): the profile's world scanned from the true pose.

It ray-casts the profile's ``world`` (``EnbarrNode.world``) from the lidar's mount, the
frame tree's ``frame_id`` frame in ``base_link``, at the simulated vessel's true pose
(``sim/odometry``), with the A1's error model of ``sim_scan`` (the CS Saucer manual's
figures), and publishes what the real driver (``rplidar``) publishes: one
``sensor_msgs/LaserScan`` per revolution on ``scan``, in the lidar's own frame, ``bins``
rays of a fixed increment from -pi (``scan.bin_revolution``, REP-117 special values),
``time_increment`` 0, ``range_min`` 0.15 m and ``range_max`` 12 m.

Time: the truth's stamps schedule the revolutions, one every ``1 / rotation_hz`` of the
node clock (simulated time in a scenario, as ``sim_mocap`` does). A revolution is cast at
one instant: the truth's pose and the world at that stamp (``EnbarrNode.world_time``), and
the scan carries that stamp and ``scan_time`` = 1 / ``rotation_hz``. In ``stall_windows``
(world time) no scan is published at all, as when the lidar is unplugged or stalls. The real
A1 sweeps for a whole period, so a scan taken while turning smears; the simulated one does
not, so ``scan_obstacles`` reads it with ``sweep: at_stamp`` (its default reads the A1's
sweep from the stamp on).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from nav_msgs.msg import Odometry

from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import convert, topics
from enbarr_plugins.lidar.common import laser_scan
from enbarr_plugins.lidar.sim_scan import A1Model, RANGE_MAX, RANGE_MIN, SimulatedA1
from enbarr_plugins.sim_sensor import TruthSensor

SPECS = [
    ParamSpec('frame_id', topics.LASER_FRAME, "The lidar's own frame: the scan is published "
              'in it, and the frame tree places it on the vessel (base_link)', read_only=True),
    ParamSpec('rotation_hz', 5.5, 'Rotation rate: one scan per revolution (A1: about 5.5 Hz, '
              'adjustable)', 'Hz', 1.0, 15.0),
    ParamSpec('samples', 360, 'Samples per revolution (manual Table 1.1: 1 deg resolution)',
              '', 36, 7200, read_only=True),
    ParamSpec('bins', 360, 'Rays per revolution in the published scan (as the rplidar '
              "driver's bins)", '', 36, 7200, read_only=True),
    ParamSpec('noise_scale', 1.0, "Range error in units of the manual's accuracy (1 % below "
              '3 m, 2 % to 5 m, 2.5 % beyond, read as one standard deviation); 0: exact', '',
              0.0, 10.0),
    ParamSpec('dropout_probability', 0.0, 'Probability that a sample returns nothing', '',
              0.0, 1.0),
    ParamSpec('mask_sectors', [0.0], 'Sectors hidden by the marker rods: start, end, start, '
              'end, ... bearings in the laser frame, CCW (start > end: through 180 deg); the '
              'CS Saucer keeps [-90, 90] clear; [0.0]: none', 'deg', -180.0, 180.0),
    ParamSpec('mask_range', 0.0, "What a masked sample reports: the rod's distance; 0: no "
              'return (a rod inside the 0.15 m blind zone)', 'm', 0.0, RANGE_MAX),
    ParamSpec('stall_windows', [0.0], 'No scan at all (the lidar unplugged or stalled): start, '
              'end, start, end, ... [s] of world time (a scenario: since its start); [0.0]: '
              'never', 's', 0.0, 1e6),
    ParamSpec('seed', 3, 'Seed of the noise generator', '', 0, 2**31 - 1, read_only=True),
]


@dataclass(frozen=True)
class SimLidarSettings:
    """Settings of ``SimLidarNode`` (see ``SPECS``)."""

    frame_id: str
    rotation_hz: float  # [Hz]
    bins: int
    model: A1Model
    seed: int
    stall_windows: tuple[tuple[float, float], ...] = ()  # (start, end) world time [s]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimLidarSettings:
        """Build from the declared parameters' values (ValueError naming the parameter)."""
        frame_id = v['frame_id'].strip()
        if not frame_id or frame_id.startswith('/') or ' ' in frame_id:
            raise ValueError(f"frame_id: a frame name such as 'laser' (no leading '/', no "
                             f"spaces), got {v['frame_id']!r}")
        m = [float(a) for a in v['mask_sectors']]
        sectors: tuple[tuple[float, float], ...] = ()
        if m != [0.0]:
            if len(m) % 2 or any(a == b for a, b in zip(m[::2], m[1::2])):
                raise ValueError('mask_sectors: expected pairs of start, end bearings [deg], '
                                 'start != end')
            sectors = tuple(zip(m[::2], m[1::2]))
        if 0.0 < v['mask_range'] < RANGE_MIN:
            raise ValueError(f'mask_range: 0 (no return) or a distance the A1 measures, '
                             f'{RANGE_MIN} to {RANGE_MAX} m; got {v["mask_range"]}')
        model = A1Model(int(v['samples']), v['noise_scale'], v['dropout_probability'],
                        sectors, v['mask_range'])
        w = [float(a) for a in v['stall_windows']]
        stalls: tuple[tuple[float, float], ...] = ()
        if w != [0.0]:
            if len(w) % 2 or any(b <= a for a, b in zip(w[::2], w[1::2])):
                raise ValueError('stall_windows: expected pairs of start < end times [s]')
            stalls = tuple(zip(w[::2], w[1::2]))
        return cls(frame_id, v['rotation_hz'], int(v['bins']), model, int(v['seed']), stalls)


class SimLidarNode(TruthSensor):
    """See the module docstring."""

    def __init__(self, node_name: str = 'lidar', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimLidarSettings
        self.bind_settings(SPECS, SimLidarSettings.from_params, self._apply)
        s = self.settings
        mount = self.mount(s.frame_id, 'lidar')
        self.lidar = SimulatedA1(self.world, mount, s.model, np.random.default_rng(s.seed))
        self._next_ns: int | None = None
        self.revolutions = 0
        self.stalled = 0
        self._pub = self.create_topic_publisher(topics.SCAN)
        self.create_topic_subscription(topics.SIM_ODOMETRY, self._on_truth)

    def _apply(self, s: SimLidarSettings) -> None:
        self.settings = s
        lidar = getattr(self, 'lidar', None)
        if lidar is not None:
            lidar.set_model(s.model)

    def status_values(self) -> dict[str, Any]:
        """Return the driver's status, with the revolutions published and truths refused."""
        return {**super().status_values(), 'revolutions': self.revolutions,
                'stalled': self.stalled,
                'obstacles': len(self.world), 'refused': self.truth_gate.refused}

    def _on_truth(self, truth: Odometry) -> None:
        t = self.admit_truth(truth)
        if t is None:
            return
        if not self.started:  # a source: silent before start and after stop
            return
        s = self.settings
        period_ns = round(1e9 / s.rotation_hz)
        if self._next_ns is None:
            self._next_ns = t
        if t < self._next_ns:
            return
        self._next_ns += period_ns * max(1, (t - self._next_ns) // period_ns + 1)
        now = self.world_time(t)
        if any(a <= now < b for a, b in s.stall_windows):
            self.stalled += 1  # a stalled lidar sends nothing: consumers see the silence
            return
        pose = truth.pose.pose
        ranges = self.lidar.scan(pose.position.x, pose.position.y,
                                 convert.quaternion_to_yaw(pose.orientation),
                                 now, s.bins)
        self._pub.publish(laser_scan(t, s.frame_id, ranges, 1.0 / s.rotation_hz, RANGE_MIN,
                                     RANGE_MAX))
        self.revolutions += 1
        self.sample_received()
