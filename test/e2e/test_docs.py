"""The commands the documentation shows run as written (e2e: the command line, in processes).

Which commands: every line of a fenced ``sh`` block of README.md and docs/*.md (a ``#`` starts
a comment, a trailing backslash continues the line). Output shown to the reader belongs in a
plain fence. ``./dev enbarr ARGS``, ``./dev bench ARGS`` and ``./dev sim`` are read as the
``dev`` script expands them (its ``exec "$VENV/bin/enbarr" ...`` line of that case).

What each test proves, in this order:

1. Every ``enbarr`` command, hardware ones included, is parsed by the real ``enbarr`` parser
   (the console script's ``main``, stopped once ``ArgumentParser.parse_args`` returns): the
   subcommand and every option exist and their values parse. Nothing is run yet.
2. Then a bounded run, by subcommand (``RUNS``), in a temporary folder (a path the docs give
   from the clone's root is passed as that path); what each proves:
   - ``bringup``: the doc's arguments plus ``--check``: the profile exists, validates and
     every node is built with the doc's ``--set`` values. A vessel profile (its environment
     widens discovery beyond LOCALHOST: it looks for a topside on the network) is only
     loaded (it exists, merges and validates), never started here.
   - ``scenario``: the named scenario (it must exist in params/scenarios) run for two
     simulated seconds past its settle time, ``--no-plot``: it runs and prints its JSON
     with a verdict (exit 0 on pass, 1 on fail: a run cut short may miss its targets).
   - ``bench`` and ``chaos`` run for tens of seconds to minutes whatever their options: parsed
     only, and a ``--profile``/``PROFILE`` they name is loaded (it exists and validates).
   - ``list``, and ``check-device`` against an emulator: as written.
   - ``calibrate``: parsed only (it needs a camera or pictures of a board; its own tests run
     it on rendered ones).
   - ``param`` talks to a running node: parsed only (skipped; its own tests run it).
   - ``python -m MODULE``: with the options of ``MODULE_RUNS`` (``--help``: it imports and
     has its command line).
   - ``python scripts/NAME.py``: ``--help`` (it imports and has its command line; it needs
     a bag).
3. Skipped, each by its command line with the reason: what needs hardware or a toolchain
   (``make`` in firmware/, ``apt-get``, ``ls`` of the serial devices plugged in,
   ``check-device`` with a real port, bus, host or device: parsed in step 1 all the same) and
   ``./dev test`` (this suite).

A command no rule covers fails, naming itself: add a rule here, or fix the doc. Each run is
made once per session (a second doc line with the same run reuses its result).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
import json
import os
from pathlib import Path
import re
import shlex
import subprocess
import sys
from typing import Any

import pytest
import yaml

from enbarr_core.bringup.profile import load_profile

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]
SH_BLOCK = re.compile(r'^```sh\n(.*?)^```', re.M | re.S)
TIMEOUT = 120.0

#: ``python -m MODULE`` in the docs -> the smallest options that run it through.
#: ``python -m MODULE`` commands of the docs and what is appended to run them bounded.
MODULE_RUNS: dict[str, list[str]] = {
    'timeit': [],   # the attitude filter's step: the doc's -n bounds it (a second or so)
}


@dataclass(frozen=True)
class Command:
    """One command line of the docs, with every place that shows it."""

    argv: tuple[str, ...]
    where: tuple[str, ...]   # 'docs/x.md:12'

    @property
    def text(self) -> str:
        return shlex.join(self.argv)


def doc_commands() -> list[Command]:
    """Every command of the fenced sh blocks, once each (in order of first appearance)."""
    found: dict[tuple[str, ...], list[str]] = {}
    for doc in DOCS:
        text = doc.read_text(encoding='utf-8')
        for block in SH_BLOCK.finditer(text):
            first = text.count('\n', 0, block.start(1)) + 1
            lines = block.group(1).replace('\\\n', ' ').split('\n')
            for i, line in enumerate(lines):
                argv = tuple(shlex.split(line, comments=True))
                if argv:
                    found.setdefault(argv, []).append(f'{doc.relative_to(ROOT)}:{first + i}')
    return [Command(argv, tuple(where)) for argv, where in found.items()]


def dev_expansions() -> dict[str, list[str]]:
    """``./dev NAME`` -> the ``enbarr`` arguments its case runs (``$VARS`` as placeholders)."""
    text = (ROOT / 'dev').read_text(encoding='utf-8')
    out = {}
    for case in re.finditer(r'^  (\w+)\)\n(.*?)^    ;;', text, re.M | re.S):
        m = re.search(r'exec "\$VENV/bin/enbarr" (.*)', case.group(2))
        if m:
            args = shlex.split(m.group(1))
            out[case.group(1)] = ['RUN_DIR' if a.startswith('$') else a
                                  for a in args if a != '$@']
    return out


def enbarr_argv(argv: tuple[str, ...]) -> list[str] | None:
    """The ``enbarr`` arguments of a doc command, or None when it is not an enbarr command."""
    if argv[0] == 'enbarr':
        return list(argv[1:])
    if argv[0] == './dev' and len(argv) > 1:
        expansion = dev_expansions().get(argv[1])
        if expansion is not None:
            return [*expansion, *argv[2:]]
    return None


# -- 1. parsing ---------------------------------------------------------------------------------


class _Parsed(Exception):
    """Raised with the namespace once the real parser has parsed: the command stops there."""


def parse(args: list[str], monkeypatch: pytest.MonkeyPatch,
          capsys: pytest.CaptureFixture[str]) -> argparse.Namespace:
    """Parse ``enbarr ARGS`` with the real command line, without running it."""
    (script,) = entry_points(group='console_scripts', name='enbarr')
    main = script.load()
    original = argparse.ArgumentParser.parse_args

    def parse_args(self: argparse.ArgumentParser, *a: Any, **k: Any) -> argparse.Namespace:
        raise _Parsed(original(self, *a, **k))

    with monkeypatch.context() as patch:  # undone on leaving: the test's own patches stay
        patch.setattr(argparse.ArgumentParser, 'parse_args', parse_args)
        try:
            main(args)
        except _Parsed as parsed:
            return parsed.args[0]
        except SystemExit as stop:
            pytest.fail(f'enbarr {shlex.join(args)}: refused by its parser (exit {stop.code}): '
                        f'{capsys.readouterr().err.strip()}')
    pytest.fail('enbarr did not parse its arguments with ArgumentParser.parse_args')


# -- 2. bounded runs --------------------------------------------------------------------------

_done: dict[tuple[str, ...], subprocess.CompletedProcess[str]] = {}


def run(argv: list[str], cwd: Path, key: tuple[str, ...] | None = None,
        ok: tuple[int, ...] = (0,)) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` once per session, in ``cwd`` (a temporary folder: nothing it writes lands
    in the clone), with a terminal as its input, as a user would. The docs write commands
    from the clone's root: an argument that is a path there is given as that path. ``key``
    names the run when ``argv`` differs only in where it writes."""
    argv = [str(ROOT / a) if not a.startswith('-') and '/' in a and (ROOT / a).exists() else a
            for a in argv]
    key = key or tuple(argv)
    if key not in _done:
        master, slave = os.openpty()  # the keyboard teleop needs a terminal, even to --check
        try:
            _done[key] = subprocess.run(argv, cwd=cwd, stdin=slave, capture_output=True,
                                        text=True, timeout=TIMEOUT, env=os.environ)
        finally:
            os.close(master)
            os.close(slave)
    result = _done[key]
    assert result.returncode in ok, (
        f'{shlex.join(argv)} exited {result.returncode}:\n{result.stderr[-3000:]}')
    return result


