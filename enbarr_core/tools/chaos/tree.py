"""The process tree of a chaos run: ``enbarr bringup`` of the split profile, its output read.

The supervisor logs every start of a group (``group NAME started (pid N)``); that log is how
a fault finds the process to signal. A driver that puts its outputs neutral logs it
(``NEUTRAL_LOG``), which is an observation of its own.
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import threading
import time

from enbarr_core.framework.errors import EnbarrError

#: A driver's log line saying its outputs went neutral: ``[WARN] [<wall s>] [node]: ...``.
NEUTRAL_LOG = re.compile(r'^\[WARN\] \[(\d+\.\d+)\] \[[^\]]+\]: [^\n]*neutral', re.MULTILINE)


def enbarr_command(*args: str) -> list[str]:
    """``enbarr ARGS`` in this interpreter."""
    return [sys.executable, '-m', 'enbarr_core.commands.main', *args]


def neutral_log_times(text: str) -> list[tuple[int, bool]]:
    """Return the drivers' 'neutral' log lines in ``text`` as observations ``(ns, True)``."""
    return [(int(float(t) * 1e9), True) for t in NEUTRAL_LOG.findall(text)]


class Tree:
    """``enbarr bringup`` of the split profile, its merged output collected on a thread."""

    def __init__(self, cmd: list[str], log_path: Path) -> None:
        self.lines: list[str] = []
        self.log_path = log_path
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, text=True,
                                     start_new_session=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        with open(self.log_path, 'w') as log:
            for line in self.proc.stdout:
                self.lines.append(line)
                log.write(line)
                log.flush()

    @property
    def text(self) -> str:
        """Everything the tree printed so far."""
        return ''.join(self.lines)

    def group_pid(self, group: str) -> int | None:
        """Return the pid of the latest start of ``group`` (from the supervisor's log)."""
        found = re.findall(rf'group {group} started \(pid (\d+)\)', self.text)
        return int(found[-1]) if found else None

    def wait_group(self, group: str, timeout: float, other_than: int | None = None) -> int:
        """Wait until ``group`` runs (a process other than ``other_than``); its pid."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            pid = self.group_pid(group)
            if pid is not None and pid != other_than:
                return pid
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise EnbarrError(f'group {group} did not start within {timeout:.0f} s; see '
                          f'{self.log_path}')

    def child_pids(self) -> list[int]:
        """Every group process the supervisor started."""
        return [int(p) for p in re.findall(r'group \w+ started \(pid (\d+)\)', self.text)]

    def stop(self, sig: int = signal.SIGINT, timeout: float = 30.0) -> int:
        """Signal the supervisor and wait for it; SIGKILL the session after ``timeout``."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            rc = self.proc.wait()
        self.reap_children()
        self._reader.join(5.0)
        return rc

    def reap_children(self, timeout: float = 15.0) -> bool:
        """Wait for every group process to end (SIGKILL what is left); True if none was."""
        deadline = time.monotonic() + timeout
        left = self.child_pids()
        while left and time.monotonic() < deadline:
            left = [p for p in left if alive(p)]
            time.sleep(0.1)
        for p in left:
            try:
                os.kill(p, signal.SIGKILL)
            except ProcessLookupError:
                pass
        return not left


def alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().split(') ')[-1][:1] not in ('Z', 'X')
    except OSError:
        return False


def rss_mb(pid: int) -> float | None:
    """Resident memory of ``pid`` [MB], or None when it is gone."""
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None
