"""A real, small filesystem for full-disk tests: a tmpfs in a private mount namespace.

``unshare -m`` starts a holder process in its own mount namespace and mounts a tmpfs of the
asked size there; this process reaches it through ``/proc/<holder>/root/...`` (root only), so
nothing is mounted in the machine's own namespace and the filesystem disappears with the
holder. Where that cannot be had (not root, no ``unshare``, no user namespaces) the test is
skipped, saying why; CI runs as root.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
import os
from pathlib import Path
import shutil
import subprocess
import time

import pytest


@contextmanager
def small_disk(where: Path, size: str) -> Iterator[Path]:
    """Yield a directory on a fresh tmpfs of ``size`` (as ``mount -o size=``, e.g. '2m')."""
    if os.geteuid() != 0:
        pytest.skip('a full-disk test mounts a tmpfs: needs root (CI runs as root)')
    unshare = shutil.which('unshare')
    if unshare is None:
        pytest.skip('a full-disk test needs util-linux unshare to mount a private tmpfs')
    mountpoint = where / 'small_disk'
    mountpoint.mkdir()
    holder = subprocess.Popen(
        [unshare, '-m', '--propagation', 'private', 'sh', '-c',
         f'mount -t tmpfs -o size={size} tmpfs "{mountpoint}" && echo mounted && exec cat'],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None
        line = holder.stdout.readline()
        if line.strip() != 'mounted':
            holder.wait(10)
            pytest.skip(f'cannot mount a private tmpfs: {holder.stderr.read().strip()}')
        disk = Path(f'/proc/{holder.pid}/root') / mountpoint.relative_to('/')
        deadline = time.monotonic() + 10
        while shutil.disk_usage(disk).total == shutil.disk_usage(where).total:
            assert time.monotonic() < deadline, 'the tmpfs did not appear'
            time.sleep(0.05)
        yield disk
    finally:
        holder.kill()  # stdin closed or not: the namespace and its tmpfs go with it
        holder.wait()


def fill(disk: Path, leave: int) -> None:
    """Fill ``disk`` up to ``leave`` bytes free (a file named ``filler``)."""
    free = shutil.disk_usage(disk).free
    with open(disk / 'filler', 'ab') as f:
        f.write(b'\0' * max(0, free - leave))
