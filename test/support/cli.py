"""Run the ``enbarr`` command line as a user runs it: a separate process (e2e tier)."""

from __future__ import annotations

from collections.abc import Mapping
import os
from pathlib import Path
import subprocess
import sys

#: ``enbarr`` in this interpreter (the console script of an installed copy does the same).
ENBARR = [sys.executable, '-m', 'enbarr_core.commands.main']


def enbarr(*args: str, cwd: Path | None = None, env: Mapping[str, str] | None = None,
           timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """Run ``enbarr ARGS`` to the end, with no terminal; output captured as text."""
    return subprocess.run([*ENBARR, *args], env=os.environ if env is None else env, cwd=cwd,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=timeout)


def refused(result: subprocess.CompletedProcess[str], command: str = 'bringup') -> str:
    """The one error line of a run that must have been refused with exit code 2."""
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert 'Traceback' not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f'enbarr {command}: error: '), lines[0]
    return lines[0]
