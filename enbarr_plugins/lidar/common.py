"""What every lidar plugin of this kind publishes the same way: a revolution's ``LaserScan``.

The real driver (``rplidar``) and the simulated A1 (``sim_lidar``) both bin a revolution into
rays of a fixed increment from -pi, counter-clockwise in the lidar's own frame
(``scan.bin_revolution``), so they build the same message here: consumers cannot tell them
apart by its geometry.
"""

from __future__ import annotations

import math

import numpy as np
from sensor_msgs.msg import LaserScan

from enbarr_interfaces import convert


def laser_scan(stamp_ns: int, frame_id: str, ranges: np.ndarray, scan_time: float,
               range_min: float, range_max: float) -> LaserScan:
    """Return one revolution of ``len(ranges)`` rays from -pi as a ``LaserScan``.

    ``time_increment`` is 0: the rays are binned, not in the order they were measured.
    """
    bins = len(ranges)
    inc = 2.0 * math.pi / bins
    msg = LaserScan()
    convert.ns_to_stamp(stamp_ns, msg.header.stamp)
    msg.header.frame_id = frame_id
    msg.angle_min = -math.pi
    msg.angle_increment = inc
    msg.angle_max = -math.pi + (bins - 1) * inc
    msg.time_increment = 0.0
    msg.scan_time = scan_time
    msg.range_min = range_min
    msg.range_max = range_max
    msg.ranges = ranges.tolist()
    return msg
