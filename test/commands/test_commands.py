"""The ``enbarr`` subcommands: one pattern (``enbarr_core.commands.Command``), found by name in
the built-in table and the ``enbarr.commands`` entry points, and no import cycle through the
command line (pure: the parser is built and run in this process).
"""

from __future__ import annotations

import argparse
import ast
from importlib import metadata
from pathlib import Path

import pytest

from enbarr_core import commands
from enbarr_core.commands import main as cli
from enbarr_core.commands.arguments import check_seconds, DeprecatedAlias, NOTICES, wrap
from enbarr_core.framework.errors import EnbarrError

ROOT = Path(__file__).resolve().parents[2]


def test_every_builtin_command_is_a_command() -> None:
    known, warnings = commands.entries()
    assert not warnings
    assert list(known)[:len(commands.BUILTIN)] == list(commands.BUILTIN)
    for entry in known.values():
        command = commands.load(entry)
        assert isinstance(command, commands.Command) and command.help


def test_no_module_imports_the_command_line_back() -> None:
    # The command line sits on top of the package: a tool importing it back closes a cycle.
    importers = []
    for path in sorted((ROOT / 'enbarr_core').rglob('*.py')) + sorted(
            (ROOT / 'enbarr_plugins').rglob('*.py')):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f'{node.module}.{a.name}' for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            if 'enbarr_core.commands.main' in names:
                importers.append(str(path.relative_to(ROOT)))
    assert importers == []


def fake_entry_points(*eps: metadata.EntryPoint):
    def entry_points(group: str) -> tuple[metadata.EntryPoint, ...]:
        return tuple(ep for ep in eps if ep.group == group)
    return entry_points


HELLO = metadata.EntryPoint('hello', 'support.hello_command:HelloCommand', 'enbarr.commands')


def test_a_third_party_command_runs_by_its_entry_point(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(commands.metadata, 'entry_points', fake_entry_points(HELLO))
    assert cli.main(['hello', '--name', 'saucer']) == 0
    assert capsys.readouterr().out == 'hello saucer (--name saucer)\n'
    assert cli.main(['hello', '--name', '']) == 2
    assert capsys.readouterr().err == 'enbarr hello: error: --name must not be empty\n'


def test_a_third_party_command_cannot_take_a_builtin_name(
        monkeypatch: pytest.MonkeyPatch) -> None:
    taken = metadata.EntryPoint('bringup', 'support.hello_command:HelloCommand',
                                'enbarr.commands')
    monkeypatch.setattr(commands.metadata, 'entry_points', fake_entry_points(taken))
    known, warnings = commands.entries()
    assert known['bringup'].target == commands.BUILTIN['bringup']
    assert warnings == ["command 'bringup' of unknown distribution "
                        '(support.hello_command:HelloCommand) left out: the name is taken by '
                        'enbarr_core.commands.bringup:BringupCommand (builtin)']


@pytest.mark.parametrize('target, says', [
    ('support.hello_command:NotACommand', 'is not an enbarr_core.commands.Command'),
    ('support.no_such_module:X', "No module named 'support.no_such_module'"),
])
def test_a_broken_third_party_command_is_left_out_with_a_warning(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], target: str,
        says: str) -> None:
    broken = metadata.EntryPoint('broken', target, 'enbarr.commands')
    monkeypatch.setattr(commands.metadata, 'entry_points', fake_entry_points(broken))
    with pytest.raises(SystemExit):
        cli.main(['list', '--help'])   # the rest of the command line still works
    out = capsys.readouterr()
    assert 'usage: enbarr list' in out.out
    assert out.err.startswith("enbarr: warning: command 'broken' of unknown distribution "
                              f'({target}) left out: ')
    assert says in out.err


# -- the shared argument helpers ----------------------------------------------------------------
@pytest.mark.parametrize('value, says', [
    (0.0, 'must be a positive finite number of seconds, got 0.0'),
    (float('nan'), 'must be a positive finite number of seconds, got nan'),
    (float('inf'), 'must be a positive finite number of seconds, got inf'),
    (1e308, 'must be at most 31536000 s, got 1e+308'),
])
def test_check_seconds_refuses(value: float, says: str) -> None:
    with pytest.raises(EnbarrError) as info:
        check_seconds('--x', value)
    assert str(info.value) == f'--x {says}'


def test_check_seconds_takes_a_year_and_none() -> None:
    check_seconds('--x', 365 * 86400.0)
    check_seconds('--x', None)


def test_a_deprecated_alias_stores_and_notes() -> None:
    p = argparse.ArgumentParser()
    p.add_argument('--output')
    p.add_argument('--out', dest='output', action=DeprecatedAlias, replacement='--output')
    p.add_argument('old', nargs='?', metavar='PROFILE', action=DeprecatedAlias,
                   replacement='--profile {}')
    assert '--out ' not in p.format_help() and 'PROFILE' not in p.format_help()
    args = p.parse_args(['--out', 'd', 'x'])
    assert args.output == 'd' and args.old == 'x'
    assert getattr(args, NOTICES) == ['--out is deprecated; use --output',
                                      'PROFILE as a positional argument is deprecated; use '
                                      '--profile x']
    assert getattr(p.parse_args(['--output', 'd']), NOTICES, None) is None


def test_wrap_fills_prose_and_keeps_tables() -> None:
    text = 'a ' * 60 + '\n\n  name  a row that stays as it is\n  other  row'
    out = wrap(text, width=40).split('\n\n')
    assert all(len(line) <= 40 for line in out[0].splitlines())
    assert out[1] == '  name  a row that stays as it is\n  other  row'
