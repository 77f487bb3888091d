"""``enbarr chaos PROFILE``: run a profile as a real process tree and inject faults in turn.

The profile runs under ``enbarr bringup --record`` split into process groups, built on the
fly (``chaos.yaml`` in the output directory): the core nodes (command receiver, filter,
observer, guidance, controllers, allocation, PWM mapping) go to group ``control``, the rest
(simulator, sensor and actuator plugins, operator stand-ins) stay in ``main``, the recorder
gets its own. The split is what lets injection reach the nodes: a fast topic travels the
in-process link bus, and an outside publisher reaches a link subscription only when no
publisher of that topic lives in the subscriber's process (``enbarr_interfaces.links``).
The operator stand-in is given a steady command (an ROV drives ahead, a surface vessel holds
its pose in automatic) so that the actuators are busy when a fault comes.

Faults (``--faults`` selects kinds or names), each judged by ``chaos_judge`` from what a
subscriber in this process and the bag observe:

``stamps``
    For every stamped input of the control group (contract topics with a header that a
    control node subscribes to in the running graph: ``imu/data_raw``, ``imu/mag``,
    ``surface_command/twist``, ``mocap/pose``, ``joy``, ...): a burst of ten copies of
    the last real sample (a distinctive command on command topics) stamped +20 s, +0.4 s
    and -0.1 s from now.
    Safe: control not disrupted, and a command so stamped is never executed.
``compete``
    A second publisher on every command topic the profile has (``surface_command/twist``,
    ``surface_command/io``, ``joy``), sending a distinctive command for the window. Safe:
    control not disrupted and the intruder's command never executed (never the velocity
    goal, never an io request, never a surge force in manual: the joystick intruder presses
    manual and pushes surge, while manual with zero force is the safe outcome of a contested
    joystick).
``params``
    A parameter storm: for every node, ``SetParameters`` calls as ``ros2 param set`` makes
    them (one parameter per call, all at once): each parameter set to its own value
    (valid), to a value of the wrong type and, for floating-point ones, to NaN (invalid).
    Safe: control not disrupted and no invalid value accepted.
``sigstop`` / ``sigkill``
    The control group SIGSTOPped (SIGCONT after the window) / SIGKILLed (the supervisor
    restarts it). Safe: actuators neutral within 0.5 s.
``disk``
    A second run recording to a 160 MiB tmpfs in a private mount namespace (needs root,
    else skipped), filled to the last byte once control runs. Safe: control not disrupted
    while the disk is full, the recorder's memory bounded, the bag readable, and
    ``bringup`` exiting non-zero.
``supervisor``
    The supervisor SIGKILLed (last: the run ends). Safe: actuators neutral within 0.5 s and
    the bag's last actuator output neutral.

Between faults the run waits until control is back (actuators busy again); a fault that left
control broken is followed by a SIGKILL of the control group, so the next fault starts clean.
Prints one JSON line (``chaos_judge.summary``) and exits 1 when a fault failed, a traceback
appeared in any process's output or a bag is unreadable.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
import json
import math
import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

import yaml

from enbarr_core.framework.errors import EnbarrError
from enbarr_core.tools import chaos_judge as judge
from enbarr_core.tools.chaos_judge import KEEPS_CONTROL, Verdict

#: Plugins that make the control group: what must keep working, and what injection reaches.
CONTROL_PLUGINS = frozenset({
    'command_receiver', 'attitude_filter', 'velocity_control', 'thruster_converter',
    'dp_observer', 'guidance', 'dp_control', 'azimuth_allocation', 'pwm_mapper'})
CONTROL_GROUP = 'control'
#: Core nodes that are neither the control chain nor a plugin: they stay with the plugins.
SUPPORT_PLUGINS = frozenset({'frame_publisher'})
#: The operator stand-ins' steady command during a chaos run (a busy vehicle).
STEADY_SCRIPTS = {
    'scripted_commands': ['0.0 twist 0.3 0.0 0.0 0.0 0.0 0.0', '0.5 io gpio_12 false'],
    # Then the automatic button (hold the pose): the observer's estimate is in the loop.
    'scripted_joy': ['0.0 sticks 0.0 0.0 0.0'],
}
#: A driver's log line saying its outputs went neutral: ``[WARN] [<wall s>] [node]: ...``.
NEUTRAL_LOG = re.compile(r'^\[WARN\] \[(\d+\.\d+)\] \[[^\]]+\]: [^\n]*neutral', re.MULTILINE)
#: Operator command topics: an injection there is also a second source (see chaos_judge).
COMMAND_TOPICS = ('surface_command/twist', 'surface_command/io', 'joy')
JOY_PRESS_EVERY_S = 3
JOY_SCRIPT_S = 1200
KINDS = ('stamps', 'compete', 'params', 'sigstop', 'sigkill', 'disk', 'supervisor')
#: Stamp offsets injected on every stamped input [s]: far future, just beyond a tolerance,
#: older than the last accepted sample.
STAMP_OFFSETS = (('future+20s', 20.0), ('future+0.4s', 0.4), ('past-0.1s', -0.1))
INTRUDER_FORCE_MIN = 0.05      # [N] a surge force in manual above this is the joystick intruder's
INTRUDER_SPEED = -0.21          # m/s: the intruder's twist, never the vehicle's own
DISK_BYTES = 160 << 20          # the tmpfs of the disk fault (over the recorder's 64 MB margin)
STAMP_BURST = 10                # bad-stamped samples per stamp fault, 10 ms apart
RSS_GROWTH_LIMIT_MB = 3.0       # recorder memory growth allowed while the disk stays full
RSS_SETTLE_S = 2.0              # ... counted from this long after the disk filled
STARTUP_TIMEOUT = 90.0          # s, a split profile coming up on a loaded machine
RECOVERY_TIMEOUT = 5.0          # s, control back after a bad input, before a reset
RESET_TIMEOUT = 45.0            # s, control back after that reset


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``enbarr chaos`` options to ``p``."""
    p.add_argument('profile', metavar='PROFILE', help='vessel profile (name or path)')
    p.add_argument('--duration', type=float, default=2.0, metavar='S',
                   help='observation window after each fault (default 2 s)')
    p.add_argument('--faults', default='', metavar='a,b,...',
                   help=f'fault kinds or names to inject (default all: {",".join(KINDS)})')
    p.add_argument('--out', metavar='DIR',
                   help='keep profile, bags and logs in DIR (must not exist; default: a '
                   'temporary directory, removed)')
    p.add_argument('--json', action='store_true', help='print only the JSON line')


