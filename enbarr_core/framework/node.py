"""The base class of every Enbarr node.

An ``EnbarrNode`` is an ordinary rclpy ``Node`` (``__init__(node_name, **kwargs)`` passes
``context``, ``namespace``, ``parameter_overrides``, ``cli_args`` ... through) with four
additions that bringup relies on:

- ``create_topic_publisher`` / ``create_topic_subscription``: a topic of the contract
  (``enbarr_interfaces.topics``); the contract's ``TopicSpec.fast`` decides whether it travels
  over the in-process ``LinkBus`` (``enbarr_interfaces.links``) or as an ordinary ROS topic;
- ``bind_settings``: declared, validated, live-tunable parameters (``framework.params``);
- ``create_rate_loop``: a periodic source on its own thread, for drivers and simulators whose
  rate matters more than an executor timer can give (``docs/architecture.md``);
- ``create_periodic``: supervision (watchdogs, ``/diagnostics`` reports) on the process's one
  ``Ticker`` timer instead of an executor timer per node and period;
- ``start`` / ``stop`` / ``safe_state``: bringup starts sources once the graph is wired,
  stops them first on every exit path, then asks every node to put its actuators in their
  safe state (thrusters neutral) before anything is destroyed;
- ``frame_tree``: the profile's frame tree (``framework.frames``), where every sensor sits.
  Bringup installs it per process (``install_frame_tree``) before it builds the nodes, so every
  group of a split profile has it; a node built alone (a test) gets ``DEFAULT_TREE`` unless
  its test installs one.
- ``world`` and ``world_time``: the profile's simulated world (``enbarr_core.world``), which
  simulated sensors and emulators measure, installed the same way (``install_world``, an
  empty world unless installed), and the world time of a stamp: seconds since the world's
  epoch (bringup: when the process composed its nodes; a scenario: when it began).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
import threading
import time
from typing import Any, TypeVar

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.subscription import Subscription
from rclpy.timer import Timer

from enbarr_interfaces import convert, topics
from enbarr_interfaces.links import (Callback, LinkBus, LinkPublisher, LinkSubscription,
                                      PerContext)
from enbarr_interfaces.topics import TopicSpec

from enbarr_core.framework.frames import DEFAULT_TREE, FrameTree
from enbarr_core.framework.health import InputHealth
from enbarr_core.framework.params import ParamSpec, SettingsBinding
from enbarr_core.framework.stamps import StampGate, StampVerdict
from enbarr_core.world.model import EMPTY_WORLD, World

S = TypeVar('S')

#: Period of actuator watchdogs and other supervision timers [s] (``framework.driver``). Every
#: executor wake-up costs CPU in rclpy whatever the callback does (``docs/benchmarks.md``),
#: so supervision runs at 10 Hz: a command timeout of 0.25 s trips within 0.35 s.
WATCHDOG_PERIOD = 0.1
#: The period of a process's ``Ticker`` [s]; every ``create_periodic`` period is a multiple.
TICK = WATCHDOG_PERIOD


class Periodic:
    """One node's periodic check on its process's ``Ticker`` (``EnbarrNode.create_periodic``)."""

    def __init__(self, node: Node, ticks: int, callback: Callable[[], None], start: int) -> None:
        self.node = node
        self.ticks = ticks
        self.callback = callback
        self.start = start
        self.errors = 0
        self.cancelled = False

    @property
    def period(self) -> float:
        """Return the period [s]."""
        return self.ticks * TICK

    def cancel(self) -> None:
        """Stop calling it."""
        self.cancelled = True


class Ticker(PerContext):
    """One executor timer per rclpy ``Context`` that runs every node's periodic checks.

    Why: each executor wake-up costs more CPU than a watchdog's own work, so in an idle process a
    timer per check spends most of the CPU on waking up (``docs/benchmarks.md``, costs behind
    choices in the code). So the checks of all nodes of a process share one timer at ``TICK``; a
    check of period P runs every P / TICK ticks, in registration order. The timer lives on one of
    the registered nodes (its clock: simulated time in scenarios) and moves to another when that
    node is destroyed. A check that raises is logged and counted and the others still run: one
    node's faulty report must not silence another's watchdog.
    """

    def __init__(self) -> None:
        self._entries: tuple[Periodic, ...] = ()
        self._host: Node | None = None
        self._timer: Any = None
        self.count = 0

    @property
    def host(self) -> Node | None:
        """Return the node whose timer drives the ticker (None: no check registered)."""
        return self._host

    def add(self, node: Node, period: float, callback: Callable[[], None]) -> Periodic:
        """Call ``callback`` every ``period`` [s], a whole multiple of ``TICK``."""
        ticks = round(period / TICK)
        if ticks < 1 or abs(ticks * TICK - period) > 1e-9 * max(1.0, period):
            raise ValueError(f'periodic check period {period} s is not a whole multiple of '
                             f'the {TICK} s tick')
        entry = Periodic(node, ticks, callback, self.count)
        self._entries = (*self._entries, entry)
        if self._timer is None:
            self._host_on(node)
        return entry

    def remove_node(self, node: Node) -> None:
        """Drop ``node``'s checks; move the timer off it when it hosts it."""
        self._entries = tuple(e for e in self._entries if e.node is not node)
        if self._host is node:
            node.destroy_timer(self._timer)
            self._timer = self._host = None
            if self._entries:
                self._host_on(self._entries[0].node)

    def _host_on(self, node: Node) -> None:
        self._host = node
        self._timer = node.create_timer(TICK, self.tick)

    def tick(self) -> None:
        """Run the checks due at this tick (the timer's callback)."""
        self.count += 1
        for e in self._entries:
            if e.cancelled or (self.count - e.start) % e.ticks:
                continue
            try:
                e.callback()
            except Exception as err:  # noqa: BLE001 - see the class doc
                e.errors += 1
                e.node.get_logger().error(
                    f'periodic check {getattr(e.callback, "__name__", e.callback)} failed '
                    f'({e.errors} so far): {err!r}', throttle_duration_sec=5.0)


