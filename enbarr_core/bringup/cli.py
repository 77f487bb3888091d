"""The ``enbarr`` command line (and ``ros2 run enbarr bringup``, the same ``bringup``)."""

from __future__ import annotations

import argparse
import logging
import math
import sys
from typing import Sequence

from enbarr_core.framework.errors import EnbarrError

EPILOG = """\
Profiles: a bare name (enbarr_sim) is looked up among the installed profiles
(share/enbarr/params); anything else is a path. Set ROS_AUTOMATIC_DISCOVERY_RANGE and
ROS_DOMAIN_ID as usual; simulated profiles set LOCALHOST themselves.
"""


def _bringup_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--profile', required=True, metavar='NAME|PATH',
                        help='vessel profile (YAML) to run, e.g. enbarr_sim')
    parser.add_argument('--duration', type=float, metavar='S',
                        help='stop after S seconds (default: run until SIGINT/SIGTERM)')
    parser.add_argument('--record', metavar='DIR',
                        help='record a rosbag2 (MCAP) into DIR, which must not exist yet')
    parser.add_argument('--record-topic', action='append', default=[], metavar='TOPIC',
                        help='record only this topic (repeatable; default: all)')
    parser.add_argument('--record-split-size', type=float, metavar='MB',
                        help='start a new file of the bag past MB megabytes (as ros2 bag '
                        'record --max-bag-size; default: one file per run)')
    parser.add_argument('--record-split-seconds', type=float, metavar='S',
                        help='start a new file of the bag past S seconds of messages (as '
                        '--max-bag-duration; default: one file per run)')
    parser.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                        help='override a node parameter; VALUE is YAML (repeatable)')
    parser.add_argument('--check', action='store_true',
                        help='validate the profile and build every node, then exit')
    parser.add_argument('--group', help=argparse.SUPPRESS)  # a supervised child process


def check_seconds(option: str, value: float | None) -> None:
    """Refuse a time span that is not a positive, finite number of seconds."""
    if value is not None and not (value > 0 and math.isfinite(value)):
        raise EnbarrError(f'{option} must be a positive finite number of seconds, got {value}')


