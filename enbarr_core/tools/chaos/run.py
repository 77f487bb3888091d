"""A whole chaos run: the split profile under bringup, every selected fault in turn, judged.

Between faults the run waits until control is back (actuators busy again); a fault that left
control broken is followed by a SIGKILL of the control group, so the next fault starts clean.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
import os
from pathlib import Path
import signal
import sys
import time
from typing import Any

from enbarr_core.framework.errors import EnbarrError
from enbarr_core.tools.chaos import inputs, judge, removal, storm
from enbarr_core.tools.chaos.disk import bag_readable, disk_run
from enbarr_core.tools.chaos.judge import Verdict
from enbarr_core.tools.chaos.observer import Observer
from enbarr_core.tools.chaos.plan import CONTROL_GROUP, write_split_profile
from enbarr_core.tools.chaos.tree import alive, enbarr_command, Tree

KINDS = ('stamps', 'compete', 'params', 'sigstop', 'sigkill', 'disk', 'supervisor')
STARTUP_TIMEOUT = 90.0          # s, a split profile coming up on a loaded machine
RECOVERY_TIMEOUT = 5.0          # s, control back after a bad input, before a reset


@dataclass(frozen=True)
class Fault:
    """One fault to inject: its name, kind and how to inject and judge it."""

    name: str
    kind: str
    run: Callable[[], Verdict]


def unknown_faults(selected: Sequence[str]) -> list[str]:
    """Return the ``--faults`` entries that are neither a kind nor a fault name."""
    return [f for f in selected if f not in KINDS and ':' not in f]


class Chaos:
    """One chaos run of a profile: the tree, the observer, the faults.

    ``window`` [s] is the observation window after each fault; ``selected`` the fault kinds
    or names to inject (empty: all); ``quiet`` keeps the per-fault lines off stderr.
    """

    def __init__(self, profile: str, out: Path, window: float, selected: Sequence[str] = (),
                 quiet: bool = False) -> None:
        self.out = out
        self.window = window
        self.selected = set(selected)
        self.quiet = quiet
        self.plan = write_split_profile(profile, out)
        self.verdicts: list[Verdict] = []
        self.outputs: list[str] = []
        self.bags: list[Path] = []
        self.tree: Tree | None = None
        self.broken = False  # control did not come back: the remaining faults are skipped
        self.obs: Observer | None = None

    def wanted(self, kind: str, name: str = '') -> bool:
        """Whether ``--faults`` selects this fault (by kind or by name; empty: all)."""
        return not self.selected or kind in self.selected or name in self.selected

    def run(self) -> dict[str, Any]:
        """Inject every selected fault; return the summary."""
        main_kinds = [k for k in KINDS if k != 'disk']
        if any(self.wanted(k) for k in main_kinds) or self.selected - set(KINDS):
            self.main_run()
        if self.wanted('disk'):
            disk = disk_run(self.plan, self.out, self.window, STARTUP_TIMEOUT)
            self.verdicts.append(disk.verdict)
            self.outputs.append(disk.output)
            if disk.bag is not None:
                self.bags.append(disk.bag)
        traces = sum(judge.count_tracebacks(t) for t in self.outputs)
        readable = sum(1 for b in self.bags if bag_readable(b))
        return judge.summary(self.verdicts, traces, readable, len(self.bags))

    def main_run(self) -> None:
        """Run the split profile under bringup; inject every fault but the disk in turn."""
        bag = self.out / 'bag'
        self.bags.append(bag)
        self.obs = Observer()
        self.tree = Tree(enbarr_command('bringup', '--profile', str(self.plan.path),
                                        '--output', str(bag)), self.out / 'bringup.log')
        supervisor_killed = False
        try:
            self.tree.wait_group(CONTROL_GROUP, STARTUP_TIMEOUT)
            if not self.obs.wait_busy(STARTUP_TIMEOUT):
                raise EnbarrError(f'control never drove the actuators; see {self.tree.log_path}')
            for fault in self.faults():
                if self.broken or not self.settle():
                    self.broken = True
                    self.verdicts.append(judge.skipped(fault.name, '', 'control did not '
                                                       'recover from the previous fault'))
                    continue
                verdict = fault.run()
                self.verdicts.append(verdict)
                self._say(verdict)
                supervisor_killed = supervisor_killed or fault.kind == 'supervisor'
            if not supervisor_killed and not self.broken:
                self.settle()  # a restarted group is not stopped while it still starts
        finally:
            if not supervisor_killed:
                self.tree.stop()
            self.obs.close()
            self.outputs.append(self.tree.text)
        if supervisor_killed:
            removal.after_supervisor(self.verdicts, bag)

    def faults(self) -> list[Fault]:
        """Return the selected faults of the main run, in order (the supervisor last)."""
        obs, tree, plan, window = self.obs, self.tree, self.plan, self.window
        assert obs is not None and tree is not None
        faults: list[Fault] = []
        for topic in obs.stamped_inputs(plan.control_nodes):
            for label, offset in inputs.STAMP_OFFSETS:
                name = f'{label}:{topic}'
                if self.wanted('stamps', name):
                    faults.append(Fault(name, 'stamps', lambda t=topic, o=offset, n=name:
                                        inputs.stamp(obs, plan, window, n, t, o)))
        for topic in obs.command_topics(plan.control_nodes):
            name = f'compete:{topic}'
            if self.wanted('compete', name):
                faults.append(Fault(name, 'compete', lambda t=topic, n=name:
                                    inputs.compete(obs, plan, window, n, t)))
        table: tuple[tuple[str, str, Callable[[str], Verdict]], ...] = (
            ('params', 'params', self.param_storm),
            ('sigstop', f'sigstop:{CONTROL_GROUP}',
             lambda n: removal.sigstop(obs, tree, window, n)),
            ('sigkill', f'sigkill:{CONTROL_GROUP}',
             lambda n: removal.sigkill(obs, tree, window, n)),
            ('supervisor', 'sigkill:supervisor',
             lambda n: removal.kill_supervisor(obs, tree, n)))
        for kind, name, fn in table:
            if self.wanted(kind, name):
                faults.append(Fault(name, kind, lambda f=fn, n=name: f(n)))
        return faults

    def param_storm(self, name: str) -> Verdict:
        """Storm every node's parameters (``storm``); control must hold, every call judged."""
        assert self.obs is not None
        outcome = storm.storm(self.obs.node, window=self.window)
        return judge.judge_storm(name, list(self.obs.control), list(self.obs.actuators),
                                 outcome.start_ns, outcome.end_ns, outcome.answers,
                                 outcome.nodes)

    def settle(self) -> bool:
        """Wait for control to drive again; reset the control group if it does not.

        How long that took is added to the previous fault's figures (``recovered_after_s``,
        and ``reset`` when the control group had to be restarted).
        """
        assert self.obs is not None and self.tree is not None
        t0 = time.monotonic()
        ok, reset = self.obs.wait_busy(RECOVERY_TIMEOUT), False
        if not ok:
            reset = True
            pid = self.tree.group_pid(CONTROL_GROUP)
            if pid is not None and alive(pid):
                os.kill(pid, signal.SIGKILL)
            try:
                self.tree.wait_group(CONTROL_GROUP, 30.0, other_than=pid)
                ok = self.obs.wait_busy(removal.RESET_TIMEOUT)
            except EnbarrError:
                ok = False
        if self.verdicts:
            v = self.verdicts[-1]
            figures = {**v.figures, 'recovered_after_s': round(time.monotonic() - t0, 1)
                       if ok else None}
            if reset:
                figures['reset'] = True
            self.verdicts[-1] = replace(v, figures=figures)
        return ok

    def _say(self, v: Verdict) -> None:
        if not self.quiet:
            t = '' if v.time_to_safe_s is None else f' ({v.time_to_safe_s:.3f} s)'
            print(f'{"PASS" if v.passed else "FAIL"} {v.fault}{t}: {v.detail}',
                  file=sys.stderr, flush=True)

