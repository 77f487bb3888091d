"""Simulated depth sensor: the MS5837-30BA's topics from the simulator's depth.

It measures the simulated vessel's depth (``sim/odometry``: odom ENU, depth = -z of
base_link; the sensor's offset from base_link is not modelled) at ``rate`` and publishes what
the driver (``ms5837.py``) publishes: absolute pressure p = surface + rho g depth (the
``water_surface_pressure`` and ``water_density`` of the simulated world; depth 0 above the
surface) with white noise
``pressure_noise``, rounded to the chip's output step of 0.1 mbar (10 Pa), and the water
temperature ``water_temperature`` rounded to the chip's 0.01 degC. The default noise, 0.2 mbar,
is the data sheet's headline resolution of the 30BA ("high-resolution module 0.2 mbar"); set it
from a bench measurement at your OSR. The depth is computed from the noisy, rounded pressure
with the driver's parameters (``fluid_density``, ``surface_pressure``, re-zero with 0), so a
controller sees what it would with the chip.

Time: the truth's stamp schedules the measurements (``enbarr_plugins.sim_sensor``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from nav_msgs.msg import Odometry

from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics
from enbarr_plugins.pressure.common import DEPTH_SPECS, DepthTopics
from enbarr_plugins.pressure.ms5837_protocol import G
from enbarr_plugins.sim_sensor import TruthSensor

#: The chip's output steps: P in 0.1 mbar [Pa], TEMP in 0.01 degC.
PRESSURE_STEP = 10.0
TEMPERATURE_STEP = 0.01

SPECS = [
    ParamSpec('rate', 10.0, 'Measurement rate (at most the simulator rate)', 'Hz', 0.1, 100.0,
              read_only=True),
    ParamSpec('pressure_noise', 20.0, 'Pressure noise, std per sample (0.2 mbar: the data '
              "sheet's resolution)", 'Pa', 0.0, 10000.0),
    ParamSpec('water_surface_pressure', 101325.0, 'Air pressure on the simulated water',
              'Pa', 50000.0, 150000.0),
    ParamSpec('water_density', 997.0, 'Density of the simulated water (fluid_density is what '
              'the sensor is told)', 'kg/m^3', 900.0, 1100.0),
    ParamSpec('water_temperature', 15.0, 'Temperature of the simulated water', 'degC', -5.0,
              40.0),
    ParamSpec('seed', 3, 'Seed of the noise generator', '', 0, 2**31 - 1, read_only=True),
    *DEPTH_SPECS,
]


@dataclass(frozen=True)
class SimDepthSettings:
    """Settings of ``SimDepthNode`` (see ``SPECS``)."""

    rate: float                     # [Hz]
    pressure_noise: float           # std [Pa]
    water_surface_pressure: float   # [Pa]
    water_density: float            # [kg/m^3]
    water_temperature: float        # [degC]
    seed: int
    fluid_density: float            # [kg/m^3]
    surface_pressure: float         # [Pa], 0: re-zero on the next reading
    depth_noise: float              # [m]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimDepthSettings:
        """Build from the declared parameters' values."""
        return cls(**{name: v[name] for name in cls.__dataclass_fields__})


def measure(depth: float, s: SimDepthSettings, noise: float) -> tuple[float, float]:
    """Return the chip's (pressure [Pa], temperature [degC]) at ``depth`` [m].

    ``noise`` [Pa] is added; both are rounded to the chip's output steps.
    """
    pressure = s.water_surface_pressure + s.water_density * G * max(depth, 0.0) + noise
    return (round(pressure / PRESSURE_STEP) * PRESSURE_STEP,
            round(s.water_temperature / TEMPERATURE_STEP) * TEMPERATURE_STEP)


class SimDepthNode(TruthSensor):
    """See the module docstring."""

    def __init__(self, node_name: str = 'depth_sensor', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimDepthSettings
        self._topics = DepthTopics(self)
        self.bind_settings(SPECS, SimDepthSettings.from_params, self._apply)
        self._rng = np.random.default_rng(self.settings.seed)
        self._period_ns = round(1e9 / self.settings.rate)
        self._next_ns: int | None = None
        self.create_topic_subscription(topics.SIM_ODOMETRY, self._on_truth)

    def _apply(self, v: SimDepthSettings) -> None:
        self.settings = v
        self._topics.set_surface(v.surface_pressure)

    def status_values(self) -> dict[str, Any]:
        """Return the sample count, the refused truths and the surface pressure in use."""
        return {**super().status_values(), 'refused': self.truth_gate.refused,
                'surface_pressure': self._topics.surface}

    def _on_truth(self, truth: Odometry) -> None:
        t = self.admit_truth(truth)
        if t is None:
            return
        if self._next_ns is None:
            self._next_ns = t
        if t < self._next_ns:
            return
        self._next_ns += self._period_ns * max(1, (t - self._next_ns) // self._period_ns + 1)
        s = self.settings
        noise = float(self._rng.normal(0.0, s.pressure_noise)) if s.pressure_noise else 0.0
        pressure, temperature = measure(-truth.pose.pose.position.z, s, noise)
        self._topics.publish(truth.header.stamp, pressure, temperature, s.fluid_density,
                             s.depth_noise)
        self.sample_received()