# -- the run's profile ---------------------------------------------------------------------
@dataclass(frozen=True)
class Plan:
    """What the split profile holds: its file, control nodes and command sources."""

    path: Path
    control_nodes: frozenset[str]
    joy_buttons: dict[str, int] = field(default_factory=dict)


def _joy_layout(params: dict[str, Any]) -> tuple[dict[str, int], tuple[str, ...]]:
    """Return the profile's joystick indices and, with a named ``joy.layout``, its buttons.

    Indices as ``axis_surge``, ``button_automatic`` ...; empty without a joystick.
    """
    from enbarr_core.control.joy_layouts import get_layout, INDEX_PARAMETERS, mapping_from_params
    if not any(k.startswith('joy.') for k in params):
        return {}, ()
    try:
        mapping, _ = mapping_from_params(params)
    except ValueError:
        return {}, ()
    layout = params.get('joy.layout')
    return ({k: getattr(mapping, k) for k in INDEX_PARAMETERS},
            get_layout(layout).buttons if layout else ())


def write_split_profile(ref: str, out: Path) -> Plan:
    """Write ``out/chaos.yaml``: ``ref`` with its core nodes in group ``control``."""
    from enbarr_core.bringup import profile as profiles
    prof = profiles.load_profile(ref)
    control = [n.name for n in prof.nodes if n.plugin in CONTROL_PLUGINS]
    plugins = [n for n in prof.nodes if n.plugin not in CONTROL_PLUGINS | SUPPORT_PLUGINS]
    if not control or not plugins:
        core = ', '.join(sorted(CONTROL_PLUGINS))
        raise EnbarrError(f'{prof.path}: chaos needs core nodes ({core}) and plugins beside '
                          'them to split the profile')
    nodes: dict[str, Any] = {n: {'group': CONTROL_GROUP} for n in control}
    buttons, names = _joy_layout(prof.parameters)
    for n in prof.nodes:
        if n.plugin in STEADY_SCRIPTS:
            script = list(STEADY_SCRIPTS[n.plugin])
            names = names or n.parameters.get('joy.buttons', ())
            auto = buttons.get('button_automatic')
            if n.plugin == 'scripted_joy' and auto is not None and auto < len(names):
                # Pressed again every few seconds: a control group restarted after a fault
                # starts in manual, and the run goes on in automatic.
                script += [f'{t:.1f} press {names[auto]}'
                           for t in range(1, JOY_SCRIPT_S, JOY_PRESS_EVERY_S)]
            nodes[n.name] = {'parameters': {'script': script}}
    doc = {'profile': f'chaos_{prof.name}', 'description': f'{prof.name} split for chaos',
           'include': [str(Path(prof.path).resolve())], 'nodes': nodes,
           'groups': {CONTROL_GROUP: {'restart_limit': 50, 'restart_delay': 0.2}}}
    path = out / 'chaos.yaml'
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return Plan(path, frozenset(control), buttons)


