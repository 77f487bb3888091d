"""What the depth sensor's driver and its simulated twin share: parameters and topics.

``DEPTH_SPECS``: the water and the zero (``fluid_density``, ``surface_pressure``, where 0
re-zeroes on the next reading) and the published depth variance. ``DepthTopics`` publishes
one reading on ``pressure`` (``sensor_msgs/FluidPressure``, Pa), ``pressure/temperature``
(``sensor_msgs/Temperature``, degC) and ``depth`` (``geometry_msgs/PoseWithCovarianceStamped``,
position.z = -depth in odom ENU, variance in covariance[14], every other axis unobserved).
"""

from __future__ import annotations

from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import FluidPressure, Temperature

from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins.pressure.ms5837_protocol import DENSITY_FRESH, depth

#: Variance published for the unobserved axes of ``depth`` [m^2 / rad^2].
UNOBSERVED = 1e9

DEPTH_SPECS = [
    ParamSpec('fluid_density', DENSITY_FRESH, 'Water density for the depth: 997 fresh, 1029 '
              'salt', 'kg/m^3', 900.0, 1100.0),
    ParamSpec('surface_pressure', 101325.0, 'Pressure at the surface (depth 0); 0 takes the '
              'next reading as the surface (re-zero)', 'Pa', 0.0, 200000.0),
    ParamSpec('depth_noise', 0.002, 'Depth standard deviation published in covariance[14]',
              'm', 0.0, 10.0),
]


class DepthTopics:
    """The three publishers of a depth sensor and its zero (see the module docstring)."""

    def __init__(self, node: Any) -> None:
        self._node = node
        self._pressure = node.create_topic_publisher(topics.PRESSURE)
        self._temperature = node.create_topic_publisher(topics.PRESSURE_TEMPERATURE)
        self._depth = node.create_topic_publisher(topics.DEPTH)
        #: The surface pressure in use [Pa]; None: the next reading becomes it.
        self.surface: float | None = None

    def set_surface(self, surface_pressure: float) -> None:
        """Take the ``surface_pressure`` parameter [Pa]: 0 re-zeroes on the next reading."""
        self.surface = surface_pressure or None

    def publish(self, stamp: Time, pressure: float, temperature: float, density: float,
                depth_noise: float) -> None:
        """Publish ``pressure`` [Pa], ``temperature`` [degC] and the depth they give."""
        if self.surface is None:
            self.surface = pressure
            self._node.get_logger().info(f'depth zeroed at {pressure:.0f} Pa')
        p = FluidPressure()
        p.header.stamp = stamp
        p.header.frame_id = topics.PRESSURE_FRAME
        p.fluid_pressure = pressure
        self._pressure.publish(p)
        t = Temperature()
        t.header.stamp = stamp
        t.header.frame_id = topics.PRESSURE_FRAME
        t.temperature = temperature
        self._temperature.publish(t)
        d = PoseWithCovarianceStamped()
        d.header.stamp = stamp
        d.header.frame_id = topics.WORLD_FRAME
        d.pose.pose.position.z = -depth(pressure, self.surface, density)
        d.pose.pose.orientation.w = 1.0
        c = d.pose.covariance
        for i in (0, 7, 21, 28, 35):
            c[i] = UNOBSERVED
        c[14] = depth_noise ** 2
        self._depth.publish(d)
