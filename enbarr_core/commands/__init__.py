"""The ``enbarr`` subcommands: one pattern, found by name.

Every subcommand is a ``Command``: ``add_arguments(parser)`` declares its options and
``main(args=..., argv=...)`` runs it and returns the exit code. The ones this package ships
are listed in ``BUILTIN`` (name -> ``'module:Class'``); a third-party package adds one
without touching this repository by declaring, in its own ``setup.py``::

    entry_points={'enbarr.commands': ['my_tool = my_package.my_tool:MyToolCommand']}

after which ``enbarr my_tool`` runs it (ros2cli's ``ros2cli.command`` extensions work the same
way; node plugins are found the same way in ``enbarr_core.framework.registry``). A command
raises ``EnbarrError`` for a user's mistake: the command line prints it as one line
``enbarr NAME: error: ...`` and exits 2.

The command line (``enbarr_core.commands.main``) loads the commands by name; no command imports
it back. Their shared argument checks live in ``enbarr_core.commands.arguments``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
import importlib
from importlib import metadata

ENTRY_POINT_GROUP = 'enbarr.commands'

#: name -> 'module:Class' of the commands this package ships, in the order ``--help`` lists.
BUILTIN: dict[str, str] = {
    'bringup': 'enbarr_core.commands.bringup:BringupCommand',
    'list': 'enbarr_core.commands.listing:ListCommand',
    'scenario': 'enbarr_core.commands.scenario:ScenarioCommand',
    'chaos': 'enbarr_core.commands.chaos:ChaosCommand',
    'bench': 'enbarr_core.commands.bench:BenchCommand',
    'check-device': 'enbarr_core.commands.check_device:CheckDeviceCommand',
    'bag': 'enbarr_core.commands.bag:BagCommand',
    'calibrate': 'enbarr_core.commands.calibrate:CalibrateCommand',
}


class Command:
    """One ``enbarr`` subcommand (subclass it; see the module docstring).

    ``help`` is its line in ``enbarr --help``; ``description`` (default: ``help``) and
    ``epilog`` head and end ``enbarr NAME --help``.
    """

    help: str = ''
    description: str = ''
    epilog: str = ''

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare the command's options on ``parser``."""

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Run the command with the parsed ``args`` (``argv``: its own words); exit code."""
        raise NotImplementedError


@dataclass(frozen=True)
class CommandEntry:
    """A command known by name, and where it comes from."""

    name: str
    target: str   # 'module:Class'
    origin: str   # 'builtin' or the distribution that declared the entry point


def entries() -> tuple[dict[str, CommandEntry], list[str]]:
    """Every command by name, built-ins first; and the warnings about entry points left out.

    An entry point that takes a built-in's name is left out with a warning rather than an
    error: a broken third-party package must not take the whole command line (and with it
    ``bringup``) down.
    """
    known = {name: CommandEntry(name, target, 'builtin') for name, target in BUILTIN.items()}
    warnings = []
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep.dist, 'name', None) or 'unknown distribution'
        if ep.name in known:
            if known[ep.name].target != ep.value:
                warnings.append(f'command {ep.name!r} of {dist} ({ep.value}) left out: the '
                                f'name is taken by {known[ep.name].target} '
                                f'({known[ep.name].origin})')
            continue
        known[ep.name] = CommandEntry(ep.name, ep.value, dist)
    return known, warnings


def load(entry: CommandEntry) -> Command:
    """Import and instantiate the command of ``entry``."""
    module_name, _, attr = entry.target.partition(':')
    obj = importlib.import_module(module_name)
    for part in attr.split('.'):
        obj = getattr(obj, part)
    command = obj()
    if not isinstance(command, Command):
        raise TypeError(f'{entry.target} is not an enbarr_core.commands.Command')
    return command
