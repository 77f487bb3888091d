"""The surface station in a real browser: Debian's headless chromium driven by Selenium.

The CS Saucer simulation (``saucer_station_sim``) is composed in this process on a thread of
its own, with the station on a free port and a token; a probe node in a separate rclpy
context watches the graph over DDS as any outside process would (``joy``, ``joy/connected``,
``force_command``, ``sim/odometry``). Every wait is bounded (``poll_until`` / ``spin_until``);
nothing is judged by how long it took.

Skipped, saying why, when chromium or chromium-driver are missing (``./dev test`` installs
them as root: ``ensure_test_packages``). ``ENBARR_STATION_SCREENSHOTS=docs`` makes the
screenshot test write the PNGs of docs/station.md there.
"""

from __future__ import annotations

from collections.abc import Iterator
import os
from pathlib import Path
import shutil
import tempfile
from typing import Any
import urllib.error
import urllib.request

import pytest

from support.browser import chromium, Composed, missing
from support.waiting import poll_until

# alone (setup.cfg): a browser or two vessels take the machine; run after the parallel pass
pytestmark = [pytest.mark.e2e, pytest.mark.alone]

TOKEN = 'browser-test-token'

if missing():
    pytest.skip(missing(), allow_module_level=True)

from selenium import webdriver  # noqa: E402 - after the skip: absent without the browser
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402


class Vessel(Composed):
    """The composed Saucer simulation and what the probe saw."""

    def __init__(self) -> None:
        from enbarr_interfaces import topics
        self.bags = tempfile.mkdtemp(prefix='enbarr-station-bags-')
        super().__init__('saucer_station_sim', [
            'station.port=0', f'station.token={TOKEN}', 'station.input_timeout=0.5'],
            record=os.path.join(self.bags, 'bag'))
        self.station = self.node('station')
        self.dp = self.node('dp_control')
        self.joys: list[Any] = []
        self.connected: list[bool] = []
        self.forces: list[Any] = []
        self.odometry: Any = None
        self.sink(topics.JOY, self.joys.append)
        self.sink(topics.JOY_CONNECTED, lambda m: self.connected.append(m.data))
        self.sink(topics.FORCE_COMMAND, self.forces.append)
        self.sink(topics.SIM_ODOMETRY, self._on_odometry)

    def _on_odometry(self, msg: Any) -> None:
        self.odometry = msg

    @property
    def url(self) -> str:
        return self.station.server.url

    def pose(self) -> tuple[float, float]:
        p = self.odometry.pose.pose.position
        return p.x, p.y

    def close(self) -> None:
        try:
            super().close()
        finally:
            shutil.rmtree(self.bags, ignore_errors=True)


@pytest.fixture(scope='module')
def vessel() -> Iterator[Vessel]:
    v = Vessel()
    try:
        assert v.spin_until(lambda: v.odometry is not None), 'no sim/odometry on DDS'
        yield v
    finally:
        v.close()


@pytest.fixture
def browser() -> Iterator[webdriver.Chrome]:
    with chromium() as driver:
        yield driver


def text(driver: webdriver.Chrome, element_id: str) -> str:
    return driver.find_element(By.ID, element_id).text


def open_page(driver: webdriver.Chrome, vessel: Vessel) -> None:
    driver.get(vessel.url)
    assert poll_until(lambda: text(driver, 'conn') == 'connected', 20.0), text(driver, 'conn')


def hold_key(driver: webdriver.Chrome, key: str, down: bool) -> None:
    # Dispatched to the document as a keyboard user's would be (keydown/keyup events).
    kind = 'keydown' if down else 'keyup'
    driver.execute_script(
        f"document.dispatchEvent(new KeyboardEvent('{kind}', {{key: arguments[0]}}))", key)


def test_the_page_loads_and_its_telemetry_follows_the_vessel(vessel, browser):
    open_page(browser, vessel)
    assert browser.title == 'Enbarr surface station'
    assert poll_until(lambda: text(browser, 'x') != '-', 20.0)
    first = (text(browser, 'x'), text(browser, 'y'), text(browser, 'heading'))
    # The basin's current carries the vessel: the shown pose changes as the vessel moves.
    assert poll_until(lambda: (text(browser, 'x'), text(browser, 'y'),
                               text(browser, 'heading')) != first, 30.0)
    assert text(browser, 'mode') == 'manual'
    assert 'az_bow' in browser.find_element(By.ID, 'actuators').text
    assert '/dp_control' in browser.find_element(By.ID, 'diagnostics').text
    _the_record_buttons_stop_and_start_the_recorder(vessel, browser)
    _the_camera_shows_an_image_with_its_own_boxes(vessel, browser)


