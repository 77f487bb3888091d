"""``enbarr bag repair PATH``: give a bag whose recorder was killed a valid index again."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from enbarr_core.commands import Command


class BagCommand(Command):
    """``enbarr bag repair PATH``."""

    help = 'repair a bag whose recorder was killed'
    description = ('repair PATH: give every file of a bag recorded by Enbarr a valid index and '
                   'footer, as of its last complete flush (a kill can tear the file end being '
                   'rewritten), and rewrite its metadata.yaml from what the files hold. Intact '
                   'files are left as they are.')

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare ``ACTION`` (repair) and ``PATH``."""
        parser.add_argument('action', choices=('repair',))
        parser.add_argument('path', metavar='PATH', help='the bag directory')

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Repair the bag; print one line per file."""
        from enbarr_core.recording.bag import repair_bag

        for r in repair_bag(args.path):
            state = (f'repaired, {r.dropped_bytes} torn bytes cut' if r.repaired
                     else 'intact, its index written' if r.indexed else 'intact')
            print(f'{r.name}: {r.messages} messages, {state}')
        return 0