ENBARR = [sys.executable, '-m', 'enbarr_core.commands.main']


def is_vessel(profile: str) -> bool:
    """Whether ``profile`` runs on a vessel, looking for its topside beyond this machine."""
    range_ = load_profile(profile).environment.get('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET')
    return range_ != 'LOCALHOST'


def run_bringup(args: list[str], ns: argparse.Namespace, tmp: Path) -> str:
    if is_vessel(ns.profile):
        return f'vessel profile {ns.profile}: loaded (not started: it looks for the network)'
    # --duration changes nothing that --check looks at (step 1 parsed it): one run for both
    check = [a for i, a in enumerate(args)
             if a != '--duration' and (i == 0 or args[i - 1] != '--duration')]
    run([*ENBARR, *check, '--check'], tmp)
    return f'{ns.profile}: --check built every node'


def run_scenario(args: list[str], ns: argparse.Namespace, tmp: Path) -> str:
    path = Path(ns.name) if ('/' in ns.name or ns.name.endswith('.yaml')) else (
        ROOT / 'params' / 'scenarios' / f'{ns.name}.yaml')
    assert path.is_file(), f'no scenario {ns.name} ({path})'
    spec = yaml.safe_load(path.read_text(encoding='utf-8'))['scenario']
    seconds = float(spec.get('settle_time', 0.0)) + 2.0
    out = run([*ENBARR, 'scenario', ns.name, '--duration', str(seconds), '--no-plot',
               '--output', str(tmp / 'scenario')], tmp, key=('scenario', ns.name), ok=(0, 1))
    verdict = json.loads(out.stdout.strip().splitlines()[-1])['verdict']
    assert out.returncode == {'pass': 0, 'fail': 1}[verdict], out.stderr[-3000:]
    return f'scenario {ns.name}: ran {seconds} simulated seconds'


def run_bench(args: list[str], ns: argparse.Namespace, tmp: Path) -> str:
    if ns.perception or ns.camera:
        return run_as_written(args, ns, tmp)   # seconds: one process, no ROS graph
    if ns.profile is not None:
        load_profile(ns.profile)
        if ns.against is not None:   # the baseline too
            load_profile(str(ROOT / ns.against) if (ROOT / ns.against).exists() else ns.against)
        return f'bench --profile {ns.profile}: profile loaded (a whole-profile run is long)'
    return f'bench --chain {ns.chain}: parsed (a chain is one of its choices); not run: its ' \
        'fixed phases take tens of seconds whatever the options'


