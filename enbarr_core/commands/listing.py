"""``enbarr list [WHAT]``: the profiles, fragments, scenarios, nodes and commands known here."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence

from enbarr_core.commands import Command

WHATS = ('profiles', 'scenarios', 'nodes', 'commands')


class ListCommand(Command):
    """``enbarr list``: what a profile, ``scenario`` or ``bringup`` can name."""

    help = 'list the profiles, scenarios, nodes and commands known here'
    description = ('List what can be named: every section without WHAT, or one of them.\n\n'
                   '  profiles   vessel profiles to run (enbarr bringup --profile NAME), then '
                   'the\n             fragments: include-only pieces (include: [NAME]), '
                   'never run alone\n'
                   '  scenarios  headless simulated runs (enbarr scenario NAME)\n'
                   '  nodes      the plugins a profile node can be (plugin: NAME), and where '
                   'each\n             comes from (builtin, or the package of its entry point)\n'
                   '  commands   the enbarr subcommands, third-party ones included\n\n'
                   'Profiles and scenarios are looked up where bare names are: the installed\n'
                   'share/enbarr/params, then the source tree.')

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare the optional ``WHAT``."""
        parser.add_argument('what', nargs='?', choices=WHATS, metavar='WHAT',
                            help=f'one of: {", ".join(WHATS)} (default: all, in sections)')

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Print the sections asked for."""
        sections: dict[str, Callable[[], list[str]]] = {
            'profiles': _profiles, 'scenarios': _scenarios, 'nodes': _nodes,
            'commands': _commands}
        if args.what is not None:
            print('\n'.join(sections[args.what]()))
            return 0
        blocks = ['\n'.join(fn()) for fn in sections.values()]
        print('\n\n'.join(blocks))
        return 0


def _table(heading: str, rows: Sequence[tuple[str, str]]) -> list[str]:
    """``heading``, then one line per row: the names in a column as wide as the longest."""
    width = max((len(name) for name, _ in rows), default=0) + 2
    return [heading] + [f'  {name:{width}s}{text}'.rstrip() for name, text in rows]


def _profiles() -> list[str]:
    from enbarr_core.bringup.profile import installed_profiles
    found = installed_profiles()
    runnable = [p for p in found if not p.fragment]
    fragments = [p for p in found if p.fragment]
    return (_table('Profiles (enbarr bringup --profile NAME):',
                   [(p.name, p.description) for p in runnable]) + ['']
            + _table('Fragments (include-only: include: [NAME] in a profile):',
                     [(p.name, p.description) for p in fragments]))


def _scenarios() -> list[str]:
    from enbarr_core.bringup.profile import installed_profiles
    return _table('Scenarios (enbarr scenario NAME):',
                  [(p.name, p.description) for p in installed_profiles('scenarios')])


def _nodes() -> list[str]:
    from enbarr_core.framework import registry
    return _table('Nodes (plugin: NAME in a profile):',
                  [(name, f'{entry.target}  ({entry.origin})')
                   for name, entry in sorted(registry.entries().items())])


def _commands() -> list[str]:
    from enbarr_core.commands import entries, load
    known, _ = entries()
    rows = []
    for name, entry in known.items():
        try:
            text = load(entry).help
        except Exception as err:  # noqa: BLE001 - listed as broken, not hidden
            text = f'cannot be loaded: {type(err).__name__}: {err}'
        rows.append((name, f'{text}  ({entry.origin})'))
    return _table('Commands (enbarr COMMAND --help):', rows)