def _the_record_buttons_stop_and_start_the_recorder(vessel: Vessel,
                                                    browser: webdriver.Chrome) -> None:
    assert poll_until(lambda: text(browser, 'rec-state') == 'recording', 20.0)
    assert text(browser, 'rec-free').split()[1] in ('kB', 'MB', 'GB')
    browser.find_element(By.ID, 'rec-stop').click()
    assert poll_until(lambda: text(browser, 'rec-state') == 'stopped (recorder/control)', 20.0)
    assert poll_until(lambda: text(browser, 'rec-size') not in ('-', '0 B'), 20.0)
    browser.find_element(By.ID, 'rec-stop').click()    # a stop while stopped: why not
    assert poll_until(lambda: text(browser, 'rec-refusal').startswith('not recording'), 20.0)
    browser.find_element(By.ID, 'rec-start').click()
    assert poll_until(lambda: text(browser, 'rec-state') == 'recording'
                      and text(browser, 'rec-bag').endswith('bag_1'), 20.0)


def _the_camera_shows_an_image_with_its_own_boxes(vessel: Vessel,
                                                  browser: webdriver.Chrome) -> None:
    import cv2
    import numpy as np
    from sensor_msgs.msg import CompressedImage

    from enbarr_interfaces import convert, detections, topics

    ok, jpeg = cv2.imencode('.jpg', np.full((120, 160, 3), 40, np.uint8))
    assert ok
    images = vessel.probe.create_publisher(CompressedImage, topics.CAMERA_COMPRESSED.name,
                                           topics.CAMERA_COMPRESSED.qos)
    boxes = vessel.probe.create_publisher(detections.PointCloud2, topics.DETECTIONS.name,
                                          topics.DETECTIONS.qos)

    def image(stamp_ns: int) -> CompressedImage:
        msg = CompressedImage(format='jpeg', data=jpeg.tobytes())
        convert.ns_to_stamp(stamp_ns, msg.header.stamp)
        return msg

    def shown() -> list[str]:
        return browser.execute_script(
            "const c = document.getElementById('camera');"
            "return [c.dataset.stamp || '', c.dataset.boxes || '']")

    first = 7 * 10**9 + 5
    cloud = detections.to_cloud([(0, 0.9, 20.0, 30.0, 100.0, 90.0)], first,
                                topics.CAMERA_OPTICAL_FRAME)
    assert not vessel.station._camera_subs       # nobody watches: not subscribed
    browser.find_element(By.ID, 'camera-toggle').click()
    assert vessel.spin_until(lambda: (images.publish(image(first)), boxes.publish(cloud),
                                      shown() == ['7.5', '1'])[2], 30.0), shown()
    # The box's left edge (x = 20) in the box colour (#00e676) over the image's dark grey.
    r, g, b, _ = browser.execute_script(
        "return Array.from(document.getElementById('camera').getContext('2d')"
        ".getImageData(20, 60, 1, 1).data)")
    assert g > 150 and r < 100, (r, g, b)
    # The next image has no detections of its own: the last boxes are not drawn on it.
    assert vessel.spin_until(lambda: (images.publish(image(first + 1)),
                                      shown() == ['7.6', '0'])[1], 30.0), shown()
    browser.find_element(By.ID, 'camera-toggle').click()
    assert vessel.spin_until(lambda: not vessel.station._camera_subs, 20.0)


def test_a_key_held_on_the_page_drives_the_simulated_vessel(vessel, browser):
    open_page(browser, vessel)
    assert vessel.spin_until(lambda: vessel.odometry is not None)
    x0, y0 = vessel.pose()
    n_forces = len(vessel.forces)
    hold_key(browser, 'w', True)
    try:
        # w: surge ahead at the page's stick gain: the controller's manual force is ahead...
        assert vessel.spin_until(lambda: any(
            f.wrench.force.x > 0.1 for f in vessel.forces[n_forces:])), 'no surge force'
        assert vessel.spin_until(lambda: vessel.joys[-1].axes[1] > 0.0)  # enbarr_ds4 left_y
        # ...and the simulated vessel moves well beyond what the current alone does.
        assert vessel.spin_until(lambda: abs(vessel.pose()[0] - x0)
                                 + abs(vessel.pose()[1] - y0) > 0.4, 40.0)
    finally:
        hold_key(browser, 'w', False)
    assert vessel.spin_until(lambda: vessel.joys[-1].axes[1] == 0.0)
    assert browser.find_element(By.ID, 'input-stale').is_displayed() is False


def test_an_on_screen_button_held_drives_and_released_stops(vessel, browser):
    from selenium.webdriver.common.action_chains import ActionChains
    open_page(browser, vessel)
    button = browser.find_element(By.CSS_SELECTOR, '.hold[data-axis="sway"][data-dir="1"]')
    ActionChains(browser).click_and_hold(button).perform()
    # enbarr_ds4: left_x is axis 0, left = +1: sway to port at the slider's 0.5.
    assert vessel.spin_until(lambda: vessel.joys and vessel.joys[-1].axes[0] == 0.5)
    ActionChains(browser).release(button).perform()
    assert vessel.spin_until(lambda: vessel.joys[-1].axes[0] == 0.0)


