"""Simulated battery: the ``battery`` topic of ``ina219_battery`` from a pack model.

The pack: ``cells`` Li-ion cells in series, ``capacity`` [Ah], starting at ``start_charge``
(0..1). Its terminal voltage is the open-circuit voltage at the state of charge less the drop
on the internal resistance, V = cells * OCV(SoC) - I R, and the charge falls by the current
drawn, dSoC/dt = -I / (3600 capacity). The current is the thrusters' electric power over the
voltage plus a constant ``hotel_current`` (computer, lights, camera). A thruster's power goes
as its thrust to the power 1.5 (momentum theory: P = T^1.5 / sqrt(2 rho A)), scaled so that
``thruster_max_thrust`` draws ``thruster_max_power``.

Default numbers:

- the pack is Blue Robotics' "Lithium-ion Battery (14.8 V, 18 Ah)" (bluerobotics.com, the
  battery's product page and data sheet): 4S (14.8 V nominal, 16.8 V full), 18 Ah;
- the thruster is Blue Robotics' T200 at 16 V (its published performance chart): 5.25 kgf
  (51.5 N, the profile's ``max_forward``) at about 390 W;
- the internal resistance (20 mOhm for the pack) and the hotel load (1 A) are estimates, not
  from a data sheet: set them from a discharge test of your pack;
- ``OCV``: the open-circuit voltage of one Li-ion (NMC) cell against its state of charge, a
  typical published curve rounded to 10 mV (3.0 V empty, 4.2 V full), not Blue Robotics'
  own cells' curve.

It samples at ``rate`` on the node's clock and publishes what the driver publishes: voltage,
current (negative while discharging), percentage (the model's state of charge); the rest NaN.
It keeps only the latest ``sim/thrust`` message per simulator step (no work per sample).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from sensor_msgs.msg import BatteryState, JointState

from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec
from enbarr_interfaces import topics

NAN = float('nan')
#: One Li-ion (NMC) cell's open-circuit voltage [V] at state of charge 0, 0.1, ..., 1.0.
OCV = (3.00, 3.45, 3.55, 3.62, 3.68, 3.74, 3.80, 3.88, 3.96, 4.06, 4.20)

SPECS = [
    ParamSpec('rate', 5.0, 'Samples per second (as the driver)', 'Hz', 0.1, 50.0,
              read_only=True),
    ParamSpec('cells', 4, 'Li-ion cells in series', '', 1, 14),
    ParamSpec('capacity', 18.0, 'Pack capacity', 'Ah', 0.01, 1000.0),
    ParamSpec('start_charge', 1.0, 'State of charge at start', '', 0.0, 1.0),
    ParamSpec('internal_resistance', 0.02, 'Pack internal resistance', 'ohm', 0.0, 10.0),
    ParamSpec('hotel_current', 1.0, 'Current of everything but the thrusters', 'A', 0.0,
              100.0),
    ParamSpec('thruster_max_power', 390.0, 'Electric power of one thruster at its '
              'thruster_max_thrust', 'W', 0.0, 10000.0),
    ParamSpec('thruster_max_thrust', 51.5, 'Thrust of one thruster at thruster_max_power',
              'N', 0.1, 10000.0),
]


@dataclass(frozen=True)
class SimBatterySettings:
    """Settings of ``SimBatteryNode`` (``SPECS``)."""

    rate: float                  # [Hz]
    cells: int
    capacity: float              # [Ah]
    start_charge: float          # 0..1
    internal_resistance: float   # [ohm]
    hotel_current: float         # [A]
    thruster_max_power: float    # [W]
    thruster_max_thrust: float   # [N]

    @classmethod
    def from_params(cls, v: Mapping[str, Any]) -> SimBatterySettings:
        """Build from the declared parameters' values."""
        return cls(**{name: v[name] for name in cls.__dataclass_fields__})


def open_circuit_voltage(soc: float) -> float:
    """Return one cell's open-circuit voltage [V] at state of charge ``soc`` (clipped 0..1)."""
    return float(np.interp(min(1.0, max(0.0, soc)), np.linspace(0.0, 1.0, len(OCV)), OCV))


def thruster_power(thrust: np.ndarray, max_power: float, max_thrust: float) -> float:
    """Return the electric power [W] of thrusters producing ``thrust`` [N] each."""
    return float(max_power * np.sum((np.abs(thrust) / max_thrust) ** 1.5))


class Pack:
    """The pack's state of charge and terminal voltage (module docstring)."""

    def __init__(self, s: SimBatterySettings) -> None:
        self.settings = s
        self.soc = s.start_charge
        self.current = 0.0                                     # drawn [A]
        self.voltage = s.cells * open_circuit_voltage(self.soc)  # terminal [V]

    def step(self, power: float, dt: float) -> None:
        """Draw ``power`` [W] of thrusters (plus the hotel load) for ``dt`` [s]."""
        s = self.settings
        ocv = s.cells * open_circuit_voltage(self.soc)
        # P = V I with V = ocv - I R: the smaller root of R I^2 - ocv I + P = 0 (the other is
        # the far side of maximum power, which a pack never runs at).
        r = s.internal_resistance
        disc = ocv * ocv - 4.0 * r * power
        thrusters = power / ocv if r == 0.0 else (
            (ocv - math.sqrt(disc)) / (2.0 * r) if disc > 0.0 else ocv / (2.0 * r))
        self.current = thrusters + s.hotel_current
        self.voltage = max(0.0, ocv - self.current * r)
        self.soc = max(0.0, self.soc - self.current * dt / (3600.0 * s.capacity))


class SimBatteryNode(EnbarrNode):
    """See the module docstring."""

    def __init__(self, node_name: str = 'battery', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.settings: SimBatterySettings
        self.pack: Pack | None = None
        self.bind_settings(SPECS, SimBatterySettings.from_params, self._apply)
        self._thrust: JointState | None = None
        self._last_ns: int | None = None
        self._pub = self.create_topic_publisher(topics.BATTERY)
        self.create_topic_subscription(topics.SIM_THRUST, self._on_thrust)
        self.create_source_timer(1.0 / self.settings.rate, self._sample)

    def _apply(self, settings: SimBatterySettings) -> None:
        self.settings = settings
        if self.pack is None:
            self.pack = Pack(settings)
        else:   # new numbers act from now; the charge drawn stays drawn
            self.pack.settings = settings

    def _on_thrust(self, msg: JointState) -> None:
        self._thrust = msg   # the latest only: the model steps at `rate`

    def _sample(self) -> None:
        assert self.pack is not None
        now = self.now_ns()
        last, self._last_ns = self._last_ns, now
        dt = 0.0 if last is None or now < last else (now - last) * 1e-9
        s = self.settings
        power = 0.0 if self._thrust is None else thruster_power(
            np.asarray(self._thrust.effort, dtype=float), s.thruster_max_power,
            s.thruster_max_thrust)
        self.pack.step(power, dt)
        msg = BatteryState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.voltage = self.pack.voltage
        msg.current = -self.pack.current
        msg.percentage = self.pack.soc
        msg.temperature = msg.charge = msg.capacity = msg.design_capacity = NAN
        msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
        msg.present = True
        self._pub.publish(msg)
