"""``enbarr check-device arduino``: the Arduino PWM board's identity and one neutral command.

Kept apart from the driver (``arduino/link.py``) and the emulator (``arduino/emulator.py``):
it uses both (``--port emulated`` runs the emulator in this process) and neither needs it.
"""

from __future__ import annotations

from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.arduino.emulator import ArduinoEmulator
from enbarr_plugins.arduino.link import BoardSession, LinkSettings
from enbarr_plugins.arduino.protocol import CHANNELS, DEFAULT_NEUTRAL, UNITS_PER_PERCENT
from enbarr_plugins.check import CheckTarget, device_endpoint
from enbarr_plugins.transport.serial_link import open_serial, SerialLink


def check_device(target: CheckTarget) -> list[str]:
    """Open the board, read its HELLO, send one neutral SET_DUTY, read the STATUS.

    ``target.port`` (default ``/dev/ttyACM0``) or ``emulated``: then this package's emulator
    runs in the process. A board that resets on open needs ``--timeout`` of a few seconds.
    """
    port = target.port or '/dev/ttyACM0'
    timeout = target.timeout
    settings = LinkSettings(boot_wait=min(2.5, 0.5 * timeout), hello_timeout=timeout,
                            reply_timeout=max(0.5, 0.25 * timeout))
    with device_endpoint(port, port, ArduinoEmulator) as path:
        session = None
        try:
            link = SerialLink(open_serial(path, 115200, timeout=0.05, write_timeout=0.1), port)
            session = BoardSession(link, settings, port)
            session.start()
            session.wait(session.ready.is_set, timeout + settings.reply_timeout)
            if session.fault is not None:
                raise session.fault
            if not session.ready.is_set():
                raise DeviceError(f'{port}: no HELLO from the board within {timeout:g} s')
            hello = session.hello
            assert hello is not None
            session.set_command(settings.neutral)
            if not session.wait(lambda: session.confirmed, settings.reply_timeout * 2):
                raise session.fault or DeviceError(
                    f'{port}: the board did not acknowledge a neutral SET_DUTY')
            status = session.last_status
            assert status is not None
            return [
                f'{port}: Enbarr PWM board, {hello.describe()}',
                f'{port}: neutral SET_DUTY ({DEFAULT_NEUTRAL / UNITS_PER_PERCENT:.2f} % on '
                f'{CHANNELS} channels) '
                f'acknowledged (seq {status.acked}); outputs '
                f'{"neutral" if status.neutral else "NOT neutral"}; board counters: watchdog '
                f'trips {status.watchdog_trips}, CRC errors {status.crc_errors}, sequence errors '
                f'{status.seq_errors}, refused {status.refused}, truncated {status.truncated}']
        finally:
            if session is not None:
                session.stop()
