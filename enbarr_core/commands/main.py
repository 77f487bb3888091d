"""The ``enbarr`` command line (and ``ros2 run enbarr bringup``, the same ``bringup``).

The subcommands are ``enbarr_core.commands.Command``s found by name (the built-in table and
the ``enbarr.commands`` entry points, ``enbarr_core.commands``); this module builds the parser
from them, runs the one asked for, and turns a user's mistake into one line
``enbarr COMMAND: error: ...`` and exit code 2. It sits on top of everything: nothing in the
package imports it.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Sequence

from enbarr_core.commands import entries, load
from enbarr_core.commands.arguments import NOTICES, wrap
from enbarr_core.commands.bringup import EPILOG
from enbarr_core.framework.errors import EnbarrError


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
