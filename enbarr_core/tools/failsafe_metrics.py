"""The time from an event to the safe state, from a recorded ROV run with failsafes.

Reported when the profile has a ``failsafe`` node and the bag records ``/failsafe/action``
and an action other than ``none`` and ``warn`` was published. Times are simulated seconds on
the bag's record times (every node of a scenario runs on the runner's clock):

- ``failsafe_event_s``: when the event happened, from the start of the run: the first
  ``/leak`` true for a leak; the first ``/battery`` voltage below the tripped failsafe's
  threshold for a battery failsafe; the last ``/surface_command/twist`` for a lost pilot
  input or link; otherwise the trip itself (``/failsafe/active``). The failsafe is the one
  whose action acted (a battery's critical, not its earlier low warning).
- ``failsafe_action_s``: from the event to the acting action on ``/failsafe/action``.
- ``failsafe_safe_s``: from the event to the safe state of that action: for ``surface``, the
  vehicle rising (``/sim/odometry``, over ``SPEED_SPAN``) at ``SAFE_CLIMB_FRACTION`` of the
  velocity loop's ``failsafe.climb_rate`` or more; for ``neutral``, the first all-zero
  ``/force_command`` after the action.
- ``failsafe_surfaced``: whether the vehicle ends the run within ``SURFACE_DEPTH`` of the
  surface (a ``surface`` action only).
"""

from __future__ import annotations

from typing import Any

import numpy as np

FAILSAFE_TOPICS = ('/failsafe/action', '/failsafe/active', '/leak', '/battery',
                   '/surface_command/twist', '/sim/odometry', '/force_command')
FAILSAFE_FIGURES = ('failsafe_event_s', 'failsafe_action_s', 'failsafe_safe_s')
#: The yes/no figures.
FAILSAFE_FLAGS = ('failsafe_surfaced',)
SAFE_CLIMB_FRACTION = 0.8
SPEED_SPAN = 0.5       # [s] the climb rate is the rise over this span
SURFACE_DEPTH = 0.1    # [m] at the surface this close (ArduSub's SURFACE_DEPTH: 10 cm)
_QUIET = ('none', 'warn', '')

Messages = dict[str, list[tuple[int, Any]]]


def _node(profile: Any, plugin: str) -> Any | None:
    return next((n for n in profile.nodes if n.plugin == plugin), None)


def has_failsafes(profile: Any) -> bool:
    """Whether the profile runs the failsafe node."""
    return _node(profile, 'failsafe') is not None


def _param(profile: Any, plugin: str, name: str, default: Any) -> Any:
    node = _node(profile, plugin)
    if node is None:
        return default
    return {**profile.parameters, **node.parameters}.get(name, default)


def failsafe_figures(msgs: Messages, profile: Any, t0_ns: int) -> dict[str, Any]:
    """Return the figures (module docstring); empty when no failsafe acted."""
    from enbarr_core.control.failsafe_node import DEFAULTS
    actions = [(t, m.data) for t, m in msgs.get('/failsafe/action', [])]
    acting = next(((t, a) for t, a in actions if a not in _QUIET), None)
    if acting is None:
        return {}
    t_action, action = acting
    # The failsafe that asked for the action: on /failsafe/active as 'name: action since ...'
    # entries joined by '; ' (control.failsafes.describe), the first with that action.
    name, t_event = '', t_action
    for t, m in msgs.get('/failsafe/active', []):
        entries = [e.split(': ', 1) for e in m.data.split('; ') if ': ' in e]
        found = next((n for n, rest in entries if rest.startswith(action + ' ')), None)
        if found is not None:
            name, t_event = found, t
            break
    if name == 'leak':
        t_event = next((t for t, m in msgs.get('/leak', []) if m.data), t_event)
    elif name.startswith('battery'):
        limit = _param(profile, 'failsafe', f'{name}.voltage', DEFAULTS[name][1])
        t_event = next((t for t, m in msgs.get('/battery', []) if m.voltage < limit), t_event)
    elif name in ('pilot_input', 'surface_link'):
        t_event = max((t for t, _ in msgs.get('/surface_command/twist', []) if t <= t_action),
                      default=t_event)
    out: dict[str, Any] = {'failsafe': name, 'failsafe_acting': action,
                           'failsafe_event_s': round((t_event - t0_ns) * 1e-9, 3),
                           'failsafe_action_s': round((t_action - t_event) * 1e-9, 3)}
    t_safe: float | None = None
    if action == 'surface':
        climb = _param(profile, 'velocity_control', 'failsafe.climb_rate', 0.25)
        odo = msgs.get('/sim/odometry', [])
        t = np.array([tm for tm, _ in odo], dtype=float)
        z = np.array([m.pose.pose.position.z for _, m in odo])
        span = int(np.searchsorted(t, t[0] + SPEED_SPAN * 1e9)) if len(t) else 0
        for i in range(span, len(t)):
            if t[i] < t_action:
                continue
            rate = (z[i] - z[i - span]) / ((t[i] - t[i - span]) * 1e-9)
            if rate >= SAFE_CLIMB_FRACTION * climb:
                t_safe = float(t[i])
                break
        out['failsafe_surfaced'] = bool(len(z) and -z[-1] <= SURFACE_DEPTH)
    elif action == 'neutral':
        t_safe = next((t for t, m in msgs.get('/force_command', []) if t >= t_action and not any(
            (m.wrench.force.x, m.wrench.force.y, m.wrench.force.z, m.wrench.torque.x,
             m.wrench.torque.y, m.wrench.torque.z))), None)
    out['failsafe_safe_s'] = (round((t_safe - t_event) * 1e-9, 3) if t_safe is not None
                              else None)   # never safe: fails any target
    return out