# The W3C Gamepad "standard" mapping, as a browser presents a DualShock 4: buttons[0] the
# bottom face button (cross), [1] right (circle), [2] left (square), [3] top (triangle);
# axes[0] left stick x (right +1), axes[1] left stick y (down +1), axes[2] right stick x.
FAKE_PAD = """
window.fakePad = {connected: true, id: 'Wireless Controller (STANDARD GAMEPAD)',
  mapping: 'standard', axes: [0, 0, 0, 0],
  buttons: Array.from({length: 17}, () => ({pressed: false, value: 0}))};
navigator.getGamepads = () => [window.fakePad];
"""


def pad(driver: webdriver.Chrome, script: str) -> None:
    driver.execute_script(script)


def test_a_gamepad_drives_and_changes_the_mode_as_the_manual_says(vessel, browser):
    open_page(browser, vessel)
    pad(browser, FAKE_PAD)
    pad(browser, 'window.fakePad.axes[1] = -0.8')      # left stick pushed up
    # enbarr_ds4 (ds4_driver's order): left_y is axis 1, up = +1: surge ahead.
    assert vessel.spin_until(lambda: vessel.joys and vessel.joys[-1].axes[1] == pytest.approx(
        0.8, abs=1e-6))
    neutrals = vessel.station.neutrals_sent
    n = len(vessel.joys)
    # Held still for many input periods: the page keeps sending, the station keeps driving.
    assert vessel.spin_until(lambda: len(vessel.joys) >= n + 40)
    assert vessel.station.neutrals_sent == neutrals and vessel.station.driving
    assert all(j.axes[1] == pytest.approx(0.8, abs=1e-6) for j in vessel.joys[n:])
    pad(browser, 'window.fakePad.axes[1] = 0')
    # Triangle: automatic (hold the pose), CS Saucer manual section 3.2.5.
    pad(browser, 'window.fakePad.buttons[3] = {pressed: true, value: 1}')
    assert poll_until(lambda: text(browser, 'mode') == 'automatic', 20.0), text(browser, 'mode')
    assert vessel.dp.mode.value == 'automatic'
    pad(browser, 'window.fakePad.buttons[3] = {pressed: false, value: 0}')
    # Cross: back to manual.
    pad(browser, 'window.fakePad.buttons[0] = {pressed: true, value: 1}')
    assert poll_until(lambda: text(browser, 'mode') == 'manual', 20.0), text(browser, 'mode')
    pad(browser, 'window.fakePad.buttons[0] = {pressed: false, value: 0}')
    assert 'Wireless Controller' in text(browser, 'gamepad')


def row(driver: webdriver.Chrome, node: str, name: str) -> Any:
    return driver.find_element(
        By.CSS_SELECTOR, f'tr.param[data-node="{node}"][data-name="{name}"]')


def test_a_gain_edit_is_applied_and_a_refused_one_shows_its_reason(vessel, browser):
    open_page(browser, vessel)
    browser.find_element(By.ID, 'tab-tune').click()   # (re)loads the table
    assert poll_until(lambda: browser.find_element(By.ID, 'params').get_attribute(
        'data-state') == 'ready', 20.0)
    assert len(browser.find_elements(
        By.CSS_SELECTOR, 'tr.param[data-node="/dp_control"][data-name="kp"]')) == 1
    kp = list(vessel.dp.get_parameter('kp').value)
    inputs = row(browser, '/dp_control', 'kp').find_elements(By.CSS_SELECTOR, '.editor input')
    assert len(inputs) == 3 and float(inputs[0].get_attribute('value')) == kp[0]
    inputs[0].clear()
    inputs[0].send_keys('12.5', Keys.TAB)
    status = row(browser, '/dp_control', 'kp').find_element(By.CLASS_NAME, 'param-status')
    assert poll_until(lambda: status.text == 'applied', 20.0), status.text
    assert list(vessel.dp.get_parameter('kp').value) == [12.5, *kp[1:]]
    inputs[1].clear()
    inputs[1].send_keys('-3', Keys.TAB)
    assert poll_until(lambda: status.text.startswith('refused'), 20.0), status.text
    assert status.text == 'refused: kp[1] = -3.0 is outside [0.0, 10000.0]'
    assert list(vessel.dp.get_parameter('kp').value) == [12.5, *kp[1:]]
    assert float(inputs[1].get_attribute('value')) == kp[1]   # back to what the node kept
    inputs[0].clear()
    inputs[0].send_keys(str(kp[0]), Keys.TAB)
    assert poll_until(lambda: status.text == 'applied', 20.0)


