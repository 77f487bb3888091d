"""Debian's headless chromium under Selenium, and a composed profile to point it at.

For the station's browser tests (``docs/station.md``, ``docs/testing.md``): the browser and
its driver are Debian's (``/usr/bin/chromium``, ``/usr/bin/chromedriver``); ``missing``
says why a module must skip. ``Composed`` runs a profile's nodes in this process on a thread of
their own, with a probe node in a separate context that watches the graph over DDS as another
process would.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
import os
import shutil
import tempfile
import threading
from typing import Any

from support.waiting import spin_until

CHROMIUM = '/usr/bin/chromium'
CHROMEDRIVER = '/usr/bin/chromedriver'
FLAGS = ('--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
         '--disable-background-networking', '--disable-component-update', '--disable-sync',
         '--window-size=1400,1000')


def missing() -> str | None:
    """Why the browser tests cannot run here, or None."""
    if os.access(CHROMIUM, os.X_OK) and os.access(CHROMEDRIVER, os.X_OK):
        return None
    return ("the browser tests need Debian's chromium and chromium-driver "
            f'({CHROMIUM}, {CHROMEDRIVER}); as root: apt-get install chromium '
            'chromium-driver (./dev test does it)')


@contextmanager
def chromium() -> Iterator[Any]:
    """A headless chromium with a fresh profile folder, quit and removed afterwards."""
    from selenium import webdriver
    profile_dir = tempfile.mkdtemp(prefix='enbarr-chromium-')
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (*FLAGS, f'--user-data-dir={profile_dir}'):
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options,
                              service=webdriver.ChromeService(executable_path=CHROMEDRIVER))
    try:
        yield driver
    finally:
        try:
            driver.quit()
        finally:
            shutil.rmtree(profile_dir, ignore_errors=True)


class Composed:
    """A profile composed on a thread, and a probe (``sink(topic_spec, callback)``)."""

    def __init__(self, profile: str, overrides: Sequence[str], record: str | None = None) -> None:
        """Compose ``profile`` with ``overrides``; ``record``: a bag path, as ``--record``."""
        from dataclasses import replace

        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        from enbarr_core.bringup.compose import add_recorder, composed
        from enbarr_core.bringup.profile import load_profile, RecordSpec

        loaded = load_profile(profile, list(overrides))
        if record is not None:
            loaded = add_recorder(replace(loaded, record=RecordSpec(path=record)))
        self._composed = composed(loaded)
        self.c = self._composed.__enter__()
        try:
            self.c.start()
            self._stop = threading.Event()
            self._thread = threading.Thread(target=self._spin, name='composed', daemon=True)
            self._thread.start()
            self.ctx = Context()
            rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
            self.probe = Node('browser_test_probe', context=self.ctx)
            self.ex = SingleThreadedExecutor(context=self.ctx)
            self.ex.add_node(self.probe)
        except BaseException:
            self._composed.__exit__(None, None, None)
            raise

    def node(self, name: str) -> Any:
        """Return the composed node called ``name``."""
        return self.c.node(name)

    def sink(self, spec: Any, callback: Callable[[Any], None]) -> None:
        """Subscribe the probe to a contract topic over DDS."""
        self.probe.create_subscription(spec.msg_type, spec.name, callback, spec.qos)

    def _spin(self) -> None:
        while not self._stop.is_set() and self.c.context.ok():
            self.c.executor.spin_once(timeout_sec=0.05)

    def spin_until(self, condition: Callable[[], bool], timeout: float = 20.0) -> bool:
        """Spin the probe until ``condition`` holds (bounded); whether it held."""
        return spin_until(self.ex, condition, timeout)

    def close(self) -> None:
        """Stop the profile's thread, take its nodes down, then the probe."""
        import rclpy
        self._stop.set()
        self._thread.join(5.0)
        self._composed.__exit__(None, None, None)
        self.ex.shutdown()
        self.probe.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