class FrameTreeOf(PerContext):
    """The frame tree of one process (rclpy ``Context``): the profile's, once installed."""

    def __init__(self) -> None:
        self.tree: FrameTree = DEFAULT_TREE


def install_frame_tree(context: Any, tree: FrameTree) -> None:
    """Give the nodes of ``context`` the frame tree ``tree`` (bringup: the profile's)."""
    FrameTreeOf.of(context).tree = tree


class WorldOf(PerContext):
    """The simulated world of one process (rclpy ``Context``) and its epoch."""

    def __init__(self) -> None:
        self.world: World = EMPTY_WORLD
        self.epoch_ns = 0  # the clock time [ns] at which the world time is 0


def install_world(context: Any, world: World, epoch_ns: int = 0) -> None:
    """Give the nodes of ``context`` the world ``world`` (bringup: the profile's).

    Its time 0 is the node clocks' time ``epoch_ns`` [ns].
    """
    held = WorldOf.of(context)
    held.world, held.epoch_ns = world, int(epoch_ns)


class RateLoop:
    """Calls ``callback()`` every ``1/rate_hz`` seconds on a dedicated thread.

    Deadlines are absolute (no drift); when a call overruns by more than a period the missed
    ticks are skipped and counted, never bunched. An exception in ``callback`` is logged and
    counted, and the loop goes on: a driver that fails one read must not stop its node.
    """

    def __init__(self, node: Node, rate_hz: float, callback: Callable[[], None],
                 name: str) -> None:
        if not rate_hz > 0.0:
            raise ValueError(f'rate must be positive, got {rate_hz}')
        self.node = node
        self.period = 1.0 / rate_hz
        self.callback = callback
        self.name = name
        self.ticks = 0
        self.overruns = 0
        self.errors = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        """Whether the loop thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        """Start the loop thread (a no-op when it runs)."""
        if self.running:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the loop and wait up to ``timeout`` [s] for its thread."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout)

    def _run(self) -> None:
        deadline = time.monotonic()
        while not self._stop.is_set():
            try:
                self.callback()
            except Exception as err:  # noqa: BLE001 - keep the loop alive, see class doc
                self.errors += 1
                self.node.get_logger().error(
                    f'{self.name}: {err!r} ({self.errors} errors so far)',
                    throttle_duration_sec=1.0)
            self.ticks += 1
            deadline += self.period
            delay = deadline - time.monotonic()
            if delay < -self.period:
                skipped = int(-delay / self.period)
                self.overruns += skipped
                deadline += skipped * self.period
                delay = deadline - time.monotonic()
            if delay > 0.0:
                self._stop.wait(delay)


def sim_steps(time_ns: int, now_ns: int, period_ns: int,
              max_steps: int) -> tuple[int, float, bool]:
    """How a real-time simulator reaches ``now_ns`` from ``time_ns``: (steps, dt [s], skipped).

    The span is cut into round(span / period) equal steps (at least one), so the simulated
    state is exactly at the clock's present when it is published: its stamp is the time of
    the truth it carries, and a sensor sample is not older than the tick that produced it.
    A span longer than ``max_steps`` periods is cut to that (``skipped``: time was lost).
    Driven by simulated time (``enbarr scenario``) every span is exactly one period.
    """
    span = now_ns - time_ns
    if span <= 0:
        return 0, 0.0, False
    skipped = span > max_steps * period_ns
    if skipped:
        span = max_steps * period_ns
    n = max(1, round(span / period_ns))
    return n, span * 1e-9 / n, skipped


class LatencyLog:
    """Ring buffer of sensor-stamp -> actuator latencies [ns], kept by actuator plugins.

    ``enbarr bench`` (and a curious user) reads there what the chain really costs.
    """

    def __init__(self, size: int = 4096) -> None:
        self.samples = np.zeros(size, dtype=np.int64)
        self.count = 0

    def add(self, latency_ns: int) -> None:
        """Record one latency [ns]."""
        self.samples[self.count % len(self.samples)] = latency_ns
        self.count += 1

    def last(self, n: int) -> np.ndarray:
        """Return the newest ``n`` samples (at most the buffer size) [ns]."""
        n = min(n, self.count, len(self.samples))
        return self.samples[np.arange(self.count - n, self.count) % len(self.samples)]


def _construct(init: Callable[..., None]) -> Callable[..., None]:
    """Wrap a node class's ``__init__``: when the construction raises, destroy the node.

    A node refused at construction (a parameter missing or out of range: the usual user
    mistake) has already joined the ROS graph as an rcl node. Nothing else will destroy it:
    the caller never gets the object, and the traceback of the error (kept by whoever handles
    it, a test's ``pytest.raises`` among them) keeps it alive, so its name stayed on the graph
    answering nothing, and a later run in the same domain met it. Only the outermost
    ``__init__`` of the class chain cleans up, and with the base's ``destroy_node`` (the
    subclass's own may need what its construction never made).
    """
    def guarded(self: EnbarrNode, *args: Any, **kwargs: Any) -> None:
        outer = not self.__dict__.get('_constructing', False)
        self.__dict__['_constructing'] = True
        try:
            init(self, *args, **kwargs)
        except BaseException:
            if outer and '_bus' in self.__dict__:   # EnbarrNode.__init__ made the rcl node
                try:
                    EnbarrNode.destroy_node(self)
                except Exception:  # noqa: BLE001 - the construction's error is the one to see
                    try:   # the base's own state half made: the rcl node at least
                        Node.destroy_node(self)
                    except Exception:  # noqa: BLE001 - as above
                        pass
            raise
        finally:
            if outer:
                self.__dict__['_constructing'] = False

    guarded.__wrapped__ = init  # type: ignore[attr-defined]
    guarded.__name__, guarded.__qualname__, guarded.__doc__ = (
        init.__name__, init.__qualname__, init.__doc__)
    return guarded


class EnbarrNode(Node):
    """Base of core and plugin nodes; see the module docstring."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Make a node whose construction fails leave the ROS graph (:meth:`_construct`)."""
        super().__init_subclass__(**kwargs)
        if '__init__' in cls.__dict__:
            cls.__init__ = _construct(cls.__dict__['__init__'])  # type: ignore[method-assign]

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._bus = LinkBus.of(self.context)
        self._clock_handle = self.get_clock().handle
        self._links: list[LinkPublisher | LinkSubscription] = []
        self._loops: list[RateLoop] = []
        self._source_timers: list[Timer] = []
        self._diagnostics_pub: Publisher | None = None
        self._started = False
        self._problems: list[str] = []

    def now_ns(self) -> int:
        """Return the node clock's present [ns]: ``get_clock().now().nanoseconds``, cheaper.

        The same clock (ROS time, simulated time when overridden) read without building an
        ``rclpy.time.Time`` (far cheaper: ``docs/benchmarks.md``), several times per
        sample in the chain.
        The clock's handle lives as long as this node holds it (rclpy never destroys a node's
        clock), so it is read without the handle's guard.
        """
        return self._clock_handle.get_now().nanoseconds

    def admit_stamp(self, name: str, stamp: Time, gate: StampGate,
                    health: InputHealth) -> int | None:
        """Pass one sample of input ``name`` through its ``gate`` (``framework.stamps``).

        Return the stamp [ns] when the gate accepts it, counted in ``health`` as accepted;
        else None, counted in ``health`` under the verdict and warned in the log. The warning
        is throttled to one a second per node (rclpy throttles per call site), so a node
        that admits several inputs here shares that one warning a second between them.
        """
        t = convert.stamp_to_ns(stamp)
        verdict = gate.offer(t, self.now_ns())
        if verdict is not StampVerdict.ACCEPTED:
            health.refused(name, verdict.value)
            self.get_logger().warn(f'{name} refused ({verdict.value})',
                                   throttle_duration_sec=1.0)
            return None
        health.accepted(name)
        return t

    # -- topics -----------------------------------------------------------------------------
    def create_topic_publisher(self, spec: TopicSpec) -> LinkPublisher | Publisher:
        """Create a publisher of a contract topic: link bus when ``spec.fast``, else ROS."""
        if not spec.fast:
            return self.create_publisher(spec.msg_type, spec.name, spec.qos)
        pub = self._bus.create_publisher(self, spec)
        self._links.append(pub)
        return pub

    def create_topic_subscription(self, spec: TopicSpec,
                                  callback: Callback) -> LinkSubscription | Subscription:
        """Subscription to a contract topic: over the link bus when ``spec.fast``, else ROS."""
        if not spec.fast:
            return self.create_subscription(spec.msg_type, spec.name, callback, spec.qos)
        sub = self._bus.create_subscription(self, spec, callback)
        self._links.append(sub)
        return sub

    @property
    def link_bus(self) -> LinkBus:
        """Return the in-process link bus of this node's context."""
        return self._bus

    @property
    def frame_tree(self) -> FrameTree:
        """Return the profile's frame tree: ``self.frame_tree.lookup('base_link', 'laser')``."""
        return FrameTreeOf.of(self.context).tree

    @property
    def world(self) -> World:
        """Return the profile's simulated world (``enbarr_core.world``; empty if none)."""
        return WorldOf.of(self.context).world

    def world_time(self, stamp_ns: int | None = None) -> float:
        """Return the world time [s] of a clock time ``stamp_ns`` (None: now)."""
        t = self.now_ns() if stamp_ns is None else stamp_ns
        return (t - WorldOf.of(self.context).epoch_ns) * 1e-9

    # -- parameters -------------------------------------------------------------------------
    def bind_settings(self, specs: Sequence[ParamSpec], build: Callable[[dict[str, Any]], S],
                      apply: Callable[[S], None]) -> SettingsBinding[S]:
        """Declare ``specs``; bind them to the settings ``build`` makes (see params)."""
        return SettingsBinding(self, specs, build, apply)

    # -- sources and lifecycle --------------------------------------------------------------
    def create_rate_loop(self, rate_hz: float, callback: Callable[[], None]) -> RateLoop:
        """Call ``callback`` at ``rate_hz`` on its own thread once started."""
        loop = RateLoop(self, rate_hz, callback, f'{self.get_name()}_loop')
        self._loops.append(loop)
        if self._started:
            loop.start()
        return loop

    def create_source_timer(self, period: float, callback: Callable[[], None]) -> Timer:
        """Call ``callback`` every ``period`` [s] on the executor thread between start and stop.

        For sources paced by the node's clock (a scripted operator, a joystick stand-in):
        nothing goes out before bringup has checked the graph or once the safe state is being
        put in place, and a node that is not started costs no executor wake-up (each costs CPU
        in rclpy's ``EventsExecutor`` whatever the callback does: ``docs/benchmarks.md``).
        """
        timer = self.create_timer(period, callback, autostart=self._started)
        self._source_timers.append(timer)
        return timer

    def create_periodic(self, period: float, callback: Callable[[], None]) -> Periodic:
        """Call ``callback`` every ``period`` [s] on the process's ``Ticker`` (executor thread).

        For supervision: watchdogs, ``/diagnostics`` reports. ``period`` is a whole multiple
        of ``TICK``; the first call comes one period after this one.
        """
        return Ticker.of(self.context).add(self, period, callback)

    @property
    def rate_loops(self) -> tuple[RateLoop, ...]:
        """The rate loops of this node, in creation order (read only: a copy of the list)."""
        return tuple(self._loops)

    @property
    def started(self) -> bool:
        """Whether the node's sources run: between ``start`` and ``stop``.

        A driver whose own thread publishes samples (not a ``RateLoop``) publishes only
        then: nothing goes out before bringup has checked the graph, and nothing drives the
        chain once the safe state is being put in place.
        """
        return self._started

    def start(self) -> None:
        """Start the node's sources. Called by bringup after every node exists and is wired."""
        self._started = True
        for timer in self._source_timers:
            timer.reset()
        for loop in self._loops:
            loop.start()

    def stop(self) -> None:
        """Stop the node's sources (bringup calls it on every node before ``safe_state``)."""
        self._started = False
        for timer in self._source_timers:
            timer.cancel()
        for loop in self._loops:
            loop.stop()

    def safe_state(self) -> None:
        """Put this node's actuators in their safe state. Nodes with actuators override it."""

    def report_problem(self, message: str) -> None:
        """Record a fault that must fail the run (``bringup`` exits non-zero naming it).

        For faults the vehicle survives but the user must hear about at the end, such as a
        recorder that could not write its bag. Logged once per distinct message.
        """
        if message not in self._problems:
            self._problems.append(message)
            self.get_logger().error(message)

    @property
    def problems(self) -> tuple[str, ...]:
        """The faults reported with ``report_problem``, oldest first."""
        return tuple(self._problems)

    def publish_diagnostics(self, level: int, message: str,
                            values: Mapping[str, Any] | Sequence[tuple[str, Any]]) -> None:
        """Publish this node's status on ``/diagnostics`` (counters, modes, faults).

        ``values``: a mapping, or (key, value) pairs where a key may repeat (one
        ``failed_thruster`` per failed thruster, ``allocation.failures``).
        """
        pairs = values.items() if isinstance(values, Mapping) else values
        if self._diagnostics_pub is None:
            self._diagnostics_pub = self.create_publisher(
                DiagnosticArray, topics.DIAGNOSTICS.name, topics.DIAGNOSTICS.qos,
                event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
        status = DiagnosticStatus(
            level=bytes([level]), name=self.get_fully_qualified_name(), message=message,
            hardware_id=self.get_name(),
            values=[KeyValue(key=k, value=str(v)) for k, v in pairs])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics_pub.publish(msg)

    def destroy_node(self) -> None:
        """Stop the sources, drop the links, then destroy the node."""
        self.stop()
        Ticker.of(self.context).remove_node(self)
        for link in self._links:
            link.destroy()
        self._links.clear()
        # mypy's untyped_calls_exclude (mypy.ini) cannot name a call through super().
        super().destroy_node()  # type: ignore[no-untyped-call]  # rclpy 7.1: unannotated
