"""``enbarr bringup`` as a real process tree, its output watched (the e2e tests of runs).

``bringup`` starts the run in a session of its own and kills what is left of it on the way
out; ``stop`` asks a run to stop as a user does; ``split_profile`` is the simulated ROV with
its control chain in a process group of its own, so that the chain's topics cross processes.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
import os
import re
import signal
import subprocess
import threading
import time
from typing import Any

import yaml

from support.cli import ENBARR

#: The nodes of ``enbarr_sim``'s control chain: IMU -> filter -> controller -> converter.
CONTROL_CHAIN = ('filtering', 'control_loop', 'thruster_converter')
#: ``surface``'s script in ``enbarr_sim``: drive ahead at 0.3 m/s for the whole run.
DRIVE_AHEAD: dict[str, Any] = {
    'parameters': {'script': ['0.0 twist 0.3 0.0 0.0 0.0 0.0 0.0']}}


class Output:
    """Collects a child's merged output lines on a thread."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            self.lines.append(line)

    @property
    def text(self) -> str:
        return ''.join(self.lines)

    def wait_for(self, pattern: str, timeout: float, start: int = 0) -> re.Match[str]:
        """The first match of ``pattern`` in the lines from ``start`` on, waiting ``timeout``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = re.search(pattern, ''.join(self.lines[start:]))
            if m:
                return m
            time.sleep(0.1)
        raise AssertionError(f'no {pattern!r} within {timeout} s; output:\n{self.text[-3000:]}')

    def wait_closed(self, timeout: float) -> None:
        """Wait up to ``timeout`` [s] for the end of the output (every writer has exited)."""
        self._thread.join(timeout)


@contextmanager
def bringup(*args: str) -> Iterator[tuple[subprocess.Popen[str], Output]]:
    """Run ``enbarr bringup ARGS`` in a session of its own, its merged output watched.

    On the way out, whatever of the run still runs is killed (``kill``).
    """
    proc = subprocess.Popen([*ENBARR, 'bringup', *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        yield proc, Output(proc)
    finally:
        kill(proc)


def kill(proc: subprocess.Popen[str]) -> None:
    """SIGKILL every process of ``proc``'s session if ``proc`` still runs, and reap it."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def stop(proc: subprocess.Popen[str], timeout: float = 60.0, session: bool = False) -> int:
    """Ask a run to stop with SIGINT (to its whole session with ``session``, as Ctrl-C in a
    terminal does); SIGKILL its session if it has not stopped after ``timeout`` [s]. Its exit
    code.
    """
    if proc.poll() is None:
        if session:
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
    return proc.wait()


def split_profile(control: Mapping[str, Any] | None = None,
                  **nodes: Mapping[str, Any]) -> str:
    """``enbarr_sim`` with ``CONTROL_CHAIN`` in the process group ``control`` (its settings:
    ``control``), and ``nodes`` (name -> what the profile says of it) added. YAML text.
    """
    profile = {'include': ['enbarr_sim'],
               'nodes': {**{name: {'group': 'control'} for name in CONTROL_CHAIN}, **nodes},
               'groups': {'control': dict(control or {})}}
    return yaml.safe_dump(profile, sort_keys=False)