# -- the process tree --------------------------------------------------------------------------
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
        alive = self.child_pids()
        while alive and time.monotonic() < deadline:
            alive = [p for p in alive if _alive(p)]
            time.sleep(0.1)
        for p in alive:
            try:
                os.kill(p, signal.SIGKILL)
            except ProcessLookupError:
                pass
        return not alive


def _alive(pid: int) -> bool:
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().split(') ')[-1][:1] not in ('Z', 'X')
    except OSError:
        return False


def _rss_mb(pid: int) -> float | None:
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


# -- the observer ----------------------------------------------------------------------------
class Observer:
    """A node in this process that watches the control and actuator outputs and injects."""

    CONTROL_TOPICS = ('thruster_commands', 'pwm/duty_cycle')
    ACTUATOR_TOPICS = ('thruster_output', 'sim/azimuth_command')

    def __init__(self) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        from enbarr_interfaces import topics

        self.topics = {t.name: t for t in topics.ALL_TOPICS}
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node('enbarr_chaos', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.control: list[int] = []                   # receive ns of control outputs
        self.actuators: list[tuple[int, bool]] = []    # (stamp ns, neutral)
        self.goals: list[tuple[int, Any]] = []         # trajectory_request
        self.io: list[tuple[int, Any]] = []            # io_request
        self.modes: list[tuple[int, str]] = []
        self.latest: dict[str, Any] = {}               # last sample of each watched input
        self._subs: list[Any] = []
        for name in self.CONTROL_TOPICS:
            self._watch(name, lambda m: self.control.append(time.time_ns()))
        for name in self.ACTUATOR_TOPICS:
            self._watch(name, self._on_actuator)
        self._watch('trajectory_request', lambda m: self.goals.append((time.time_ns(), m)))
        self._watch('io_request', lambda m: self.io.append((time.time_ns(), m)))
        self._watch('mode', lambda m: self.modes.append((time.time_ns(), m.data)))
        self.forces: list[tuple[int, float]] = []      # force_command surge [N]
        if 'force_command' in self.topics:
            self._watch('force_command', lambda m: self.forces.append(
                (time.time_ns(), m.wrench.force.x)))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _watch(self, name: str, callback: Callable[[Any], None]) -> None:
        spec = self.topics[name]
        self._subs.append(self.node.create_subscription(spec.msg_type, name, callback,
                                                        spec.qos))

    def _on_actuator(self, msg: Any) -> None:
        from enbarr_interfaces.convert import stamp_to_ns
        stamp = stamp_to_ns(msg.header.stamp) or time.time_ns()
        self.actuators.append((stamp, not any(msg.effort)))

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - a shutdown race at the end of a run
                if self._stop.is_set():
                    return
                raise

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        import rclpy
        self._stop.set()
        self._thread.join(5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    # -- state -----------------------------------------------------------------------------
    def busy(self, within_s: float = 0.3) -> bool:
        """Control output flowing and the actuators driving (not neutral) right now."""
        now = time.time_ns()
        recent = self.control and now - self.control[-1] < within_s * 1e9
        return bool(recent and self.actuators and not self.actuators[-1][1]
                    and now - self.actuators[-1][0] < within_s * 1e9)

    def wait_busy(self, timeout: float, steady_s: float = 0.5) -> bool:
        """Wait until ``busy()`` has held for ``steady_s``."""
        deadline = time.monotonic() + timeout
        since: float | None = None
        while time.monotonic() < deadline:
            if self.busy():
                since = since or time.monotonic()
                if time.monotonic() - since >= steady_s:
                    return True
            else:
                since = None
            time.sleep(0.05)
        return False

    def stamped_inputs(self, control_nodes: frozenset[str]) -> list[str]:
        """Contract topics with a header that a control node takes from outside its group."""
        found = []
        for name, spec in self.topics.items():
            if 'header' not in spec.msg_type.get_fields_and_field_types():
                continue
            topic = '/' + name.lstrip('/')
            subs = self.node.get_subscriptions_info_by_topic(topic)
            # Fed from outside the control group: a fast topic produced inside it reaches its
            # subscribers in-process (their graph readers are never read), so a sample
            # injected over DDS would never arrive there.
            pubs = self.node.get_publishers_info_by_topic(topic)
            if any(s.node_name in control_nodes for s in subs) and \
                    any(p.node_name not in control_nodes for p in pubs):
                found.append(name)
        return found

    def command_topics(self, control_nodes: frozenset[str]) -> list[str]:
        """Name the operator command topics a control node subscribes to, someone publishes."""
        found = []
        for name in COMMAND_TOPICS:
            subs = self.node.get_subscriptions_info_by_topic('/' + name)
            if any(s.node_name in control_nodes for s in subs) and \
                    self.node.count_publishers('/' + name) > 0:
                found.append(name)
        return found

    def sample_of(self, name: str, timeout: float = 3.0) -> Any | None:
        """Return the last real sample of input ``name`` (subscribing on first use)."""
        if name not in self.latest:
            self.latest[name] = None
            self._watch(name, lambda m, n=name: self.latest.__setitem__(n, m))
        deadline = time.monotonic() + timeout
        while self.latest[name] is None and time.monotonic() < deadline:
            time.sleep(0.02)
        return self.latest[name]

    def publisher(self, name: str, timeout: float = 5.0) -> Any:
        """Return a publisher on ``name`` once every existing subscriber matched it."""
        spec = self.topics[name]
        pub = self.node.create_publisher(spec.msg_type, name, spec.qos)
        want = len([s for s in self.node.get_subscriptions_info_by_topic('/' + name)
                    if s.node_name != self.node.get_name()])
        deadline = time.monotonic() + timeout
        while pub.get_subscription_count() < want and time.monotonic() < deadline:
            time.sleep(0.02)
        return pub


# -- the faults ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Fault:
    """One fault to inject: its name, kind and how to inject and judge it."""

    name: str
    kind: str
    run: Callable[[], Verdict]


class Chaos:
    """One chaos run of a profile: the tree, the observer, the faults."""

    def __init__(self, args: argparse.Namespace, out: Path) -> None:
        self.args = args
        self.out = out
        self.window = args.duration
        self.selected = {s.strip() for s in args.faults.split(',') if s.strip()}
        self.plan = write_split_profile(args.profile, out)
        self.verdicts: list[Verdict] = []
        self.outputs: list[str] = []
        self.bags: list[Path] = []
        self.tree: Tree | None = None
        self.broken = False  # control did not come back: the remaining faults are skipped
        self.obs: Observer | None = None

    def wanted(self, kind: str, name: str = '') -> bool:
        """Whether ``--faults`` selects this fault (by kind or by name; empty: all)."""
        return not self.selected or kind in self.selected or name in self.selected

    # -- the main run ------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        """Inject every selected fault; return the summary."""
        main_kinds = [k for k in KINDS if k != 'disk']
        if any(self.wanted(k) for k in main_kinds) or self.selected - set(KINDS):
            self.main_run()
        if self.wanted('disk'):
            self.verdicts.append(self.disk_run())
        traces = sum(judge.count_tracebacks(t) for t in self.outputs)
        readable = sum(1 for b in self.bags if _bag_readable(b))
        return judge.summary(self.verdicts, traces, readable, len(self.bags))

    def main_run(self) -> None:
        """Run the split profile under bringup; inject every fault but the disk in turn."""
        bag = self.out / 'bag'
        self.bags.append(bag)
        self.obs = Observer()
        self.tree = Tree(enbarr_command('bringup', '--profile', str(self.plan.path),
                                        '--record', str(bag)), self.out / 'bringup.log')
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
            self._judge_bag_after_supervisor(bag)

    def faults(self) -> list[Fault]:
        """Return the selected faults of the main run, in order (the supervisor last)."""
        assert self.obs is not None
        faults: list[Fault] = []
        for topic in self.obs.stamped_inputs(self.plan.control_nodes):
            for label, offset in STAMP_OFFSETS:
                name = f'{label}:{topic}'
                if self.wanted('stamps', name):
                    faults.append(Fault(name, 'stamps',
                                        lambda t=topic, o=offset, n=name: self.stamp(n, t, o)))
        for topic in self.obs.command_topics(self.plan.control_nodes):
            name = f'compete:{topic}'
            if self.wanted('compete', name):
                faults.append(Fault(name, 'compete', lambda t=topic, n=name: self.compete(n, t)))
        table = (('params', 'params', self.param_storm),
                 ('sigstop', f'sigstop:{CONTROL_GROUP}', self.sigstop),
                 ('sigkill', f'sigkill:{CONTROL_GROUP}', self.sigkill),
                 ('supervisor', 'sigkill:supervisor', self.kill_supervisor))
        for kind, name, fn in table:
            if self.wanted(kind, name):
                faults.append(Fault(name, kind, lambda f=fn, n=name: f(n)))
        return faults

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
            if pid is not None and _alive(pid):
                os.kill(pid, signal.SIGKILL)
            try:
                self.tree.wait_group(CONTROL_GROUP, 30.0, other_than=pid)
                ok = self.obs.wait_busy(RESET_TIMEOUT)
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

    def _observe(self, seconds: float) -> tuple[int, int]:
        start = time.time_ns()
        time.sleep(seconds)
        return start, time.time_ns()

    def _say(self, v: Verdict) -> None:
        if not self.args.json:
            t = '' if v.time_to_safe_s is None else f' ({v.time_to_safe_s:.3f} s)'
            print(f'{"PASS" if v.passed else "FAIL"} {v.fault}{t}: {v.detail}',
                  file=sys.stderr, flush=True)

    # -- bad inputs --------------------------------------------------------------------------
    def _intruder(self, topic: str, template: Any) -> Any:
        """Return a distinctive command for ``topic`` (never the vehicle's own)."""
        from geometry_msgs.msg import TwistStamped
        from rcl_interfaces.msg import Parameter, ParameterType
        if topic == 'surface_command/twist':
            msg = TwistStamped()
            msg.header.frame_id = 'base_link'
            msg.twist.linear.x = INTRUDER_SPEED
            return msg
        if topic == 'surface_command/io':
            msg = Parameter()
            msg.name = 'gpio_12'
            msg.value.type = ParameterType.PARAMETER_BOOL
            msg.value.bool_value = True
            return msg
        if topic == 'joy' and template is not None:
            msg = type(template)()
            msg.header.frame_id = template.header.frame_id
            msg.axes = [0.0] * len(template.axes)
            msg.buttons = [0] * len(template.buttons)
            press = self.plan.joy_buttons.get('button_manual')
            if press is not None and press < len(msg.buttons):
                msg.buttons[press] = 1
            surge = self.plan.joy_buttons.get('axis_surge')
            if surge is not None and surge < len(msg.axes):
                msg.axes[surge] = -0.6
            return msg
        return template

    def _executed(self, topic: str, start: int, end: int, mode_before: str | None) -> int:
        """How often the intruder's command took effect in ``start .. end``."""
        assert self.obs is not None
        if topic == 'surface_command/twist':
            return sum(1 for t, m in list(self.obs.goals) if start <= t <= end
                       and abs(m.twist.linear.x - INTRUDER_SPEED) < 1e-6)
        if topic == 'surface_command/io':
            return sum(1 for t, m in list(self.obs.io) if start <= t <= end
                       and m.name == 'gpio_12' and m.value.bool_value)
        if topic == 'joy':
            # The intruder presses manual and pushes surge. Manual with zero force is also the
            # safe outcome (a contested joystick counts as lost), so what gives the intruder
            # away is a surge force in manual.
            modes = list(self.obs.modes)

            def mode_at(t: int) -> str | None:
                return next((m for tm, m in reversed(modes) if tm <= t), mode_before)
            return sum(1 for t, surge in list(self.obs.forces) if start <= t <= end
                       and mode_at(t) == 'manual' and abs(surge) > INTRUDER_FORCE_MIN)
        return 0

    def _mode(self) -> str | None:
        assert self.obs is not None
        return self.obs.modes[-1][1] if self.obs.modes else None

    def stamp(self, name: str, topic: str, offset: float) -> Verdict:
        """Inject samples of ``topic`` stamped ``offset`` s from now; control must hold."""
        from enbarr_interfaces.convert import ns_to_stamp
        assert self.obs is not None
        template = self.obs.sample_of(topic)
        msg = self._intruder(topic, template)
        if msg is None:
            return judge.skipped(name, KEEPS_CONTROL, f'no sample of {topic} to copy')
        pub = self.obs.publisher(topic)
        mode_before = self._mode()
        start = time.time_ns()
        # A burst, not one sample: a split chain over DDS drops samples its executor cannot
        # take in time (the filter took 4 in 10 of a 400 Hz IMU here), and any one of these
        # that gets through is the fault.
        for _ in range(STAMP_BURST):
            msg.header.stamp = ns_to_stamp(time.time_ns() + int(offset * 1e9))
            pub.publish(msg)
            time.sleep(0.01)
        _, end = self._observe(self.window)
        self.obs.node.destroy_publisher(pub)
        executed = self._executed(topic, start, end, mode_before) \
            if msg is not template else 0
        return judge.judge_kept(name, list(self.obs.control), list(self.obs.actuators),
                                start, end, executed=executed,
                                executed_what='commands with that stamp executed',
                                allow_neutral=topic in COMMAND_TOPICS)

    def compete(self, name: str, topic: str) -> Verdict:
        """Publish on command ``topic`` as a second source; its commands must not act."""
        from enbarr_interfaces.convert import ns_to_stamp
        assert self.obs is not None
        template = self.obs.sample_of(topic) if topic == 'joy' else None
        msg = self._intruder(topic, template)
        if msg is None:
            return judge.skipped(name, KEEPS_CONTROL, f'no sample of {topic} to copy')
        pub = self.obs.publisher(topic)
        mode_before = self._mode()
        start = time.time_ns()
        sent = 0
        while time.time_ns() - start < self.window * 1e9:
            if hasattr(msg, 'header'):
                msg.header.stamp = ns_to_stamp(time.time_ns())
            pub.publish(msg)
            sent += 1
            time.sleep(0.05)
        end = time.time_ns()
        time.sleep(0.2)  # what was sent last is still on its way
        self.obs.node.destroy_publisher(pub)
        executed = self._executed(topic, start, end + int(0.2e9), mode_before)
        return judge.judge_kept(name, list(self.obs.control), list(self.obs.actuators),
                                start, end, executed=executed,
                                executed_what="of the intruder's commands executed",
                                allow_neutral=True, figures={'sent': sent})

    def param_storm(self, name: str) -> Verdict:
        """Many SetParameters calls, valid and invalid, on every node; control must hold."""
        assert self.obs is not None
        from rclpy.parameter import Parameter, parameter_value_to_python
        from rclpy.parameter_client import AsyncParameterClient
        node = self.obs.node
        targets = [(n, ns) for n, ns in node.get_node_names_and_namespaces()
                   if n != node.get_name()]
        clients, current = [], {}
        for n, ns in targets:
            full = (ns.rstrip('/') + '/' + n) if ns else n
            client = AsyncParameterClient(node, full)
            if not client.wait_for_services(5.0):
                continue
            names = _result(client.list_parameters(), 5.0)
            if names is None:
                continue
            names = [p for p in names.result.names if p != 'use_sim_time']
            values = _result(client.get_parameters(names), 5.0)
            if values is None:
                continue
            current[full] = dict(zip(names, (parameter_value_to_python(v)
                                              for v in values.values)))
            clients.append((full, client))
        calls: list[tuple[str, Any, str, Parameter, bool]] = []
        for full, client in clients:
            for pname, value in current[full].items():
                calls.append((full, client, pname, Parameter(pname, value=value), True))
                wrong: Any = 3.5 if isinstance(value, str) else 'chaos'
                calls.append((full, client, pname, Parameter(pname, value=wrong), False))
                if isinstance(value, float):
                    calls.append((full, client, pname, Parameter(pname, value=math.nan),
                                  False))
        start = time.time_ns()
        futures = [(c, c[1].set_parameters([c[3]])) for c in calls]
        deadline = time.monotonic() + max(10.0, self.window)
        while time.monotonic() < deadline and not all(f.done() for _, f in futures):
            time.sleep(0.05)
        end = max(time.time_ns(), start + int(self.window * 1e9))
        time.sleep(max(0.0, (end - time.time_ns()) * 1e-9))
        accepted_invalid, answered, refused_valid = [], 0, 0
        for (full, client, pname, param, valid), fut in futures:
            if not fut.done() or fut.result() is None:
                continue
            answered += 1
            ok = fut.result().results[0].successful
            if not valid and ok:
                accepted_invalid.append(f'{full}.{pname}={param.value!r}')
                client.set_parameters([Parameter(pname, value=current[full][pname])])
            refused_valid += valid and not ok
        v = judge.judge_kept(
            name, list(self.obs.control), list(self.obs.actuators), start, end,
            executed=len(accepted_invalid),
            executed_what='invalid values accepted: ' + ', '.join(accepted_invalid[:5]),
            figures={'nodes': len(clients), 'calls': len(calls), 'answered': answered,
                     'valid_refused': refused_valid})
        return v

    # -- control removed ---------------------------------------------------------------------
    def sigstop(self, name: str) -> Verdict:
        """SIGSTOP the control group for the window, then SIGCONT: neutral within 0.5 s."""
        assert self.obs is not None and self.tree is not None
        pid = self.tree.wait_group(CONTROL_GROUP, 5.0)
        fault = time.time_ns()
        os.kill(pid, signal.SIGSTOP)
        time.sleep(max(1.0, self.window))
        os.kill(pid, signal.SIGCONT)
        return judge.judge_removal(name, self._neutral_events(), fault)

    def sigkill(self, name: str) -> Verdict:
        """SIGKILL the control group (the supervisor restarts it): neutral within 0.5 s."""
        assert self.obs is not None and self.tree is not None
        pid = self.tree.wait_group(CONTROL_GROUP, 5.0)
        fault = time.time_ns()
        os.kill(pid, signal.SIGKILL)
        time.sleep(max(1.0, self.window))
        v = judge.judge_removal(name, self._neutral_events(), fault)
        try:
            self.tree.wait_group(CONTROL_GROUP, 30.0, other_than=pid)
        except EnbarrError as err:
            return Verdict(v.fault, v.expected, False, v.time_to_safe_s,
                           f'{v.detail}; not restarted: {err}')
        self.obs.wait_busy(RESET_TIMEOUT)  # a restart takes seconds here: not a failed one
        return v

    def _neutral_events(self) -> list[tuple[int, bool]]:
        """Actuator outputs seen, plus the drivers' own 'neutral' log lines (their stamps).

        A driver that goes neutral publishes its output once; over best-effort DDS to a busy
        observer that one message can be lost, while the driver's log line is not.
        """
        assert self.obs is not None and self.tree is not None
        logged = [(int(float(t) * 1e9), True) for t in NEUTRAL_LOG.findall(self.tree.text)]
        return sorted([*self.obs.actuators, *logged])

    def kill_supervisor(self, name: str) -> Verdict:
        """SIGKILL the supervisor (children stop through PDEATHSIG): neutral within 0.5 s."""
        assert self.obs is not None and self.tree is not None
        fault = time.time_ns()
        self.tree.proc.kill()
        self.tree.proc.wait()
        clean = self.tree.reap_children()
        time.sleep(0.5)
        return judge.judge_removal(name, list(self.obs.actuators), fault,
                                   extra='' if clean else 'group processes left behind',
                                   extra_ok=clean)

    def _judge_bag_after_supervisor(self, bag: Path) -> None:
        """After a supervisor kill the bag must end with the actuators' safe state."""
        last = _last_actuator_output(bag)
        for i, v in enumerate(self.verdicts):
            if v.fault != 'sigkill:supervisor':
                continue
            if last is None:
                extra, ok = 'no actuator output in the bag', False
            else:
                extra, ok = f'last recorded actuator output {last}', not any(last)
            self.verdicts[i] = Verdict(v.fault, v.expected, v.passed and ok, v.time_to_safe_s,
                                       f'{v.detail}; {extra}', v.figures)

    # -- the disk fault ----------------------------------------------------------------------
    def disk_run(self) -> Verdict:
        """Run with a recording disk that fills: control kept, memory bounded, exit != 0."""
        name = 'disk_full:recorder'
        if os.geteuid() != 0 or shutil.which('unshare') is None:
            return judge.skipped(name, KEEPS_CONTROL, 'needs root (a tmpfs in a private '
                                 'mount namespace)')
        mnt = self.out / 'tmpfs'
        mnt.mkdir()
        kept = self.out / 'disk_bag'
        self.bags.append(kept)
        # In the namespace: mount, run bringup (its pid printed for the final SIGINT), keep a
        # copy of the bag once it ended (the tmpfs goes with the namespace).
        script = ('mount -t tmpfs -o size=%d enbarr_chaos "$0" || exit 97; '
                  '"$@" & pid=$!; echo "chaos: bringup pid $pid"; wait $pid; rc=$?; '
                  'cp -a "$0/bag" %s 2>/dev/null; exit $rc' % (DISK_BYTES, _quote(str(kept))))
        cmd = ['unshare', '--mount', '--propagation', 'private', 'sh', '-c', script, str(mnt),
               *enbarr_command('bringup', '--profile', str(self.plan.path), '--record',
                               str(mnt / 'bag'))]
        obs = Observer()
        tree = Tree(cmd, self.out / 'disk.log')
        rss: list[float] = []
        rc: int | None = None
        try:
            try:
                tree.wait_group('recorder', STARTUP_TIMEOUT)
                if not obs.wait_busy(STARTUP_TIMEOUT):
                    raise EnbarrError('control never drove the actuators')
            except EnbarrError as err:
                return Verdict(name, KEEPS_CONTROL, False, None, str(err))
            rec = tree.group_pid('recorder')
            filled = _fill(Path(f'/proc/{tree.proc.pid}/root') / mnt.relative_to('/'))
            start = time.time_ns()
            while time.time_ns() - start < max(10.0, 3 * self.window) * 1e9:
                mb = _rss_mb(rec) if rec is not None else None
                if mb is not None and time.time_ns() - start >= RSS_SETTLE_S * 1e9:
                    rss.append(mb)
                time.sleep(0.5)
            end = time.time_ns()
            found = re.search(r'chaos: bringup pid (\d+)', tree.text)
            if found:
                os.kill(int(found.group(1)), signal.SIGINT)
            try:
                rc = tree.proc.wait(60.0)
            except subprocess.TimeoutExpired:
                rc = None
            tree.reap_children()
        finally:
            if tree.proc.poll() is None:
                tree.stop(signal.SIGKILL)
            obs.close()
            self.outputs.append(tree.text)
        growth = (max(rss) - min(rss)) if rss else 0.0
        v = judge.judge_kept(name, list(obs.control), list(obs.actuators), start, end,
                             figures={'filled_bytes': filled, 'exit_code': rc,
                                      'recorder_rss_growth_mb': round(growth, 1)})
        problems = [] if v.passed else [v.detail]
        if rc is None or rc == 0:
            problems.append(f'bringup exited {rc} after the disk filled (want non-zero)')
        if growth > RSS_GROWTH_LIMIT_MB:
            problems.append(f'recorder memory grew {growth:.0f} MB in '
                            f'{(end - start) * 1e-9:.0f} s (> {RSS_GROWTH_LIMIT_MB:.0f})')
        if not _bag_readable(kept):
            problems.append('bag unreadable')
        detail = '; '.join(problems) or f'{v.detail}; exit {rc}'
        return Verdict(name, KEEPS_CONTROL, not problems, None, detail, v.figures)


def _fill(directory: Path) -> int:
    """Fill the file system of ``directory`` (one file, until ENOSPC); bytes written."""
    written = 0
    chunk = b'\0' * (1 << 20)
    with open(directory / 'chaos_filler', 'wb', buffering=0) as f:
        while True:
            try:
                written += f.write(chunk)
            except OSError:
                break
    return written


def enbarr_command(*args: str) -> list[str]:
    """``enbarr ARGS`` in this interpreter."""
    return [sys.executable, '-m', 'enbarr_core.bringup.cli', *args]


def _quote(s: str) -> str:
    return "'" + s.replace("'", "'\\''") + "'"


def _result(future: Any, timeout: float) -> Any | None:
    deadline = time.monotonic() + timeout
    while not future.done() and time.monotonic() < deadline:
        time.sleep(0.02)
    return future.result() if future.done() else None


def _bag_readable(path: Path) -> bool:
    from enbarr_core.recording.bag import read_bag
    try:
        return bool(read_bag(path))
    except Exception:  # noqa: BLE001 - any reader failure means unreadable
        return False


def _last_actuator_output(path: Path) -> list[float] | None:
    from enbarr_core.recording.bag import read_bag
    try:
        bag = read_bag(path)
    except Exception:  # noqa: BLE001 - an unreadable bag is judged elsewhere
        return None
    for topic in ('/' + t for t in Observer.ACTUATOR_TOPICS):
        if bag.get(topic):
            return [float(e) for e in bag[topic][-1][1].effort]
    return None


def main(args: argparse.Namespace) -> int:
    """Run the chaos profile, print the JSON line; 1 when anything was unsafe."""
    if not args.duration > 0:
        raise EnbarrError(f'--duration must be positive, got {args.duration}')
    unknown = [f for f in args.faults.split(',') if f.strip() and f.strip() not in KINDS
               and ':' not in f and f.strip() != 'params']
    if unknown:
        raise EnbarrError(f'--faults: unknown {", ".join(unknown)}; kinds: {", ".join(KINDS)} '
                          '(or a fault name such as future+20s:imu/data_raw)')
    if args.out:
        out = Path(args.out)
        if out.exists():
            raise EnbarrError(f'--out {out}: exists; chaos never overwrites a run')
        out.mkdir(parents=True)
    else:
        out = Path(tempfile.mkdtemp(prefix='enbarr_chaos_'))
    try:
        result = Chaos(args, out).run()
    finally:
        if not args.out:
            shutil.rmtree(out, ignore_errors=True)
    print(json.dumps(result), flush=True)
    return 0 if judge.run_passed(result) else 1


def known_kinds() -> Sequence[str]:
    """Return the fault kinds ``--faults`` accepts (besides single fault names)."""
    return KINDS


def register(sub: Any) -> None:
    """Add the ``chaos`` subcommand to the ``enbarr`` parser's subparsers ``sub``."""
    p = sub.add_parser('chaos', help='run a profile while injecting faults (prints JSON)',
                       description='Run PROFILE split into process groups under bringup, '
                       'inject faults in turn (bad stamps, competing publishers, a '
                       'parameter storm, stopped and killed groups, a full disk, a killed '
                       'supervisor), judge each and print one JSON line.')
    add_arguments(p)
    p.set_defaults(func=lambda args, argv: main(args))