def run_chaos(args: list[str], ns: argparse.Namespace, tmp: Path) -> str:
    load_profile(ns.profile)
    return f'chaos {ns.profile}: profile loaded (a fault run takes minutes)'


def run_as_written(args: list[str], ns: argparse.Namespace, tmp: Path) -> str:
    run([*ENBARR, *args], tmp)
    return 'ran as written'


DEVICE_OPTIONS = ('port', 'bus', 'host', 'device')


def run_check_device(args: list[str], ns: argparse.Namespace, tmp: Path) -> str:
    real = [f'--{o} {getattr(ns, o)}' for o in DEVICE_OPTIONS
            if getattr(ns, o, None) not in (None, 'emulated')]
    if real or not any(getattr(ns, o, None) for o in DEVICE_OPTIONS):
        pytest.skip(f'needs the device ({", ".join(real) or "no device named"}); parsed only')
    return run_as_written(args, ns, tmp)


def run_calibrate(args: list[str], ns: argparse.Namespace, tmp: Path) -> str:
    pytest.skip('needs a camera or its pictures of a board (the live topic, or a folder, video '
                'or bag the reader has); parsed only (test/commands/test_calibrate*.py run it)')


def run_param(args: list[str], ns: argparse.Namespace, tmp: Path) -> str:
    pytest.skip('needs a running node (test/commands/test_param.py and '
                'test/e2e/test_param_cli.py run every verb against one); parsed only')


RUNS: dict[str, Callable[[list[str], argparse.Namespace, Path], str]] = {
    'bringup': run_bringup, 'scenario': run_scenario, 'bench': run_bench, 'chaos': run_chaos,
    'list': run_as_written, 'check-device': run_check_device, 'calibrate': run_calibrate,
    'param': run_param,
}

#: Commands that are not run here, by their first words, with the reason.
NOT_RUN = {
    ('make',): 'builds and flashes the Arduino: an AVR toolchain and a board',
    ('apt-get',): 'installs system packages',
    ('ls', '-l', '/dev/serial/by-id/'): 'lists the USB serial devices plugged in: hardware',
    ('./dev', 'test'): 'the test suite itself',
}


def commands() -> list[Any]:
    return [pytest.param(c, id=f'{c.where[0]} {c.text}') for c in doc_commands()]


@pytest.mark.parametrize('command', commands())
def test_the_command_runs_as_written(command: Command, tmp_path: Path,
                                     monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    for words, why in NOT_RUN.items():
        if command.argv[:len(words)] == words:
            pytest.skip(why)
    if command.argv[:2] == ('python', '-m') or command.argv[:2] == ('python3', '-m'):
        module, options = command.argv[2], MODULE_RUNS.get(command.argv[2])
        assert options is not None, f'{command.where}: no rule for python -m {module}'
        run([sys.executable, '-m', module, *command.argv[3:], *options], tmp_path)
        return
    if command.argv[0] in ('python', 'python3', '.venv/bin/python') \
            and command.argv[1:2] and command.argv[1].startswith('scripts/'):
        # A script of the tree needs its inputs (a bag): it imports and has its command line.
        run([sys.executable, str(ROOT / command.argv[1]), '--help'], tmp_path)
        return
    args = enbarr_argv(command.argv)
    assert args is not None, f'{", ".join(command.where)}: no rule for {command.text!r}'
    ns = parse(args, monkeypatch, capsys)
    runner = RUNS.get(ns.command)
    assert runner is not None, f'{command.where}: no bounded run for enbarr {ns.command}'
    print(runner(args, ns, tmp_path))


# -- the rules themselves ---------------------------------------------------------------------


def test_the_docs_have_commands_of_every_kind() -> None:
    """The extraction finds what the docs show (a fence that stops matching loses them all)."""
    found = {c.argv[:2] for c in doc_commands()}
    assert {('./dev', 'sim'), ('./dev', 'enbarr'), ('./dev', 'bench'), ('make', '-C')} <= found
    assert any(c.argv[:2] == ('enbarr', 'check-device') for c in doc_commands())


def test_dev_expands_as_the_script_does() -> None:
    dev = dev_expansions()
    assert dev['enbarr'] == [] and dev['bench'] == ['bench']
    assert dev['sim'][:3] == ['bringup', '--profile', 'enbarr_sim']


def test_an_unknown_option_is_refused(monkeypatch: pytest.MonkeyPatch,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """The parse step fails on what a doc could get wrong: an option that does not exist."""
    with pytest.raises(pytest.fail.Exception, match='refused by its parser'):
        parse(['bringup', '--profile', 'enbarr_sim', '--chekc'], monkeypatch, capsys)
    ns = parse(['scenario', 'box_path', '--no-plot'], monkeypatch, capsys)
    assert (ns.command, ns.name, ns.no_plot) == ('scenario', 'box_path', True)
