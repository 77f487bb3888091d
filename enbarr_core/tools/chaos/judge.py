"""Judging a chaos run (``enbarr chaos``): what each fault's safe outcome is, measured.

Pure: observations in, verdicts out (no rclpy), so the rules are tested on synthetic
observations. Times are wall-clock nanoseconds (``time.time_ns()``, the clock the nodes
stamp their outputs with in a real-time run).

Two kinds of fault, two safe outcomes:

- A fault that removes control (a group SIGKILLed or SIGSTOPped, the supervisor SIGKILLed):
  the actuators reach their safe state (every thruster output 0, or the azimuths' thrust 0
  at the calibrated neutral duty) within ``SAFE_WITHIN_S`` of the fault. ``time_to_neutral``
  measures it from the actuator output's own stamps.
- A bad input that must cost at most itself (future or past stamps, a competing publisher, a
  parameter storm, a full disk): control is not disrupted. Over ``window`` after the fault
  the control output (``thruster_commands`` / ``pwm/duty_cycle``) never pauses longer than
  ``CONTROL_GAP_S`` (the thruster plugin's command timeout), the actuators are never put
  neutral meanwhile, and nothing the bad input carried was executed (counted by the runner:
  an intruder's command reaching the goal, an invalid parameter value accepted, ...).
  On an operator command topic (``surface_command/*``, ``joy``) any injection is a second
  publisher, which the single-source rule answers by refusing both: there the safe state is
  allowed, and only executing the injected command fails.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

#: A fault that removes control must end with the actuators neutral within this [s].
SAFE_WITHIN_S = 0.5
#: Longest pause of the control output that is not a disruption [s]: the default
#: ``command_timeout`` of an actuator driver (``framework.driver``), beyond which it goes
#: neutral by itself.
CONTROL_GAP_S = 0.25

REMOVES_CONTROL = 'actuators neutral within 0.5 s'
KEEPS_CONTROL = 'control not disrupted'


@dataclass(frozen=True)
class Verdict:
    """The judged outcome of one injected fault."""

    fault: str                      # e.g. 'future+20s:imu/data_raw', 'sigkill:control'
    expected: str                   # REMOVES_CONTROL or KEEPS_CONTROL
    passed: bool
    time_to_safe_s: float | None    # removal faults: fault -> actuators neutral (time_to_neutral)
    detail: str = ''
    figures: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """Return the verdict as a JSON-ready dict (times rounded to the millisecond)."""
        out = asdict(self)
        if self.time_to_safe_s is not None:
            out['time_to_safe_s'] = round(self.time_to_safe_s, 3)
        return out


def time_to_neutral(outputs: Iterable[tuple[int, bool]], fault_ns: int) -> float | None:
    """Seconds from ``fault_ns`` until the actuators are neutral; None when they never were.

    ``outputs`` are ``(stamp ns, neutral)`` pairs. 0 when the last output before the fault was
    already neutral (a starved control group had put them there: a driver holds its last
    output, so they stay neutral until a new output says otherwise); else the first neutral
    output stamped at or after the fault.
    """
    outputs = sorted(outputs)
    before = [neutral for t, neutral in outputs if t < fault_ns]
    if before and before[-1]:
        return 0.0
    after = [t for t, neutral in outputs if neutral and t >= fault_ns]
    return (min(after) - fault_ns) * 1e-9 if after else None


def max_gap(times: Iterable[int], start_ns: int, end_ns: int) -> float:
    """Longest interval [s] in ``start_ns .. end_ns`` without a sample of ``times``.

    The edges count: no sample at all in the window is a gap of the whole window.
    """
    inside = sorted(t for t in times if start_ns <= t <= end_ns)
    edges = [start_ns, *inside, end_ns]
    return max(b - a for a, b in zip(edges, edges[1:])) * 1e-9


def judge_removal(fault: str, outputs: Sequence[tuple[int, bool]], fault_ns: int,
                  *, limit_s: float = SAFE_WITHIN_S, extra: str = '',
                  extra_ok: bool = True, figures: dict[str, Any] | None = None) -> Verdict:
    """Judge a fault that removes control: actuators neutral within ``limit_s``.

    ``extra_ok`` False (with ``extra`` saying why) fails the fault whatever the timing, e.g.
    a bag whose last actuator output is not neutral.
    """
    t = time_to_neutral(outputs, fault_ns)
    if t is None:
        ok, why = False, 'no neutral actuator output after the fault'
    elif t > limit_s:
        ok, why = False, f'neutral after {t:.3f} s (> {limit_s} s)'
    else:
        ok, why = True, f'neutral after {t:.3f} s'
    if not extra_ok:
        ok = False
    detail = '; '.join(x for x in (why, extra) if x)
    return Verdict(fault, REMOVES_CONTROL, ok, t, detail, dict(figures or {}))


def judge_kept(fault: str, control_times: Sequence[int],
               outputs: Sequence[tuple[int, bool]], start_ns: int, end_ns: int,
               *, executed: int = 0, executed_what: str = 'bad inputs executed',
               gap_limit_s: float = CONTROL_GAP_S, allow_neutral: bool = False,
               figures: dict[str, Any] | None = None) -> Verdict:
    """Judge a bad input: control kept over ``start_ns .. end_ns``, nothing of it executed.

    ``control_times`` are receive times of the control output, ``outputs`` the actuator
    outputs ``(stamp ns, neutral)``; ``executed`` counts what the bad input made happen.
    ``allow_neutral``: the safe state is a safe answer too (a command topic with a second
    publisher is contested: refusing every source, hence the operator's command lost, is
    safe; executing the intruder's command is not): then control may pause if the actuators
    were neutral within ``SAFE_WITHIN_S`` of the fault.
    """
    gap = max_gap(control_times, start_ns, end_ns)
    neutral = [t for t, n in outputs if n and start_ns <= t <= end_ns]
    safe_in_time = bool(neutral) and neutral[0] - start_ns <= SAFE_WITHIN_S * 1e9
    problems = []
    if gap > gap_limit_s and not (allow_neutral and safe_in_time):
        problems.append(f'control output paused {gap:.3f} s (> {gap_limit_s} s)'
                        + (' and the actuators were not neutral within '
                           f'{SAFE_WITHIN_S} s' if allow_neutral else ''))
    if neutral and not allow_neutral:
        problems.append(f'actuators put neutral {(neutral[0] - start_ns) * 1e-9:.3f} s '
                        'after the fault')
    if executed:
        problems.append(f'{executed} {executed_what}')
    figs = {'max_control_gap_s': round(gap, 3), **(figures or {})}
    if problems:
        detail = '; '.join(problems)
    elif gap > gap_limit_s:
        detail = f'safe state after {(neutral[0] - start_ns) * 1e-9:.3f} s (contested)'
    else:
        detail = f'control kept (longest pause {gap:.3f} s)'
    return Verdict(fault, KEEPS_CONTROL, not problems, None, detail, figs)


def judge_storm(fault: str, control_times: Sequence[int],
                outputs: Sequence[tuple[int, bool]], start_ns: int, end_ns: int,
                answers: Sequence[tuple[Any, bool | None]], nodes: int) -> Verdict:
    """Judge a parameter storm: control kept, no invalid value accepted, every call answered.

    ``answers`` are ``(call, successful)`` pairs, ``successful`` None for a call that got no
    answer; a call has ``valid`` (the value is the parameter's own) and prints as
    ``node.parameter=value``. A valid value refused is a figure, not a failure: a read-only
    parameter refuses any value.
    """
    accepted_invalid = [str(c) for c, ok in answers if ok and not c.valid]
    unanswered = [str(c) for c, ok in answers if ok is None]
    refused_valid = sum(1 for c, ok in answers if ok is False and c.valid)
    v = judge_kept(fault, control_times, outputs, start_ns, end_ns,
                   executed=len(accepted_invalid),
                   executed_what='invalid values accepted: ' + ', '.join(accepted_invalid[:5]),
                   figures={'nodes': nodes, 'calls': len(answers),
                            'answered': len(answers) - len(unanswered),
                            'valid_refused': refused_valid})
    if not answers:
        return replace(v, passed=False, detail='no parameter to set: no node answered')
    if unanswered:
        what = f'{len(unanswered)} of {len(answers)} calls unanswered: ' + ', '.join(
            unanswered[:5])
        return replace(v, passed=False,
                       detail=what if v.passed else f'{v.detail}; {what}')
    return v


def skipped(fault: str, expected: str, why: str) -> Verdict:
    """Return the verdict of a fault not injected here (listed, not counted as injected)."""
    return Verdict(fault, expected, False, None, f'skipped: {why}', {'skipped': True})


def count_tracebacks(text: str) -> int:
    """Lines that start a Python traceback in a process's output."""
    return sum(1 for line in text.splitlines() if 'Traceback' in line)


def summary(verdicts: Sequence[Verdict], tracebacks: int, bags_readable: int,
            bags: int) -> dict[str, Any]:
    """Return the one JSON line of a chaos run.

    ``safe_within_0_5s`` counts the injected faults that ended safe: neutral within 0.5 s
    for those that remove control, control kept for bad inputs.
    """
    injected = [v for v in verdicts if not v.figures.get('skipped')]
    return {
        'faults_injected': len(injected),
        'safe_within_0_5s': sum(1 for v in injected if v.passed),
        'tracebacks': tracebacks,
        'bags_readable': f'{bags_readable}/{bags}',
        'per_fault': [v.as_dict() for v in verdicts],
    }


def run_passed(result: dict[str, Any]) -> bool:
    """Whether a run's summary is a pass: every fault safe, no traceback, every bag readable.

    A skipped fault does not fail the run (it is listed with its reason).
    """
    readable, _, total = str(result['bags_readable']).partition('/')
    return (result['faults_injected'] == result['safe_within_0_5s']
            and result['tracebacks'] == 0 and readable == total)
