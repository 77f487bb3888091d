"""``enbarr chaos``: the judging rules on synthetic observations (they pass a safe outcome and
fail each unsafe one), the split profile a run is built on, and the command line's refusals.
The real run is in test/e2e/test_chaos.py; the parameter storm against nodes in
test/tools/test_chaos_storm.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from enbarr_core.commands.main import main as enbarr_main
from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import EnbarrError
from enbarr_core.tools.chaos import judge, plan as chaos, removal
from enbarr_core.tools.chaos.storm import Call
from enbarr_core.tools.chaos.tree import NEUTRAL_LOG

S = 1_000_000_000   # ns per s
T0 = 100 * S        # the fault


def steady(start_s: float, end_s: float, rate: float = 100.0) -> list[int]:
    """Receive times of a control output at ``rate`` from ``start_s`` to ``end_s``."""
    n = int(round((end_s - start_s) * rate))
    return [T0 + int((start_s + i / rate) * S) for i in range(n + 1)]


def outputs(times_s: list[float], neutral_from_s: float | None = None) -> list[tuple[int, bool]]:
    return [(T0 + int(t * S), neutral_from_s is not None and t >= neutral_from_s)
            for t in times_s]


# -- removal faults: actuators neutral within 0.5 s -------------------------------------------
def test_neutral_in_time_passes_with_its_time() -> None:
    v = judge.judge_removal('sigkill:control', outputs([-0.1, 0.1, 0.3, 0.4], 0.3), T0)
    assert v.passed and v.time_to_safe_s == pytest.approx(0.3)
    assert v.expected == judge.REMOVES_CONTROL


def test_neutral_too_late_fails() -> None:
    v = judge.judge_removal('sigkill:control', outputs([0.1, 0.3, 0.7], 0.7), T0)
    assert not v.passed and v.time_to_safe_s == pytest.approx(0.7)
    assert '> 0.5 s' in v.detail


def test_no_neutral_output_fails() -> None:
    v = judge.judge_removal('sigstop:control', outputs([0.1, 0.2, 1.0]), T0)
    assert not v.passed and v.time_to_safe_s is None


def test_neutral_before_the_fault_does_not_count() -> None:
    # Neutral at -0.2 s (say the operator stopped), driving again, then nothing neutral.
    obs = [(T0 - int(0.2 * S), True), (T0 - int(0.1 * S), False), (T0 + int(0.2 * S), False)]
    assert judge.time_to_neutral(obs, T0) is None
    assert not judge.judge_removal('sigkill:supervisor', obs, T0).passed


def test_already_neutral_at_the_fault_is_safe_at_once() -> None:
    # A control group starved on a loaded machine: its thrusters went neutral by their own
    # command timeout before it was killed, and no output came after (a driver holds it).
    obs = [(T0 - int(0.5 * S), False), (T0 - int(0.2 * S), True)]
    assert judge.time_to_neutral(obs, T0) == 0.0
    assert judge.judge_removal('sigkill:control', obs, T0).passed
    # ... and driving again after it does not undo that it was safe at the fault
    assert judge.time_to_neutral(obs + [(T0 + int(0.3 * S), False)], T0) == 0.0


class FakeClock:
    """Wall time for ``removal.watch``: ``sleep`` advances it; events appear at their time."""

    def __init__(self, events: list[tuple[int, bool]]) -> None:
        self.now = T0
        self.all = events
        self.sleeps: list[float] = []

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.now += int(s * S)

    def seen(self) -> list[tuple[int, bool]]:
        return [e for e in self.all if e[0] <= self.now]


def test_a_late_neutral_is_watched_for_and_measured_late() -> None:
    # A starved driver's watchdog fires 3.2 s after the fault: past the 2 s window.
    clock = FakeClock(outputs([-0.1, 0.1, 3.2], 3.2))
    seen, watched = removal.watch(clock.seen, T0, 2.0, sleep=clock.sleep,
                                  clock=lambda: clock.now)
    assert 3.2 <= watched < 3.3
    v = removal.judged('sigkill:control', seen, T0, watched)
    assert not v.passed and v.time_to_safe_s == pytest.approx(3.2)


def test_a_neutral_in_the_window_ends_the_watch_with_the_window() -> None:
    clock = FakeClock(outputs([-0.1, 0.3], 0.3))
    seen, watched = removal.watch(clock.seen, T0, 2.0, sleep=clock.sleep,
                                  clock=lambda: clock.now)
    assert watched == pytest.approx(2.0)
    assert removal.judged('sigkill:control', seen, T0, watched).passed


def test_no_neutral_is_watched_up_to_the_limit_and_says_what_was_seen() -> None:
    clock = FakeClock(outputs([-0.4, -0.1, 0.05]))
    seen, watched = removal.watch(clock.seen, T0, 2.0, sleep=clock.sleep,
                                  clock=lambda: clock.now)
    assert watched == pytest.approx(removal.WATCH_LIMIT_S)
    assert removal.WATCH_LIMIT_S == 5.0  # the e2e test's bound (test/e2e/test_chaos.py)
    v = removal.judged('sigstop:control', seen, T0, watched)
    assert not v.passed and v.time_to_safe_s is None
    assert v.detail == ('no neutral actuator output after the fault; watched 5.0 s: '
                        '1 actuator outputs after the fault, none neutral; the last before it '
                        '0.100 s earlier')


def test_extra_condition_fails_an_in_time_neutral() -> None:
    v = judge.judge_removal('sigkill:supervisor', outputs([0.1], 0.1), T0,
                            extra='last recorded actuator output [0.02]', extra_ok=False)
    assert not v.passed and 'last recorded' in v.detail


# -- bad inputs: control kept ---------------------------------------------------------------
def test_steady_control_passes() -> None:
    v = judge.judge_kept('future+20s:imu/data_raw', steady(-1, 3), outputs([0.5, 1.0]),
                         T0, T0 + 2 * S)
    assert v.passed and v.figures['max_control_gap_s'] == pytest.approx(0.01)


def test_control_pause_fails() -> None:
    times = [t for t in steady(-1, 3) if not T0 + int(0.5 * S) < t < T0 + int(0.9 * S)]
    v = judge.judge_kept('future+0.4s:imu/data_raw', times, [], T0, T0 + 2 * S)
    assert not v.passed and 'paused 0.4' in v.detail


def test_control_stopping_at_the_fault_fails() -> None:
    # The window's edges count: nothing after the fault is a gap of the whole window.
    v = judge.judge_kept('future+20s:imu/data_raw', steady(-1, 0), [], T0, T0 + 2 * S)
    assert not v.passed and v.figures['max_control_gap_s'] == pytest.approx(2.0)


def test_neutral_actuators_fail_a_bad_input() -> None:
    v = judge.judge_kept('params', steady(-1, 3), outputs([0.2, 0.4], 0.4), T0, T0 + 2 * S)
    assert not v.passed and 'neutral' in v.detail


def test_safe_state_is_allowed_on_a_contested_command_topic() -> None:
    # Two sources on joy: refusing both (joystick lost -> zero force) is safe ...
    obs = outputs([0.2, 0.4], 0.2)
    assert judge.judge_kept('compete:joy', steady(-1, 3), obs, T0, T0 + 2 * S,
                            allow_neutral=True).passed
    # ... executing the intruder is not.
    assert not judge.judge_kept('compete:joy', steady(-1, 3), obs, T0, T0 + 2 * S,
                                executed=1, allow_neutral=True).passed


def test_a_pause_on_a_contested_topic_needs_the_safe_state_within_0_5_s() -> None:
    # A contested joystick stops the forces: control pauses, and that is safe only when the
    # actuators were neutral within 0.5 s of the fault.
    paused = steady(-1, 0) + steady(1.5, 3)
    v = judge.judge_kept('compete:joy', paused, outputs([0.1, 0.5], 0.5), T0, T0 + 2 * S,
                         allow_neutral=True)
    assert v.passed and v.detail == 'safe state after 0.500 s (contested)', v.detail
    late = judge.judge_kept('compete:joy', paused, outputs([0.1, 0.51], 0.51), T0,
                            T0 + 2 * S, allow_neutral=True)
    assert not late.passed and 'not neutral within 0.5 s' in late.detail, late.detail
    # Not on an input that must cost at most itself.
    assert not judge.judge_kept('future+20s:imu/data_raw', paused, outputs([0.1], 0.1), T0,
                                T0 + 2 * S).passed


def test_executed_intruder_fails() -> None:
    v = judge.judge_kept('compete:surface_command/twist', steady(-1, 3), [], T0, T0 + 2 * S,
                         executed=3, executed_what="of the intruder's commands executed")
    assert not v.passed and "3 of the intruder's commands executed" in v.detail


def test_max_gap_counts_the_edges() -> None:
    assert judge.max_gap([], T0, T0 + S) == pytest.approx(1.0)
    assert judge.max_gap([T0 + S // 4], T0, T0 + S) == pytest.approx(0.75)


# -- the summary line ---------------------------------------------------------------------
def test_summary_counts_and_pass() -> None:
    ok = judge.judge_removal('sigkill:control', outputs([0.2], 0.2), T0)
    bad = judge.judge_kept('params', [], [], T0, T0 + S)
    skip = judge.skipped('disk_full:recorder', judge.KEEPS_CONTROL, 'needs root')
    result = judge.summary([ok, bad, skip], tracebacks=0, bags_readable=1, bags=1)
    assert result['faults_injected'] == 2 and result['safe_within_0_5s'] == 1
    assert result['bags_readable'] == '1/1'
    assert [f['fault'] for f in result['per_fault']] == [
        'sigkill:control', 'params', 'disk_full:recorder']
    json.dumps(result)  # one JSON line
    assert not judge.run_passed(result)
    assert judge.run_passed(judge.summary([ok, skip], 0, 1, 1))


@pytest.mark.parametrize('tracebacks, readable', [(1, 1), (0, 0)])
def test_a_traceback_or_an_unreadable_bag_fails_the_run(tracebacks: int,
                                                         readable: int) -> None:
    ok = judge.judge_removal('sigkill:control', outputs([0.2], 0.2), T0)
    assert not judge.run_passed(judge.summary([ok], tracebacks, readable, 1))


def test_tracebacks_are_counted_per_line() -> None:
    text = 'ok\nTraceback (most recent call last):\n  x\nException in thread:\nTraceback (\n'
    assert judge.count_tracebacks(text) == 2


# -- the split profile and the command line -----------------------------------------------
def test_split_profile_puts_the_core_in_the_control_group(tmp_path: Path) -> None:
    plan = chaos.write_split_profile('enbarr_sim', tmp_path)
    prof = load_profile(str(plan.path))
    groups = {n.name: n.group for n in prof.nodes}
    assert plan.control_nodes == {'command_receiver', 'filtering', 'control_loop',
                                  'thruster_converter'}
    assert {n for n, g in groups.items() if g == chaos.CONTROL_GROUP} == plan.control_nodes
    assert groups['imu'] == groups['thruster_control'] == 'main'
    assert prof.node('surface').parameters['script'] == chaos.STEADY_SCRIPTS[
        'scripted_commands']


def test_split_profile_of_the_saucer_knows_its_buttons(tmp_path: Path) -> None:
    plan = chaos.write_split_profile('saucer_sim', tmp_path)
    assert {'observer', 'dp_control', 'pwm'} <= plan.control_nodes
    assert plan.joy_buttons['button_automatic'] == 1  # triangle in the enbarr_ds4 layout
    # It holds its pose in automatic (the profile's name of button 1), the observer in the loop.
    script = load_profile(str(plan.path)).node('joystick').parameters['script']
    assert script[:3] == ['0.0 sticks 0.0 0.0 0.0', '1.0 press triangle',
                          '4.0 press triangle']


def test_profile_without_plugins_is_refused(tmp_path: Path) -> None:
    only_core = tmp_path / 'only_core.yaml'
    only_core.write_text('include: [core]\n')
    with pytest.raises(EnbarrError, match='chaos needs core nodes'):
        chaos.write_split_profile(str(only_core), tmp_path)


@pytest.mark.parametrize('argv, message', [
    (['--profile', 'enbarr_sim', '--faults', 'sigkil'], '--faults: unknown sigkil; kinds: '
     'stamps'),
    (['--profile', 'enbarr_sim', '--duration', '0'], '--duration must be a positive finite'),
    (['--profile', 'enbarr_sim', '--duration', '1e308'], '--duration must be at most 600 s'),
    ([], '--profile is required (e.g. --profile enbarr_sim)'),
])
def test_bad_arguments_are_one_line_and_exit_2(argv: list[str], message: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert enbarr_main(['chaos', *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('enbarr chaos: error: ') and message in err[0]


def test_existing_output_directory_is_refused(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert enbarr_main(['chaos', '--profile', 'enbarr_sim', '--output', str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == (
        f'enbarr chaos: error: --output {tmp_path}: exists; chaos never overwrites a run')


def test_old_spellings_still_work_with_a_notice(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    # 'chaos PROFILE' and --out, as before --profile and --output: same run, one notice each.
    assert enbarr_main(['chaos', 'enbarr_sim', '--out', str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        'enbarr chaos: warning: PROFILE as a positional argument is deprecated; use --profile '
        'enbarr_sim',
        'enbarr chaos: warning: --out is deprecated; use --output',
        f'enbarr chaos: error: --output {tmp_path}: exists; chaos never overwrites a run']


def test_two_profiles_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert enbarr_main(['chaos', '--profile', 'enbarr_sim', 'saucer_sim']) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        'enbarr chaos: error: two profiles: --profile enbarr_sim and saucer_sim')


def test_a_drivers_neutral_log_line_is_an_observation() -> None:
    log = ('[INFO] [1795376177.2] [dp_control]: mode automatic -> manual (neutral stick)\n'
           '[WARN] [1795376177.885158580] [arduino]: PWM input stopped: outputs neutral\n'
           '[ERROR] [enbarr.bringup]: group control died (signal SIGKILL); restart 2 of 50\n')
    assert NEUTRAL_LOG.findall(log) == ['1795376177.885158580']


# -- the parameter storm: every call judged ------------------------------------------------------
def storm_answers(*oks: bool | None, valid: bool = False) -> list[tuple[Call, bool | None]]:
    return [(Call('/imu', f'p{i}', 'chaos', valid), ok) for i, ok in enumerate(oks)]


def test_a_storm_with_every_invalid_value_refused_passes() -> None:
    answers = storm_answers(False, False, False) + storm_answers(True, valid=True)
    v = judge.judge_storm('params', steady(-1, 3), [], T0, T0 + 2 * S, answers, nodes=1)
    assert v.passed, v.detail
    assert (v.figures['calls'], v.figures['answered'], v.figures['valid_refused']) == (4, 4, 0)


def test_an_unanswered_call_fails_the_storm() -> None:
    # Before: an unanswered call was skipped, so a storm that lost most of its calls passed
    # on the ones answered.
    v = judge.judge_storm('params', steady(-1, 3), [], T0, T0 + 2 * S,
                          storm_answers(False, None, False), nodes=1)
    assert not v.passed
    assert v.detail == "1 of 3 calls unanswered: /imu.p1='chaos'"
    assert v.figures['answered'] == 2


def test_an_accepted_invalid_value_fails_the_storm() -> None:
    v = judge.judge_storm('params', steady(-1, 3), [], T0, T0 + 2 * S,
                          storm_answers(False, True), nodes=1)
    assert not v.passed and "1 invalid values accepted: /imu.p1='chaos'" in v.detail


def test_a_valid_value_refused_is_only_counted() -> None:
    # A read-only parameter refuses its own value too: not unsafe.
    v = judge.judge_storm('params', steady(-1, 3), [], T0, T0 + 2 * S,
                          storm_answers(False, valid=True), nodes=1)
    assert v.passed and v.figures['valid_refused'] == 1


def test_a_storm_that_reached_no_node_fails() -> None:
    v = judge.judge_storm('params', steady(-1, 3), [], T0, T0 + 2 * S, [], nodes=0)
    assert not v.passed and 'no node answered' in v.detail
