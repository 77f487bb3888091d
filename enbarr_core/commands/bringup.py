"""``enbarr bringup`` (and ``ros2 run enbarr bringup``): build and run a vessel profile.

What it runs lives in ``enbarr_core.bringup``: the profile (``profile``), the nodes of one
process (``compose``, ``validate`` for ``--check``), a run (``run``) and the supervisor of a
profile split into process groups (``supervisor``).
"""

from __future__ import annotations

import argparse
from typing import Sequence

from enbarr_core.commands import Command
from enbarr_core.commands.arguments import check_seconds, DeprecatedAlias
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
        """Declare ``--profile``, ``--duration``, ``--output``, ``--set``, ``--check``, ..."""
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
        which = parser.add_mutually_exclusive_group()
        which.add_argument('--only-group', action='append', default=[], metavar='GROUP',
                           help='run only the nodes of this process group of the profile '
                           '(repeatable), e.g. operator on the operator computer')
        which.add_argument('--skip-group', action='append', default=[], metavar='GROUP',
                           help='run every process group of the profile but this one '
                           '(repeatable), e.g. operator on the vessel')
        parser.add_argument('--group', help=argparse.SUPPRESS)  # a supervised child process

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Run the profile (or one group of it, or only check it)."""
        from enbarr_core.bringup import compose, profile as profiles, run, supervisor

        check_seconds('--duration', args.duration)
        prof = profiles.load_profile(args.profile, args.set)
        if args.only_group or args.skip_group:
            prof = profiles.select_groups(prof, args.only_group, args.skip_group)
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
