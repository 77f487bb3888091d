"""Where an allocation node hears of failed thrusters, and how it reports them.

Both allocation nodes (``thruster_converter_node``, ``azimuth_allocation_node``) take failures
from two places (the entries and the diagnostics convention are ``failures``'):

- the operator: the parameter ``failed_thrusters`` (a string array, settable live with
  ``ros2 param set`` or ``enbarr param set``); a bad entry is refused naming it;
- ``/diagnostics``: a ``DiagnosticStatus`` at ERROR whose ``values`` carry the key
  ``failed_thruster`` (a fault detector, such as one comparing commanded thrust with feedback).

Every change re-solves the allocation once (``set_failures``), is logged once, and is reported
in the node's own status: DEGRADED naming the thrusters out and the DOFs lost, ERROR when no
controlled DOF is left.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

from diagnostic_msgs.msg import DiagnosticArray

from enbarr_interfaces import topics

from enbarr_core.allocation.failures import Failure, FailureBook, parse_entries
from enbarr_core.framework.health import DEGRADED, ERROR, OK
from enbarr_core.framework.node import EnbarrNode
from enbarr_core.framework.params import ParamSpec

FAILED_THRUSTERS = 'failed_thrusters'


def failed_thrusters_spec(allow_stuck: bool) -> ParamSpec:
    """Return the ``failed_thrusters`` spec (azimuths also take ``name:stuck:<deg>``)."""
    forms = 'name or name:dead' + (', name:stuck:<deg> for a servo stuck at <deg>'
                                   if allow_stuck else '')
    return ParamSpec(FAILED_THRUSTERS, [''], f'Thrusters out of the allocation ({forms}); '
                     "[''] for none", element=str)


class FailureAware(Protocol):
    """What ``FailureInput`` needs of an allocator (both allocators have it)."""

    @property
    def failed(self) -> dict[str, Failure]:
        """The failed thrusters and how."""

    @property
    def lost_dofs(self) -> tuple[str, ...]:
        """The DOFs the thrusters left cannot produce."""

    def set_failures(self, failures: dict[str, Failure]) -> None:
        """Run with exactly these thrusters failed."""


class FailureInput:
    """The failed thrusters of one allocation node: its parameter, ``/diagnostics``, status.

    ``dofs`` are the DOFs the node controls (all lost means the node can do nothing).
    """

    def __init__(self, node: EnbarrNode, allocator: FailureAware, known: tuple[str, ...],
                 allow_stuck: bool, dofs: tuple[str, ...]) -> None:
        self.node = node
        self.allocator = allocator
        self.dofs = dofs
        self.book = FailureBook(known, allow_stuck)
        self._warned: set[str] = set()
        node.bind_settings([failed_thrusters_spec(allow_stuck)],
                           lambda v: self._parse(v[FAILED_THRUSTERS]), self._set_operator)
        node.create_topic_subscription(topics.DIAGNOSTICS, self._on_diagnostics)

    def _parse(self, entries: list[str]) -> dict[str, Failure]:
        try:
            return parse_entries(entries, self.book.known, self.book.allow_stuck)
        except ValueError as err:
            raise ValueError(f'{FAILED_THRUSTERS}: {err}') from err

    def _set_operator(self, failures: Mapping[str, Failure]) -> None:
        self.book.set_operator(failures)
        self._apply('parameter failed_thrusters')

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        own = self.node.get_fully_qualified_name()
        changed = False
        for status in msg.status:
            if status.name == own:
                continue
            level = status.level[0] if isinstance(status.level, bytes) else int(status.level)
            before = self.book.sources.get(status.name)
            for problem in self.book.report(status.name, level,
                                            [(kv.key, kv.value) for kv in status.values]):
                if problem not in self._warned:  # a detector repeats itself every period
                    self._warned.add(problem)
                    self.node.get_logger().warn(f'/diagnostics: ignored {problem}')
            changed |= self.book.sources.get(status.name) != before
        if changed:
            self._apply('/diagnostics')

    def _apply(self, why: str) -> None:
        merged = self.book.merged()
        if merged == self.allocator.failed:
            return
        self.allocator.set_failures(merged)
        log = self.node.get_logger()
        if merged:
            log.warn(f'{self.summary()} (from {why})')
        else:
            log.info(f'every thruster back in the allocation (from {why})')

    def summary(self) -> str:
        """'thrusters out: a:dead, b:stuck:30; lost: sway, yaw' (or 'lost: none')."""
        failed = self.allocator.failed
        out = ', '.join(f.entry(n) for n, f in failed.items())
        lost = ', '.join(self.allocator.lost_dofs) or 'none'
        return f'thrusters out: {out}; lost: {lost}'

    def status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, values) for the node's ``/diagnostics``.

        The keys are ``thrusters_out`` and ``lost_dofs`` (comma-separated), never
        ``failed_thruster``: this report must not read back as a failure.
        """
        failed = self.allocator.failed
        lost = self.allocator.lost_dofs
        values = {'thrusters_out': ','.join(f.entry(n) for n, f in failed.items()),
                  'lost_dofs': ','.join(lost)}
        if not failed:
            return OK, 'ok', values
        level = ERROR if set(lost) >= set(self.dofs) else DEGRADED
        return level, self.summary(), values