def _bringup(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from enbarr_core.bringup import compose, profile as profiles, run, supervisor

    check_seconds('--duration', args.duration)
    prof = profiles.load_profile(args.profile, args.set)
    profiles.apply_environment(prof)
    if args.record:
        prof = profiles.with_record(prof, args.record, args.record_topic,
                                    args.record_split_size, args.record_split_seconds)
    prof = compose.add_recorder(prof)
    if args.group is not None:
        if args.group not in prof.groups:
            raise EnbarrError(f'no group {args.group!r}; groups: {", ".join(prof.groups)}')
        return run.run_group(prof, args.group)
    if args.check:
        checked = compose.validate(prof)
        print(f'{prof.path}: ok ({checked.nodes} nodes in {checked.groups} group(s))')
        if checked.devices:
            print('not checked: the devices, which a check never opens: '
                  + ', '.join(f'{name} ({device})' for name, device in checked.devices)
                  + '; talk to one with `enbarr check-device KIND`')
        return 0
    if len(prof.groups) > 1:
        return supervisor.supervise(prof, supervisor.child_command(argv), args.duration)
    return run.run_group(prof, None, args.duration)


def _bench(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from enbarr_core.tools import bench
    return bench.main(args)


def _scenario(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from enbarr_core.tools import scenario
    return scenario.main(args)


def _list(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from enbarr_core.bringup import profile as profiles
    from enbarr_core.framework import registry
    if args.what == 'nodes':
        for name, entry in sorted(registry.entries().items()):
            print(f'{name:20s} {entry.target}  ({entry.origin})')
    else:
        for d in profiles.search_dirs():
            for f in sorted(d.glob('*.yaml')):
                print(f'{f.stem:20s} {f}')
    return 0


def _check_device(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from enbarr_plugins.check import CheckTarget, checker
    check_seconds('--timeout', args.timeout)
    target = CheckTarget(port=args.port, bus=args.bus, address=args.address, host=args.host,
                         device=args.device, name=args.name, timeout=args.timeout)
    for line in checker(args.kind)(target):
        print(line)
    return 0


def _address(text: str) -> int:
    """Parse an I2C address as typed: 0x6b, 107."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an address: {text!r} (e.g. 0x6b)') from None


def _bag(args: argparse.Namespace, argv: Sequence[str]) -> int:
    from enbarr_core.recording.bag import repair_bag

    for r in repair_bag(args.path):
        state = (f'repaired, {r.dropped_bytes} torn bytes cut' if r.repaired
                 else 'intact, its index written' if r.indexed else 'intact')
        print(f'{r.name}: {r.messages} messages, {state}')
    return 0


def build_parser() -> argparse.ArgumentParser:
    """Build the ``enbarr`` argument parser and its subcommands."""
    parser = argparse.ArgumentParser(
        prog='enbarr', description='Enbarr: control stack for low-cost marine vehicles.',
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    p = sub.add_parser('bringup', help='run a vessel profile',
                       description='Build and run the nodes of a vessel profile.',
                       epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    _bringup_parser(p)
    p.set_defaults(func=_bringup)
    from enbarr_core.tools.bench_profile import HELP as BENCH_PROFILE_HELP
    p = sub.add_parser('bench', help='measure a control chain or a whole profile (prints JSON)',
                       description='--chain (default rov): drive the sensor -> filter -> '
                       'control -> allocation -> actuator chain in one process at a given '
                       'rate and print one JSON line of figures.',
                       epilog=BENCH_PROFILE_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    from enbarr_core.tools.bench import add_arguments
    add_arguments(p)
    p.set_defaults(func=_bench)
    from enbarr_core.tools.scenario import add_arguments as scenario_arguments
    from enbarr_core.tools.scenario import known_scenarios
    p = sub.add_parser('scenario', help='run a simulated scenario headless (prints JSON)',
                       description='Run a named simulated scenario faster than real time, '
                       'record it, print its metrics as one JSON line and write a PNG plot. '
                       f'Scenarios (params/scenarios/): {", ".join(known_scenarios())}.')
    scenario_arguments(p)
    p.set_defaults(func=_scenario)
    __import__('enbarr_core.tools.chaos', fromlist=['register']).register(sub)
    from enbarr_plugins.check import CHECKS
    p = sub.add_parser('check-device', help='talk to one device and print what it found',
                       description="Open one device with its driver's code, read its "
                       'identity and a sample (or send a neutral command), print what was '
                       'found and exit 0; exit 2 with the reason when it is absent, silent or '
                       'not what it should be. "emulated" as the port, bus, host or device '
                       "checks against this package's emulator. docs/hardware.md has a "
                       'section per kind.')
    p.add_argument('kind', choices=sorted(CHECKS), metavar='KIND',
                   help=f'one of: {", ".join(sorted(CHECKS))}')
    p.add_argument('--port', help='serial port (/dev/ttyUSB0) or emulated')
    p.add_argument('--bus', help='I2C bus number (1 for /dev/i2c-1) or emulated')
    p.add_argument('--address', type=_address, help="I2C address (default: the chip's)")
    p.add_argument('--host', help='network host, HOST or HOST:PORT, or emulated')
    p.add_argument('--device', help='V4L2 index, video file, /dev/input/eventN or emulated')
    p.add_argument('--name', help='rigid body (motion capture) or pin (GPIO)')
    p.add_argument('--timeout', type=float, default=2.0, metavar='S',
                   help='longest wait for an answer (default 2 s)')
    p.set_defaults(func=_check_device)
    p = sub.add_parser('bag', help='repair a bag whose recorder was killed',
                       description='repair PATH: give every file of a bag recorded by Enbarr '
                       'a valid index and footer, as of its last complete flush (a kill can '
                       'tear the file end being rewritten), and rewrite its metadata.yaml '
                       'from what the files hold. Intact files are left as they are.')
    p.add_argument('action', choices=('repair',))
    p.add_argument('path', metavar='PATH', help='the bag directory')
    p.set_defaults(func=_bag)
    p = sub.add_parser('list', help='list known nodes or installed profiles')
    p.add_argument('what', choices=('nodes', 'profiles'))
    p.set_defaults(func=_list)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``enbarr ARGV``; a user's error is one line on stderr and exit code 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.INFO, format='[%(levelname)s] [%(name)s]: %(message)s')
    args = build_parser().parse_args(argv)
    sub_argv = argv[argv.index(args.command) + 1:] if args.command in argv else []
    try:
        return args.func(args, sub_argv)
    except EnbarrError as err:
        _error(args.command, str(err))
    except OSError as err:  # the environment refused (a path, a device): not a bug of ours
        where = f'{err.filename}: ' if err.filename else ''
        _error(args.command, f'{where}{err.strerror or err}')
    except RecursionError:  # a last resort: profiles are depth-checked before this
        _error(args.command, 'input nested too deeply')
    except KeyboardInterrupt:  # a stop before the run's own handlers were in place
        return 130
    return 2


#: The longest error line printed [characters]: messages quote values from untrusted files.
MAX_ERROR = 4000


def _error(command: str, message: str) -> None:
    """Print ``message`` as the one error line of ``command`` (bounded, no line breaks)."""
    line = ' '.join(message.split('\n'))
    if len(line) > MAX_ERROR:
        line = f'{line[:MAX_ERROR]}... ({len(line) - MAX_ERROR} more characters)'
    print(f'enbarr {command}: error: {line}', file=sys.stderr)


def bringup_main() -> int:
    """``ros2 run enbarr bringup ...``: the ``bringup`` subcommand."""
    return main(['bringup', *sys.argv[1:]])


if __name__ == '__main__':
    sys.exit(main())
