"""Faults that remove control: the control group stopped or killed, the supervisor killed.

Each must end with the actuators neutral within 0.5 s (``judge.judge_removal``), timed from
the actuator outputs' own stamps and the drivers' 'neutral' log lines.
"""

from __future__ import annotations

from collections.abc import Callable
import os
from pathlib import Path
import signal
import time

from enbarr_core.framework.errors import EnbarrError
from enbarr_core.tools.chaos import judge
from enbarr_core.tools.chaos.judge import Verdict
from enbarr_core.tools.chaos.observer import Observer
from enbarr_core.tools.chaos.plan import CONTROL_GROUP
from enbarr_core.tools.chaos.tree import neutral_log_times, Tree

RESET_TIMEOUT = 45.0            # s, control back after a restart of the control group
#: A removal fault with no neutral output yet is watched up to this long after the fault [s]:
#: past its window, so that a driver starved on a loaded machine, whose watchdog fires late,
#: is measured late (and failed by its time) rather than not seen at all.
WATCH_LIMIT_S = 5.0


def neutral_events(obs: Observer, tree: Tree) -> list[tuple[int, bool]]:
    """Return the actuator outputs seen, plus the drivers' own 'neutral' log lines.

    A driver that goes neutral publishes its output once; over best-effort DDS to a busy
    observer that one message can be lost, while the driver's log line is not.
    """
    return sorted([*obs.actuators, *neutral_log_times(tree.text)])


def watch(events: Callable[[], list[tuple[int, bool]]], fault_ns: int, window: float,
          *, sleep: Callable[[float], None] = time.sleep,
          clock: Callable[[], int] = time.time_ns) -> tuple[list[tuple[int, bool]], float]:
    """Watch ``events`` after a fault at ``fault_ns``: the window, then on to a neutral output.

    Returns the events and the time watched [s] once ``window`` has passed and a neutral
    output is seen, or once ``WATCH_LIMIT_S`` has passed without one.
    """
    sleep(max(0.0, window - (clock() - fault_ns) * 1e-9))
    while True:
        seen = events()
        waited = (clock() - fault_ns) * 1e-9
        if judge.time_to_neutral(seen, fault_ns) is not None or waited >= WATCH_LIMIT_S:
            return seen, waited
        sleep(min(0.05, WATCH_LIMIT_S - waited))


def judged(name: str, events: list[tuple[int, bool]], fault_ns: int,
           watched_s: float) -> Verdict:
    """Judge a removal fault on ``events``; when no neutral came, say what was seen."""
    if judge.time_to_neutral(events, fault_ns) is not None:
        return judge.judge_removal(name, events, fault_ns)
    before = [t for t, _ in events if t < fault_ns]
    after = [t for t, _ in events if t >= fault_ns]
    last = (f'the last before it {(fault_ns - max(before)) * 1e-9:.3f} s earlier' if before
            else 'none before it')
    return judge.judge_removal(
        name, events, fault_ns,
        extra=f'watched {watched_s:.1f} s: {len(after)} actuator outputs after the fault, '
              f'none neutral; {last}')


def sigstop(obs: Observer, tree: Tree, window: float, name: str) -> Verdict:
    """SIGSTOP the control group for the window (longer while nothing is neutral), SIGCONT.

    Neutral within 0.5 s.
    """
    pid = tree.wait_group(CONTROL_GROUP, 5.0)
    fault = time.time_ns()
    os.kill(pid, signal.SIGSTOP)
    try:
        events, watched = watch(lambda: neutral_events(obs, tree), fault, max(1.0, window))
    finally:
        os.kill(pid, signal.SIGCONT)
    return judged(name, events, fault, watched)


def sigkill(obs: Observer, tree: Tree, window: float, name: str) -> Verdict:
    """SIGKILL the control group (the supervisor restarts it): neutral within 0.5 s."""
    pid = tree.wait_group(CONTROL_GROUP, 5.0)
    fault = time.time_ns()
    os.kill(pid, signal.SIGKILL)
    events, watched = watch(lambda: neutral_events(obs, tree), fault, max(1.0, window))
    v = judged(name, events, fault, watched)
    try:
        tree.wait_group(CONTROL_GROUP, 30.0, other_than=pid)
    except EnbarrError as err:
        return Verdict(v.fault, v.expected, False, v.time_to_safe_s,
                       f'{v.detail}; not restarted: {err}')
    obs.wait_busy(RESET_TIMEOUT)  # a restart takes seconds here: not a failed one
    return v


def kill_supervisor(obs: Observer, tree: Tree, name: str) -> Verdict:
    """SIGKILL the supervisor (children stop through PDEATHSIG): neutral within 0.5 s."""
    fault = time.time_ns()
    tree.proc.kill()
    tree.proc.wait()
    clean = tree.reap_children()
    time.sleep(0.5)
    return judge.judge_removal(name, list(obs.actuators), fault,
                               extra='' if clean else 'group processes left behind',
                               extra_ok=clean)


def after_supervisor(verdicts: list[Verdict], bag: Path) -> None:
    """After a supervisor kill the bag must end with the actuators' safe state."""
    last = last_actuator_output(bag)
    for i, v in enumerate(verdicts):
        if v.fault != 'sigkill:supervisor':
            continue
        if last is None:
            extra, ok = 'no actuator output in the bag', False
        else:
            extra, ok = f'last recorded actuator output {last}', not any(last)
        verdicts[i] = Verdict(v.fault, v.expected, v.passed and ok, v.time_to_safe_s,
                              f'{v.detail}; {extra}', v.figures)


def last_actuator_output(path: Path) -> list[float] | None:
    """Return the last actuator output recorded in the bag at ``path`` (None: none, unreadable)."""
    from enbarr_core.recording.bag import read_bag
    try:
        bag = read_bag(path)
    except Exception:  # noqa: BLE001 - an unreadable bag is judged elsewhere
        return None
    for topic in ('/' + t for t in Observer.ACTUATOR_TOPICS):
        if bag.get(topic):
            return [float(e) for e in bag[topic][-1][1].effort]
    return None
