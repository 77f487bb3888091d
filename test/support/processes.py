"""Watch a child process's output, for the e2e tests that run real process trees."""

from __future__ import annotations

import re
import subprocess
import threading
import time


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