def test_a_refused_mode_change_shows_its_reason(vessel, browser):
    open_page(browser, vessel)
    assert poll_until(lambda: text(browser, 'mode') == 'manual', 20.0)
    # cross (manual) while manual: the controller refuses it, 'already manual'.
    browser.find_element(By.ID, 'mode-manual').click()
    assert poll_until(lambda: text(browser, 'refusal') == 'manual: already manual', 20.0), \
        text(browser, 'refusal')
    assert vessel.dp.refusals >= 1


def _drive(vessel: Vessel, browser: webdriver.Chrome) -> int:
    """Open the page and hold w until the controller pushes ahead; the joy count then."""
    open_page(browser, vessel)
    n = len(vessel.forces)
    hold_key(browser, 'w', True)
    assert vessel.spin_until(lambda: any(f.wrench.force.x > 0.1 for f in vessel.forces[n:]))
    assert vessel.spin_until(lambda: vessel.connected[-1] is True) and vessel.station.driving
    return vessel.station.neutrals_sent


def _assert_failsafe(vessel: Vessel, neutrals_before: int) -> None:
    # One neutral sample and joy/connected False: the controller's connection rule drops to
    # manual with zero force at once...
    assert vessel.spin_until(lambda: vessel.connected[-1] is False)
    assert vessel.spin_until(lambda: vessel.forces[-1].wrench.force.x == 0.0
                             and vessel.forces[-1].wrench.force.y == 0.0
                             and vessel.forces[-1].wrench.torque.z == 0.0)
    # (joy and joy/connected are two topics: their samples may arrive in either order)
    assert vessel.spin_until(lambda: vessel.joys[-1].axes[1] == 0.0)
    assert vessel.station.neutrals_sent == neutrals_before + 1 and not vessel.station.driving
    # ...and the station then stays silent: no held command is sent on the page's behalf.
    n = len(vessel.joys)
    sent = vessel.station.commands_sent
    vessel.spin_until(lambda: False, 1.5)
    assert len(vessel.joys) == n and vessel.station.commands_sent == sent
    assert vessel.dp.mode.value == 'manual'


@pytest.mark.parametrize('how', ['quit', 'navigate away'])
def test_closing_the_page_trips_the_failsafe(vessel, how):
    with chromium() as driver:
        before = _drive(vessel, driver)
        if how == 'quit':
            driver.quit()   # w still held: the page just goes
        else:
            driver.get('about:blank')
        _assert_failsafe(vessel, before)


def test_a_frozen_page_trips_the_failsafe(vessel, browser):
    before = _drive(vessel, browser)
    # The page's script stops (a frozen tab) while its socket stays open.
    browser.execute_script('stopSending(); state.ws.onclose = null;')
    _assert_failsafe(vessel, before)


def test_the_token_is_required_and_no_path_leaves_the_assets(vessel):
    base = vessel.url.split('?')[0]
    for path in ('', 'static/station.js', 'api/params', 'ws'):
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(base + path, timeout=10)
        assert err.value.code == 401, path
    with urllib.request.urlopen(f'{base}?token={TOKEN}', timeout=10) as r:
        assert r.status == 200
    for path in ('static/..%2fnode.py', 'static/%2e%2e%2fserver.py', 'static/..%5cnode.py'):
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(f'{base}{path}?token={TOKEN}', timeout=10)
        assert err.value.code == 404, path


def test_screenshots_of_the_main_views(vessel, browser, tmp_path):
    out = Path(os.environ.get('ENBARR_STATION_SCREENSHOTS') or tmp_path)
    open_page(browser, vessel)
    hold_key(browser, 'w', True)
    hold_key(browser, 'q', True)
    assert poll_until(lambda: text(browser, 'x') != '-', 20.0)
    vessel.spin_until(lambda: False, 8.0)   # let a trail build up on the map
    hold_key(browser, 'q', False)
    hold_key(browser, 'w', False)
    assert browser.save_screenshot(str(out / 'station_drive.png'))
    browser.find_element(By.ID, 'tab-tune').click()
    assert poll_until(lambda: browser.find_element(By.ID, 'params').get_attribute(
        'data-state') == 'ready', 20.0)
    browser.find_element(By.ID, 'filter').send_keys('dp_control')
    assert len(browser.find_elements(By.CSS_SELECTOR, 'tr.param')) > 10
    assert not browser.find_element(By.ID, 'view-drive').is_displayed()
    assert not browser.find_element(
        By.CSS_SELECTOR, 'div.node[data-node="/allocation"]').is_displayed()
    assert browser.save_screenshot(str(out / 'station_tune.png'))
    assert (out / 'station_drive.png').stat().st_size > 10_000
