"""The ``enbarr`` command line (and ``ros2 run enbarr bringup``, the same ``bringup``).

The subcommands are ``enbarr_core.commands.Command``s found by name (the built-in table and
the ``enbarr.commands`` entry points, ``enbarr_core.commands``); this module builds the parser
from them, runs the one asked for, and turns a user's mistake into one line
``enbarr COMMAND: error: ...`` and exit code 2. The ``bringup`` command itself is here.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Sequence

from enbarr_core.commands import Command, entries, load
from enbarr_core.commands.arguments import check_seconds, DeprecatedAlias, NOTICES, wrap
from enbarr_core.framework.errors import EnbarrError

EPILOG = (
    'Profiles: a bare name (enbarr_sim) is looked up among the installed profiles '
    '(share/enbarr/params; enbarr list shows them); anything else is a path. Set '
    'ROS_AUTOMATIC_DISCOVERY_RANGE and ROS_DOMAIN_ID as usual; simulated profiles set '
    'LOCALHOST themselves.')


class BringupCommand(Command):
    """``enbarr bringup``: build and run the nodes of a vessel profile."""

    help = 'run a vessel profile'
    description = 'Build and run the nodes of a vessel profile.'
    epilog = EPILOG

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare ``--profile``, ``--duration``, ``--output``, ``--set``, ``--check``."""
        parser.add_argument('--profile', required=True, metavar='NAME|PATH',
                            help='vessel profile (YAML) to run, e.g. enbarr_sim')
        parser.add_argument('--duration', type=float, metavar='S',
                            help='stop after S seconds (default: run until SIGINT/SIGTERM)')
        parser.add_argument('-o', '--output', metavar='DIR',
                            help='record the run: a rosbag2 (MCAP) into DIR, which must not '
                            'exist yet')
        parser.add_argument('--record', dest='output', action=DeprecatedAlias,
                            replacement='--output', metavar='DIR')
        parser.add_argument('--record-topic', action='append', default=[], metavar='TOPIC',
                            help='with --output: record only this topic (repeatable; '
                            'default: all)')
        parser.add_argument('--record-split-size', type=float, metavar='MB',
                            help='with --output: start a new file of the bag past MB '
                            'megabytes (as ros2 bag record --max-bag-size; default: one file '
                            'per run)')
        parser.add_argument('--record-split-seconds', type=float, metavar='S',
                            help='with --output: start a new file of the bag past S seconds '
                            'of messages (as --max-bag-duration; default: one file per run)')
        parser.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                            help='override a node parameter; VALUE is YAML (repeatable)')
        parser.add_argument('--check', action='store_true',
                            help='validate the profile and build every node, then exit')
        parser.add_argument('--group', help=argparse.SUPPRESS)  # a supervised child process

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Run the profile (or one group of it, or only check it)."""
        from enbarr_core.bringup import compose, profile as profiles, run, supervisor

        check_seconds('--duration', args.duration)
        prof = profiles.load_profile(args.profile, args.set)
        profiles.apply_environment(prof)
        if args.output:
            prof = profiles.with_record(prof, args.output, args.record_topic,
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


def build_parser() -> argparse.ArgumentParser:
    """Build the ``enbarr`` argument parser with a subparser for every known command."""
    parser = argparse.ArgumentParser(
        prog='enbarr', description='Enbarr: control stack for low-cost marine vehicles.',
        epilog=wrap(EPILOG + '\n\nenbarr list shows the profiles, scenarios, nodes and '
                    'commands; enbarr COMMAND --help says more about one.'),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    known, warnings = entries()
    for name, entry in known.items():
        try:
            command = load(entry)
        except Exception as err:  # noqa: BLE001 - a third party's broken command is left out
            if entry.origin == 'builtin':
                raise
            warnings.append(f'command {name!r} of {entry.origin} ({entry.target}) left out: '
                            f'{type(err).__name__}: {err}')
            continue
        p = sub.add_parser(name, help=command.help,
                           description=wrap(command.description or command.help),
                           epilog=wrap(command.epilog) if command.epilog else None,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        command.add_arguments(p)
        p.set_defaults(command_object=command)
    for warning in warnings:
        print(f'enbarr: warning: {warning}', file=sys.stderr)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``enbarr ARGV``; a user's error is one line on stderr and exit code 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.INFO, format='[%(levelname)s] [%(name)s]: %(message)s')
    args = build_parser().parse_args(argv)
    sub_argv = argv[argv.index(args.command) + 1:] if args.command in argv else []
    # A supervised group re-runs its parent's command line: the parent said it once.
    if getattr(args, 'group', None) is None:
        for notice in getattr(args, NOTICES, None) or ():
            print(f'enbarr {args.command}: warning: {notice}', file=sys.stderr)
    try:
        return args.command_object.main(args=args, argv=sub_argv)
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
