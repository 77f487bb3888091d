"""Unit tests of the simulated battery's pack model (enbarr_plugins.power.sim)."""

from __future__ import annotations

import numpy as np
import pytest

from enbarr_plugins.power.sim import (
    open_circuit_voltage, Pack, SimBatterySettings, SPECS, thruster_power)

pytestmark = pytest.mark.unit

DEFAULTS = {s.name: s.default for s in SPECS}


def settings(**changes: float) -> SimBatterySettings:
    return SimBatterySettings.from_params({**DEFAULTS, **changes})


def test_defaults_are_blue_robotics_14v8_18ah_pack_and_t200_at_16v():
    # Blue Robotics "Lithium-ion Battery (14.8 V, 18 Ah)": 4S, 18 Ah. T200 at 16 V: 5.25 kgf
    # (51.5 N) at about 390 W.
    s = settings()
    assert (s.cells, s.capacity) == (4, 18.0)
    assert (s.thruster_max_thrust, s.thruster_max_power) == (51.5, 390.0)


def test_a_li_ion_cell_is_4v2_full_3v0_empty_and_clipped_outside():
    assert open_circuit_voltage(1.0) == pytest.approx(4.2)
    assert open_circuit_voltage(0.0) == pytest.approx(3.0)
    assert open_circuit_voltage(1.5) == pytest.approx(4.2)
    assert open_circuit_voltage(-0.5) == pytest.approx(3.0)
    socs = np.linspace(0.0, 1.0, 101)
    assert np.all(np.diff([open_circuit_voltage(x) for x in socs]) > 0.0)   # monotonic


def test_thruster_power_goes_as_thrust_to_the_power_1_5():
    assert thruster_power(np.array([51.5]), 390.0, 51.5) == pytest.approx(390.0)
    assert thruster_power(np.array([-25.75, 25.75]), 390.0, 51.5) == pytest.approx(
        2 * 390.0 * 0.5 ** 1.5)
    assert thruster_power(np.zeros(8), 390.0, 51.5) == 0.0


def test_a_full_pack_at_rest_reads_16v8_less_the_hotel_load_drop():
    pack = Pack(settings())
    pack.step(0.0, 0.2)
    assert pack.current == pytest.approx(1.0)
    assert pack.voltage == pytest.approx(16.8 - 1.0 * 0.02)


def test_the_terminal_voltage_sags_by_i_r_and_p_equals_v_i():
    pack = Pack(settings(hotel_current=0.0, internal_resistance=0.1))
    pack.step(400.0, 0.2)
    assert pack.voltage * pack.current == pytest.approx(400.0)
    assert pack.voltage == pytest.approx(16.8 - 0.1 * pack.current, abs=1e-3)


def test_the_charge_falls_by_the_ampere_hours_drawn():
    pack = Pack(settings(hotel_current=9.0, internal_resistance=0.0, start_charge=0.8))
    for _ in range(2000):                 # 9 A for 400 s: 1 Ah of 18
        pack.step(0.0, 0.2)
    assert pack.soc == pytest.approx(0.8 - 1.0 / 18.0)


def test_an_empty_pack_stays_at_zero_charge():
    pack = Pack(settings(start_charge=0.0))
    pack.step(1000.0, 60.0)
    assert pack.soc == 0.0
    assert pack.voltage < 4 * 3.0
