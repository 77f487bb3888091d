"""``enbarr chaos --profile P``: a profile run while faults are injected (``tools.chaos``)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import json
from pathlib import Path
import shutil
import tempfile

from enbarr_core.commands import Command
from enbarr_core.commands.arguments import check_seconds, DeprecatedAlias
from enbarr_core.framework.errors import EnbarrError

#: The longest observation window after a fault [s].
MAX_WINDOW_S = 600.0
#: The kinds ``--faults`` takes (``enbarr_core.tools.chaos.run.KINDS``, named here so that
#: ``--help`` does not import the run).
KINDS = ('stamps', 'compete', 'params', 'sigstop', 'sigkill', 'disk', 'supervisor')


class ChaosCommand(Command):
    """``enbarr chaos --profile P``."""

    help = 'run a profile while injecting faults (prints JSON)'
    description = ('Run a profile split into process groups under bringup, inject faults in '
                   'turn (bad stamps, competing publishers, a parameter storm, stopped and '
                   'killed groups, a full disk, a killed supervisor), judge each and print '
                   'one JSON line; exit 1 when a fault was unsafe.')

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare ``--profile``, ``--duration``, ``--faults``, ``--output``, ``--json``."""
        parser.add_argument('--profile', metavar='NAME|PATH',
                            help='vessel profile to run, e.g. enbarr_sim (required)')
        parser.add_argument('old_profile', nargs='?', metavar='PROFILE',
                            action=DeprecatedAlias, replacement='--profile {}')
        parser.add_argument('--duration', type=float, default=2.0, metavar='S',
                            help='observation window after each fault (default 2 s; a removal '
                            'fault with no neutral output yet is watched up to 5 s)')
        parser.add_argument('--faults', default='', metavar='a,b,...',
                            help=f'fault kinds or names to inject (default all: '
                            f'{",".join(KINDS)}; a name such as future+20s:imu/data_raw)')
        parser.add_argument('-o', '--output', metavar='DIR',
                            help='keep profile, bags and logs in DIR (must not exist; '
                            'default: a temporary directory, removed)')
        parser.add_argument('--out', dest='output', action=DeprecatedAlias,
                            replacement='--output', metavar='DIR')
        parser.add_argument('--json', action='store_true', help='print only the JSON line')

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Run the chaos profile, print the JSON line; 1 when anything was unsafe."""
        from enbarr_core.tools.chaos import judge
        from enbarr_core.tools.chaos.run import Chaos, unknown_faults

        profile = _profile(args)
        check_seconds('--duration', args.duration, MAX_WINDOW_S)
        selected = [f.strip() for f in args.faults.split(',') if f.strip()]
        unknown = unknown_faults(selected)
        if unknown:
            raise EnbarrError(f'--faults: unknown {", ".join(unknown)}; kinds: '
                              f'{", ".join(KINDS)} (or a fault name such as '
                              'future+20s:imu/data_raw)')
        if args.output:
            out = Path(args.output)
            if out.exists():
                raise EnbarrError(f'--output {out}: exists; chaos never overwrites a run')
            out.mkdir(parents=True)
        else:
            out = Path(tempfile.mkdtemp(prefix='enbarr_chaos_'))
        try:
            result = Chaos(profile, out, args.duration, selected, quiet=args.json).run()
        finally:
            if not args.output:
                shutil.rmtree(out, ignore_errors=True)
        print(json.dumps(result), flush=True)
        return 0 if judge.run_passed(result) else 1


def _profile(args: argparse.Namespace) -> str:
    """Return the profile of ``--profile`` or of the old positional spelling."""
    if args.old_profile is not None:
        if args.profile is not None:
            raise EnbarrError(f'two profiles: --profile {args.profile} and {args.old_profile}')
        return str(args.old_profile)
    if args.profile is None:
        raise EnbarrError('--profile is required (e.g. --profile enbarr_sim)')
    return str(args.profile)
