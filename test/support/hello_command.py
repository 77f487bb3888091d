"""A third-party ``enbarr`` command, as another package would declare it (an entry point)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from enbarr_core.commands import Command
from enbarr_core.framework.errors import EnbarrError


class HelloCommand(Command):
    """``enbarr hello --name N``: greets, or refuses an empty name."""

    help = 'say hello (a third-party command)'

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument('--name', default='world')

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        if not args.name:
            raise EnbarrError('--name must not be empty')
        print(f'hello {args.name} ({" ".join(argv)})')
        return 0


class NotACommand:
    """An entry point that names something else."""
