"""``enbarr check-device KIND``: talk to one device with its driver's code, print what it is."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from enbarr_core.commands import Command
from enbarr_core.commands.arguments import check_seconds

#: The longest wait for a device's answer [s] that a check takes.
MAX_TIMEOUT_S = 3600.0


def _address(text: str) -> int:
    """Parse an I2C address as typed: 0x6b, 107."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an address: {text!r} (e.g. 0x6b)') from None


class CheckDeviceCommand(Command):
    """``enbarr check-device KIND`` (the device kinds: ``enbarr_plugins.check.CHECKS``)."""

    help = 'talk to one device and print what it found'
    description = ("Open one device with its driver's code, read its identity and a sample (or "
                   'send a neutral command), print what was found and exit 0; exit 2 with the '
                   'reason when it is absent, silent or not what it should be. "emulated" as '
                   "the port, bus, host or device checks against this package's emulator. "
                   'docs/hardware.md has a section per kind.')

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare ``KIND`` and where the device is."""
        from enbarr_plugins.check import CHECKS
        parser.add_argument('kind', choices=sorted(CHECKS), metavar='KIND',
                            help=f'one of: {", ".join(sorted(CHECKS))}')
        parser.add_argument('--port', help='serial port (/dev/ttyUSB0) or emulated')
        parser.add_argument('--bus', help='I2C bus number (1 for /dev/i2c-1) or emulated')
        parser.add_argument('--address', type=_address,
                            help="I2C address (default: the chip's)")
        parser.add_argument('--host', help='network host, HOST or HOST:PORT, or emulated')
        parser.add_argument('--device',
                            help='V4L2 index, video file, /dev/input/eventN or emulated')
        parser.add_argument('--name', help='rigid body (motion capture) or pin (GPIO)')
        parser.add_argument('--timeout', type=float, default=2.0, metavar='S',
                            help='longest wait for an answer (default 2 s)')

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Check the device; print what it found."""
        from enbarr_plugins.check import checker, CheckTarget

        check_seconds('--timeout', args.timeout, MAX_TIMEOUT_S)
        target = CheckTarget(port=args.port, bus=args.bus, address=args.address,
                             host=args.host, device=args.device, name=args.name,
                             timeout=args.timeout)
        for line in checker(args.kind)(target):
            print(line)
        return 0
