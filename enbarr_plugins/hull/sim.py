"""Simulated hull sensor: the BMP280 driver's topics, a leaking seal and overheating.

``hull/pressure`` and ``hull/temperature`` as the driver publishes them, with a seal that lets
water in and electronics that overheat at chosen times.

The air inside starts at ``pressure`` [Pa] and ``temperature`` [degC]. From ``pressure_rise_at``
[s of world time, ``EnbarrNode.world_time``] the pressure climbs ``pressure_rise_rate`` Pa/s
(water displacing air in a sealed can); from ``heat_at`` the temperature climbs
``heat_rate`` degC/s. Negative times: never. Gaussian noise of ``pressure_noise`` and
``temperature_noise`` on each sample, quantised as the chip's registers are (0.01 degC, 1/256
Pa). For exercising the internal pressure and temperature failsafes without a wet enclosure.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from sensor_msgs.msg import FluidPressure, Temperature

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics

SPECS = [
    ParamSpec('rate', 2.0, 'Samples per second', 'Hz', 0.1, 50.0, read_only=True),
    ParamSpec('pressure', 101325.0, 'Air pressure inside the hull at start', 'Pa', 30000.0,
              200000.0),
    ParamSpec('temperature', 25.0, 'Air temperature inside the hull at start', 'degC', -40.0,
              85.0),
    ParamSpec('pressure_rise_at', -1.0, 'World time from which the pressure climbs (negative: '
              'never)', 's', -1.0, 1e6),
    ParamSpec('pressure_rise_rate', 100.0, 'How fast it climbs then', 'Pa/s', 0.0, 1e5),
    ParamSpec('heat_at', -1.0, 'World time from which the temperature climbs (negative: '
              'never)', 's', -1.0, 1e6),
    ParamSpec('heat_rate', 1.0, 'How fast it climbs then', 'degC/s', 0.0, 100.0),
    ParamSpec('pressure_noise', 1.3, 'Pressure noise, one standard deviation', 'Pa', 0.0,
              1000.0),
    ParamSpec('temperature_noise', 0.01, 'Temperature noise, one standard deviation', 'degC',
              0.0, 10.0),
    ParamSpec('seed', 0, 'Noise seed (0: from the operating system)', '', 0, 2 ** 31 - 1,
              read_only=True),
]


@dataclass(frozen=True)
class SimHullSettings:
    """Settings of ``SimHullNode`` (see ``SPECS``)."""

    rate: float                # [Hz]
    pressure: float            # [Pa]
    temperature: float         # [degC]
    pressure_rise_at: float    # [s], negative: never
    pressure_rise_rate: float  # [Pa/s]
    heat_at: float             # [s], negative: never
    heat_rate: float           # [degC/s]
    pressure_noise: float      # [Pa]
    temperature_noise: float   # [degC]
    seed: int

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimHullSettings:
        """Build from the declared parameters' values."""
        return cls(**{k: (int(v[k]) if k == 'seed' else float(v[k]))
                      for k in cls.__dataclass_fields__})


def hull_air(s: SimHullSettings, t: float) -> tuple[float, float]:
    """Return the true (pressure [Pa], temperature [degC]) inside the hull at world time t."""
    p = s.pressure + (s.pressure_rise_rate * (t - s.pressure_rise_at)
                      if 0.0 <= s.pressure_rise_at <= t else 0.0)
    c = s.temperature + (s.heat_rate * (t - s.heat_at) if 0.0 <= s.heat_at <= t else 0.0)
    return p, c


class SimHullNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'hull', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimHullSettings
        self.bind_settings(SPECS, SimHullSettings.from_params, self._apply)
        self._rng = np.random.default_rng(self.settings.seed or None)
        self._pressure = self.create_topic_publisher(topics.HULL_PRESSURE)
        self._temperature = self.create_topic_publisher(topics.HULL_TEMPERATURE)
        self.create_source_timer(1.0 / self.settings.rate, self._tick)

    def _apply(self, settings: SimHullSettings) -> None:
        self.settings = settings

    def _tick(self) -> None:
        s = self.settings
        pressure, temperature = hull_air(s, self.world_time())
        noise_p, noise_t = self._rng.standard_normal(2)
        stamp = self.get_clock().now().to_msg()
        p = FluidPressure()
        p.header.stamp = stamp
        p.fluid_pressure = round((pressure + s.pressure_noise * noise_p) * 256.0) / 256.0
        p.variance = s.pressure_noise ** 2
        t = Temperature()
        t.header.stamp = stamp
        t.temperature = round(temperature + s.temperature_noise * noise_t, 2)
        self._pressure.publish(p)
        self._temperature.publish(t)
