"""The surface station driving the simulated ROV (``enbarr_station_sim``) from headless chromium.

The ROV's command is the velocity goal on ``surface_command/twist`` and the lights on
``surface_command/io``: what the command receiver makes of them is watched on the graph.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from support.browser import chromium, Composed, missing
from support.waiting import poll_until

# alone (setup.cfg): a browser or two vessels take the machine; run after the parallel pass
pytestmark = [pytest.mark.e2e, pytest.mark.alone]

if missing():
    pytest.skip(missing(), allow_module_level=True)

from selenium.webdriver.common.by import By  # noqa: E402 - after the skip


class Rov(Composed):
    """The composed ROV simulation and what the probe saw."""

    def __init__(self) -> None:
        from enbarr_interfaces import convert, topics
        super().__init__('enbarr_station_sim', ['station.port=0', 'station.max_linear=0.4'])
        self.station = self.node('station')
        self.sent: list[tuple[float, ...]] = []
        self.goals: list[tuple[float, ...]] = []
        self.io: list[Any] = []
        self.odometry: Any = None
        self.sink(topics.SURFACE_TWIST,
                  lambda m: self.sent.append(tuple(convert.twist_to_nu(m.twist))))
        self.sink(topics.TRAJECTORY_REQUEST,
                  lambda m: self.goals.append(tuple(convert.twist_to_nu(m.twist))))
        self.sink(topics.IO_REQUEST, self.io.append)
        self.sink(topics.SIM_ODOMETRY, self._on_odometry)

    def _on_odometry(self, msg: Any) -> None:
        self.odometry = msg

    def position(self) -> tuple[float, float, float]:
        p = self.odometry.pose.pose.position
        return p.x, p.y, p.z


@pytest.fixture(scope='module')
def rov() -> Iterator[Rov]:
    r = Rov()
    try:
        assert r.spin_until(lambda: r.odometry is not None), 'no sim/odometry on DDS'
        yield r
    finally:
        r.close()


# The W3C Gamepad "standard" mapping of a DualShock 4 (test_station_browser.py's).
FAKE_PAD = """
window.fakePad = {connected: true, id: 'Wireless Controller (STANDARD GAMEPAD)',
  mapping: 'standard', axes: [0, 0, 0, 0],
  buttons: Array.from({length: 17}, () => ({pressed: false, value: 0}))};
navigator.getGamepads = () => [window.fakePad];
"""


def key(driver: Any, name: str, down: bool) -> None:
    kind = 'keydown' if down else 'keyup'
    driver.execute_script(
        f"document.dispatchEvent(new KeyboardEvent('{kind}', {{key: arguments[0]}}))", name)


def test_the_page_drives_the_rov_and_closing_it_stops_it(rov):
    with chromium() as driver:
        driver.get(rov.station.server.url)
        assert poll_until(lambda: driver.find_element(By.ID, 'conn').text == 'connected', 20.0)
        assert driver.find_element(By.ID, 'lights-row').is_displayed()
        assert poll_until(lambda: 'vert_rear_left' in driver.find_element(
            By.ID, 'actuators').text, 20.0)
        x0, y0, _ = rov.position()
        key(driver, 'w', True)
        # w at the page's stick 0.5 of max_linear 0.4 m/s: a goal of 0.2 m/s ahead.
        assert rov.spin_until(lambda: rov.goals and rov.goals[-1][0] == pytest.approx(0.2))
        assert rov.spin_until(lambda: abs(rov.position()[0] - x0)
                              + abs(rov.position()[1] - y0) > 0.3, 40.0)
        key(driver, 'l', True)
        assert rov.spin_until(lambda: any(m.name == 'gpio_12' and m.value.bool_value
                                          for m in rov.io))
        # The manipulator: manipulator_step (50) steps, the keyboard teleop's io request;
        # the page shows the lights' and the stepper's state from io_state.
        driver.find_element(By.ID, 'manipulator-plus').click()
        assert rov.spin_until(lambda: any(m.name == 'manipulator'
                                          and m.value.integer_value == 50 for m in rov.io))
        assert poll_until(lambda: driver.find_element(By.ID, 'manipulator-state').text == '50'
                          and driver.find_element(By.ID, 'lights-state').text == 'on', 20.0)
        # A gamepad is the ROV pilot's pad (docs/rov_gamepad.png): right stick surge, left stick
        # heave (the W3C standard mapping: axes[3] right y, axes[1] left y, up -1); cross
        # asks for depth hold, options toggles the lights.
        key(driver, 'w', False)
        driver.execute_script(FAKE_PAD)
        driver.execute_script('window.fakePad.axes[3] = -0.5; window.fakePad.axes[1] = -0.25')
        assert rov.spin_until(lambda: rov.goals and rov.goals[-1][:3] == pytest.approx(
            (0.2, 0.0, 0.1)))
        driver.execute_script('window.fakePad.buttons[0] = {pressed: true, value: 1}; '
                              'window.fakePad.buttons[9] = {pressed: true, value: 1}')
        assert rov.spin_until(lambda: any(m.name == 'pilot_mode'
                                          and m.value.string_value == 'depth_hold'
                                          for m in rov.io))
        # the vessel took it (enbarr_sim's simulated Bar30 gives the depth): the page says so
        assert poll_until(lambda: driver.find_element(By.ID, 'mode').text == 'depth_hold',
                          20.0), driver.find_element(By.ID, 'refusal').text
        assert rov.spin_until(lambda: [m.value.bool_value for m in rov.io
                                       if m.name == 'gpio_12'][-1] is False)
        driver.execute_script('window.fakePad.axes[1] = 0')
        key(driver, 'w', True)
        neutrals = rov.station.neutrals_sent
        driver.quit()   # w still held
        assert rov.spin_until(lambda: rov.station.neutrals_sent == neutrals + 1)
        assert rov.spin_until(lambda: rov.sent[-1] == (0.0,) * 6)
        assert rov.spin_until(lambda: rov.goals[-1] == (0.0,) * 6)
        n = len(rov.sent)
        rov.spin_until(lambda: False, 1.5)
        assert len(rov.sent) == n    # silent: the held goal is never repeated
