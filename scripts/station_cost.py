"""What the surface station costs its process: CPU with and without a page, telemetry().

Composes saucer_station_sim in this process (the station on a free port), measures the
process's CPU (getrusage) over ``--seconds`` without a page, then as long with Debian's
headless chromium on the page (the browser is its own process, not counted), and times the
station's telemetry snapshot. From the clone: .venv/bin/python scripts/station_cost.py
(figures: docs/benchmarks.md, "The surface station").
"""

from __future__ import annotations

import argparse
import resource
import shutil
import statistics
import tempfile
import threading
import time

from enbarr_core.bringup.compose import composed
from enbarr_core.bringup.profile import load_profile

FLAGS = ('--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
         '--disable-background-networking', '--disable-component-update', '--disable-sync')


def cpu() -> float:
    """Return this process's CPU time [s]."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def share(seconds: float) -> float:
    """Return this process's CPU over the next ``seconds`` as a share of one core."""
    c0, w0 = cpu(), time.monotonic()
    time.sleep(seconds)
    return (cpu() - c0) / (time.monotonic() - w0)


def main() -> None:
    """Measure and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=20.0, help='each window (default 20)')
    seconds = parser.parse_args().seconds
    from selenium import webdriver   # a test requirement: only this script needs it

    with composed(load_profile('saucer_station_sim', ['station.port=0'])) as c:
        c.start()
        station = c.node('station')
        stop = threading.Event()

        def spin() -> None:
            while not stop.is_set():
                c.executor.spin_once(timeout_sec=0.05)

        spinner = threading.Thread(target=spin, daemon=True)
        spinner.start()
        time.sleep(5.0)   # settle
        idle = share(seconds)
        profile_dir = tempfile.mkdtemp(prefix='enbarr-chromium-')
        options = webdriver.ChromeOptions()
        options.binary_location = '/usr/bin/chromium'
        for flag in (*FLAGS, f'--user-data-dir={profile_dir}'):
            options.add_argument(flag)
        driver = webdriver.Chrome(options=options,
                                  service=webdriver.ChromeService('/usr/bin/chromedriver'))
        try:
            driver.get(station.server.url)
            time.sleep(5.0)
            sent = station.commands_sent
            busy = share(seconds)
            rate = (station.commands_sent - sent) / seconds
            ack = driver.execute_script(
                'return performance.now() - state.telemetry.drive.ack_t')
            times = []
            for _ in range(2000):
                t0 = time.perf_counter()
                station.telemetry()
                times.append(time.perf_counter() - t0)
        finally:
            driver.quit()
            shutil.rmtree(profile_dir, ignore_errors=True)
            stop.set()
            spinner.join()
    times.sort()
    print(f'process CPU without a page: {idle * 100:.1f} % of a core; with one page: '
          f'{busy * 100:.1f} %')
    print(f'inputs taken per second: {rate:.1f}; age of the last acknowledged input seen '
          f'by the page: {ack:.0f} ms')
    print(f'telemetry() median {statistics.median(times) * 1e6:.0f} us, '
          f'p99 {times[int(0.99 * len(times))] * 1e6:.0f} us')


if __name__ == '__main__':
    main()
