"""Give Python threads their names in the operating system (``top -H``, ``/proc``, py-spy).

CPython 3.11 names a ``threading.Thread`` for Python only: ``/proc/PID/task/TID/comm`` of
every thread is the process's name. ``name_os_threads()`` installs a ``threading.setprofile``
hook, the public way to run code in each new thread before its ``run()``: it copies the
thread's name into the kernel's (``prctl(PR_SET_NAME)``, at most 15 bytes, truncated as
pthread_setname_np does) and removes itself at once, so a thread pays for it once. The main
thread keeps the process's name. Threads started before the call, and threads started by C++
(DDS), are left as they are.
"""

from __future__ import annotations

import ctypes
import sys
import threading
from typing import Any

PR_SET_NAME = 15   # linux/prctl.h
COMM_BYTES = 15    # TASK_COMM_LEN - 1

_libc: Any = None


def os_thread_name(name: str) -> bytes:
    """Return the kernel's name for a thread called ``name``: UTF-8, cut to 15 bytes."""
    return name.encode('utf-8', 'replace')[:COMM_BYTES]


def set_os_thread_name(name: str) -> bool:
    """Name the calling thread ``name`` in the kernel; False where that is not possible."""
    global _libc
    try:
        if _libc is None:
            _libc = ctypes.CDLL(None, use_errno=True)
        result: int = _libc.prctl(PR_SET_NAME, ctypes.c_char_p(os_thread_name(name)), 0, 0, 0)
        return result == 0
    except (OSError, AttributeError):  # not Linux, or no prctl
        return False


def _name_this_thread(frame: Any, event: str, arg: Any) -> None:
    sys.setprofile(None)  # once per thread: no profiling cost afterwards
    set_os_thread_name(threading.current_thread().name)


def name_os_threads() -> None:
    """From now on, every thread started with ``threading`` carries its name in the OS."""
    threading.setprofile(_name_this_thread)
