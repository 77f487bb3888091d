"""Scenario metrics (enbarr_core.tools.metrics.compute_metrics) on synthetic bags with known
answers, and the ``scenario`` section's checks (enbarr_core.tools.scenario.scenario_spec).

Each bag is written with the project's bag writer from hand-made poses
(``support.synthetic``); the expected figures are worked out here by hand or in closed form
(geometric series, logarithms), never with the metrics' own code. The metrics round their
figures (0.1 mm, 0.001 deg, 0.01 s): that rounding is the tolerance of an exact figure
(``MM``, ``MDEG``, ``CS``), plus one sample period where a time is found on the sample grid.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from support import synthetic

from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import EnbarrError, ProfileError
from enbarr_core.tools.metrics import compute_metrics
from enbarr_core.tools.scenario import resolve, ScenarioSpec, scenario_spec, with_duration
from enbarr_core.tools.targets import Target

MM = 0.5e-4     # the metrics round metres to 4 decimals
MDEG = 0.5e-3   # and degrees to 3
CS = 0.005      # and seconds to 2
DT = 0.01       # sample period of the synthetic odometry (the simulator's 100 Hz) [s]
T0 = 1.0        # first sample [s]
TA = 2.0        # automatic mode begins [s] (a sample instant)


def grid(seconds: float) -> np.ndarray:
    """Sample times from T0 for ``seconds``, exact on the ns grid the bag stores."""
    return (np.round((T0 + DT * np.arange(int(round(seconds / DT)) + 1)) * 1e9)) * 1e-9


def hold(spec_time: float = 10.0, band: tuple[float, float] = (0.05, 2.0)) -> ScenarioSpec:
    return ScenarioSpec(duration=60.0, kind='station_keeping', settle_band=band,
                        settle_time=spec_time)


def run(tmp_path: Path, t: np.ndarray, eta: np.ndarray, spec: ScenarioSpec,
        modes: tuple[tuple[float, str], ...] = ((TA, 'automatic'),), eta_d=(0.0, 0.0, 0.0),
        profile=None, **forces) -> dict:
    bag = synthetic.write_run(tmp_path / 'bag', t, eta, eta_d, modes, **forces)
    return compute_metrics(bag, spec, profile or synthetic.profile())


def offset(t: np.ndarray, dx: np.ndarray | float, dy: np.ndarray | float = 0.0,
           dpsi_deg: np.ndarray | float = 0.0) -> np.ndarray:
    """Poses offset from a hold at (1.0, -2.0, 0.5 rad) by (dx, dy) [m], dpsi [deg]."""
    n = len(t)
    return np.column_stack((1.0 + np.broadcast_to(dx, n), -2.0 + np.broadcast_to(dy, n),
                            0.5 + np.radians(np.broadcast_to(dpsi_deg, n))))


HOLD = (1.0, -2.0, 0.5)


# -- station keeping ----------------------------------------------------------------------------
def test_constant_offset_gives_its_own_size(tmp_path: Path) -> None:
    """A 3-4-5 offset of 0.018 m east, 0.024 m north is 0.03 m exactly; 1.5 deg of heading."""
    t = grid(40.0)
    r = run(tmp_path, t, offset(t, 0.018, 0.024, 1.5), hold(), eta_d=HOLD)
    for key in ('position_error_rms_m', 'position_error_max_m', 'overall_position_error_rms_m',
                'overall_position_error_max_m'):
        assert r[key] == pytest.approx(0.03, abs=MM), key
    for key in ('heading_error_rms_deg', 'heading_error_max_deg',
                'overall_heading_error_rms_deg', 'overall_heading_error_max_deg'):
        assert r[key] == pytest.approx(1.5, abs=MDEG), key
    assert r['time_to_settle_s'] == 0.0 and r['settled'] and r['settled_in_time']
    assert r['initial_mode'] == 'manual'
    assert r['modes'] == [(1.0, 'automatic')]          # from the first sample
    assert r['automatic_s'] == pytest.approx(39.0, abs=CS)
    assert r['window_s'] == pytest.approx([11.0, 40.0], abs=CS)  # TA + settle_time .. end
    assert 'error' not in r


def test_heading_error_wraps_across_pi(tmp_path: Path) -> None:
    """Reference at +179 deg, vessel at -179 deg: 2 deg apart, not 358."""
    t = grid(20.0)
    eta = np.column_stack((np.zeros(len(t)), np.zeros(len(t)), np.full(len(t), -math.pi)))
    eta[:, 2] += math.radians(1.0)
    r = run(tmp_path, t, eta, hold(5.0, band=(0.05, 3.0)), eta_d=(0.0, 0.0, math.radians(179)))
    assert r['heading_error_max_deg'] == pytest.approx(2.0, abs=MDEG)


def test_transient_inside_the_window_counts(tmp_path: Path) -> None:
    """0.3 m for the first 5 s of automatic, then 0.01 m; window from 3 s after automatic.

    The window [TA + 3, TA + 38] holds 200 samples at 0.3 m (TA + 3.00 .. TA + 4.99) and 3301
    at 0.01 m (TA + 5.00 .. TA + 38.00): RMS = sqrt((200 0.09 + 3301 1e-4) / 3501). Taken
    only after the last sample outside the band (the old definition), it would be 0.01.
    """
    t = grid(39.0)
    dx = np.where(t < TA + 5.0 - DT / 2, 0.3, 0.01)
    r = run(tmp_path, t, offset(t, dx), hold(3.0), eta_d=HOLD)
    expected = math.sqrt((200 * 0.09 + 3301 * 1e-4) / 3501)
    assert r['position_error_rms_m'] == pytest.approx(expected, abs=MM)
    assert r['position_error_max_m'] == pytest.approx(0.3, abs=MM)
    assert r['time_to_settle_s'] == pytest.approx(5.0, abs=CS)
    assert r['settled'] and not r['settled_in_time']   # 5 s > the stated 3 s
    # Whole automatic period: 500 samples at 0.3 m, 3301 at 0.01 m.
    assert r['overall_position_error_rms_m'] == pytest.approx(
        math.sqrt((500 * 0.09 + 3301 * 1e-4) / 3801), abs=MM)


def test_exponential_decay_settles_at_the_logarithm(tmp_path: Path) -> None:
    """Position error a exp(-s/tau) (s: time in automatic), a = 0.2 m, tau = 4 s; band 0.05 m.

    It enters the band for good at s* = tau ln(a / 0.05) = 4 ln 4 = 5.545 s; the metric finds
    the first sample at or after it (within one period). The heading, 10 exp(-s/1) deg, is
    inside 2 deg from ln 5 = 1.609 s: the later of the two governs. The window (s >= 10 s,
    n = 2901 samples to s = 39) has the geometric series
    RMS^2 = a^2 q^(2 k0) (1 - q^(2n)) / ((1 - q^2) n), q = exp(-DT / tau), k0 = 10 / DT.
    """
    t = grid(40.0)
    s = np.maximum(t - TA, 0.0)
    a, tau = 0.2, 4.0
    r = run(tmp_path, t, offset(t, a * np.exp(-s / tau), 0.0, 10.0 * np.exp(-s)), hold(10.0),
            eta_d=HOLD)
    s_star = tau * math.log(a / 0.05)
    assert s_star - CS <= r['time_to_settle_s'] <= s_star + DT + CS
    assert r['settled_in_time']
    q, n, k0 = math.exp(-DT / tau), 2901, 1000
    rms = a * q ** k0 * math.sqrt((1 - q ** (2 * n)) / ((1 - q ** 2) * n))
    assert r['position_error_rms_m'] == pytest.approx(rms, abs=MM)
    assert r['position_error_max_m'] == pytest.approx(a * math.exp(-10.0 / tau), abs=MM)
    n_all = 3901  # s = 0 .. 39 in automatic
    rms_all = a * math.sqrt((1 - q ** (2 * n_all)) / ((1 - q ** 2) * n_all))
    assert r['overall_position_error_rms_m'] == pytest.approx(rms_all, abs=MM)
    assert r['overall_position_error_max_m'] == pytest.approx(a, abs=MM)
    assert r['overall_heading_error_max_deg'] == pytest.approx(10.0, abs=MDEG)


def test_heading_alone_can_keep_it_unsettled(tmp_path: Path) -> None:
    """Position inside the band from the start, heading 10 exp(-s/3) deg: inside 2 deg from
    s* = 3 ln 5 = 4.828 s; with a stated settle time of 4 s, not settled in time.
    """
    t = grid(30.0)
    s = np.maximum(t - TA, 0.0)
    r = run(tmp_path, t, offset(t, 0.01, 0.0, 10.0 * np.exp(-s / 3.0)), hold(4.0), eta_d=HOLD)
    s_star = 3.0 * math.log(5.0)
    assert s_star - CS <= r['time_to_settle_s'] <= s_star + DT + CS
    assert r['settled'] and not r['settled_in_time']


def test_a_late_excursion_moves_the_settle_time(tmp_path: Path) -> None:
    """Inside the band but for 0.06 m from s = 30 to 31 s: it settles after the excursion."""
    t = grid(40.0)
    s = t - TA
    dx = np.where((s >= 30.0 - DT / 2) & (s < 31.0 - DT / 2), 0.06, 0.01)
    r = run(tmp_path, t, offset(t, dx), hold(10.0), eta_d=HOLD)
    assert r['time_to_settle_s'] == pytest.approx(31.0, abs=CS)
    assert r['settled'] and not r['settled_in_time']
    assert r['position_error_max_m'] == pytest.approx(0.06, abs=MM)


def test_never_settles(tmp_path: Path) -> None:
    """A constant 0.08 m offset: never inside the 0.05 m band; the figures are still given."""
    t = grid(30.0)
    r = run(tmp_path, t, offset(t, 0.0, 0.08), hold(10.0), eta_d=HOLD)
    assert r['time_to_settle_s'] is None
    assert not r['settled'] and not r['settled_in_time']
    assert r['position_error_rms_m'] == pytest.approx(0.08, abs=MM)


def test_drifting_off_at_the_end_is_not_settled(tmp_path: Path) -> None:
    """Inside the band until the last second, then outside to the end: not settled."""
    t = grid(30.0)
    dx = np.where(t > t[-1] - 1.0, 0.07, 0.0)
    r = run(tmp_path, t, offset(t, dx), hold(10.0), eta_d=HOLD)
    assert r['time_to_settle_s'] is None and not r['settled']


@pytest.mark.parametrize('modes', [(), ((1.5, 'manual'),), ((1.5, 'guidance'),)])
def test_no_automatic_mode_is_an_error_without_figures(tmp_path: Path, modes) -> None:
    t = grid(20.0)
    r = run(tmp_path, t, offset(t, 0.0), hold(5.0), modes=modes, eta_d=HOLD)
    assert r['error'] == 'never in automatic mode'
    assert 'position_error_rms_m' not in r and 'settled' not in r


def test_the_automatic_period_ends_at_the_next_mode(tmp_path: Path) -> None:
    """Automatic from TA to TA + 20 s at 0.02 m, then guidance 1 m away: not counted."""
    t = grid(40.0)
    dx = np.where(t < TA + 20.0 - DT / 2, 0.02, 1.0)
    r = run(tmp_path, t, offset(t, dx), hold(5.0), eta_d=HOLD,
            modes=((TA, 'automatic'), (TA + 20.0, 'guidance')))
    assert r['automatic_s'] == pytest.approx(20.0, abs=CS)
    assert r['position_error_max_m'] == pytest.approx(0.02, abs=MM)
    assert r['overall_position_error_max_m'] == pytest.approx(0.02, abs=MM)
    assert r['time_to_settle_s'] == 0.0


def test_automatic_shorter_than_the_settle_time_is_an_error(tmp_path: Path) -> None:
    t = grid(20.0)
    r = run(tmp_path, t, offset(t, 0.01), hold(25.0), eta_d=HOLD)
    assert r['error'].startswith('the evaluation window is empty')
    assert 'position_error_rms_m' not in r
    assert r['overall_position_error_max_m'] == pytest.approx(0.01, abs=MM)


def test_error_during_a_mocap_dropout(tmp_path: Path) -> None:
    """Dropout window [10, 11] s from the start, judged up to one second after it: 0.02 m
    during the dropout, 0.04 m in the second after (the estimate drifted, then is pulled back),
    0.045 m later on (not counted), 0.005 m elsewhere.
    """
    t = grid(30.0)
    s0 = t - T0
    dx = np.full(len(t), 0.005)
    dx[(s0 >= 10.0 - DT / 2) & (s0 < 11.0 - DT / 2)] = 0.02
    dx[(s0 >= 11.0 - DT / 2) & (s0 < 12.0 - DT / 2)] = 0.04
    dx[(s0 > 12.5) & (s0 < 13.0)] = 0.045
    r = run(tmp_path, t, offset(t, dx), hold(5.0), eta_d=HOLD,
            profile=synthetic.profile(dropout_windows=[10.0, 11.0]))
    assert r['dropout_position_error_max_m'] == pytest.approx(0.04, abs=MM)


def test_thrust_saturation_time(tmp_path: Path) -> None:
    """Delivered short of the asked force on 250 samples at 100 Hz: 2.5 s."""
    t = grid(20.0)
    asked = np.tile([1.0, 0.5, 0.1], (len(t), 1))
    delivered = asked.copy()
    delivered[400:650] *= 0.8
    r = run(tmp_path, t, offset(t, 0.0), hold(5.0), eta_d=HOLD, asked=asked,
            delivered=delivered)
    assert r['thrust_saturation_s'] == pytest.approx(2.5, abs=CS)


# -- path -----------------------------------------------------------------------------------
PATH = ScenarioSpec(duration=60.0, kind='path', settle_band=(0.05, 2.0))


def straight(t: np.ndarray, speed: float, y: float, x_end: float,
             y_hold: float) -> np.ndarray:
    """Along y = ``y`` from x = 0 at ``speed`` from TA; from x_end on, hold at (x_end, y_hold)."""
    x = np.clip(speed * (t - TA), 0.0, x_end)
    return np.column_stack((x, np.where(x < x_end, y, y_hold), np.zeros(len(t))))


def test_straight_leg_with_a_constant_offset(tmp_path: Path) -> None:
    """(0, 0) -> (4, 0) at 0.2 m/s, 0.03 m left of it, then holding exactly on (4, 0).

    Arrival within 0.1 m of (4, 0): x >= 4 - sqrt(0.1^2 - 0.03^2) = 3.9046 m, i.e. at
    19.523 s (the next sample). Cross-track RMS to the arrival is 0.03: the 40 s of holding
    on the waypoint after it do not dilute it.
    """
    t = grid(60.0)
    r = run(tmp_path, t, straight(t, 0.2, 0.03, 4.0, 0.0), PATH, modes=((TA, 'guidance'),),
            profile=synthetic.profile(waypoints=[0.0, 0.0, 4.0, 0.0]))
    arrive = (4.0 - math.sqrt(0.1 ** 2 - 0.03 ** 2)) / 0.2
    assert arrive - CS <= r['path_time_s'] <= arrive + DT + CS
    assert r['all_waypoints_visited']
    assert r['cross_track_rms_m'] == pytest.approx(0.03, abs=MM)
    assert r['cross_track_max_m'] == pytest.approx(0.03, abs=MM)
    assert r['final_position_error_m'] == pytest.approx(0.0, abs=MM)


def test_go_to_one_waypoint_uses_the_line_from_the_start(tmp_path: Path) -> None:
    """One waypoint (4, 0.5): the path is the line from where guidance began, (0, 0.5)."""
    t = grid(60.0)
    r = run(tmp_path, t, straight(t, 0.2, 0.5, 4.0, 0.5), PATH, modes=((TA, 'guidance'),),
            profile=synthetic.profile(waypoints=[4.0, 0.5]))
    assert r['cross_track_max_m'] == pytest.approx(0.0, abs=MM)
    assert r['all_waypoints_visited'] and r['path_time_s'] is not None


def test_stopping_short_never_arrives(tmp_path: Path) -> None:
    """Stops at (3, 0.03) of a leg to (4, 0): no arrival; RMS over the whole period."""
    t = grid(40.0)
    r = run(tmp_path, t, straight(t, 0.2, 0.03, 3.0, 0.03), PATH, modes=((TA, 'guidance'),),
            profile=synthetic.profile(waypoints=[0.0, 0.0, 4.0, 0.0]))
    assert r['path_time_s'] is None and not r['all_waypoints_visited']
    assert r['cross_track_rms_m'] == pytest.approx(0.03, abs=MM)
    assert r['final_position_error_m'] == pytest.approx(math.hypot(1.0, 0.03), abs=MM)


def along(t: np.ndarray, corners: list[tuple[float, float]], speed: float) -> np.ndarray:
    """Poses driven exactly along the polyline ``corners`` at ``speed`` from TA, then held."""
    c = np.array(corners, dtype=float)
    lengths = np.hypot(*np.diff(c, axis=0).T)
    ends = np.concatenate(([0.0], np.cumsum(lengths)))
    s = np.clip(speed * (t - TA), 0.0, ends[-1])
    leg = np.minimum(np.searchsorted(ends, s, side='right') - 1, len(lengths) - 1)
    frac = ((s - ends[leg]) / lengths[leg])[:, None]
    p = c[leg] + frac * (c[leg + 1] - c[leg])
    return np.column_stack((p, np.zeros(len(t))))


def test_closed_triangle_driven_on_the_path(tmp_path: Path) -> None:
    """(0,0) (4,0) (4,4) (0,0) driven exactly along it at 0.2 m/s: no cross-track error on any
    leg, and the arrival at (0, 0), where it started, comes only after (4, 4): within 0.1 m of
    it at (8 + 4 sqrt 2 - 0.1) / 0.2 = 67.78 s.
    """
    corners = [(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 0.0)]
    t = grid(75.0)
    r = run(tmp_path, t, along(t, corners, 0.2), PATH, modes=((TA, 'guidance'),),
            profile=synthetic.profile(waypoints=[v for c in corners for v in c]))
    assert r['cross_track_max_m'] == pytest.approx(0.0, abs=MM)
    assert r['all_waypoints_visited']
    arrive = (8.0 + 4.0 * math.sqrt(2.0) - 0.1) / 0.2
    assert arrive - CS <= r['path_time_s'] <= arrive + DT + CS


def test_box_driven_backwards_is_not_the_path(tmp_path: Path) -> None:
    """The 2 m box (0,0) (2,0) (2,2) (0,2) (0,0) driven the other way round, exactly on its
    edges: every waypoint is passed and every point lies ON the polyline, but not in order.
    The first leg, (0,0) -> (2,0), stays active until the vessel is nearer the second,
    (2,0) -> (2,2), just past (0, 2): there it is 2 m from the first leg. The second then
    stays active (the third, (2,2) -> (0,2), is never nearer) to the end at (0, 0), 2 m
    from it.
    """
    corners = [(0.0, 0.0), (0.0, 2.0), (2.0, 2.0), (2.0, 0.0), (0.0, 0.0)]
    t = grid(50.0)
    r = run(tmp_path, t, along(t, corners, 0.2), PATH, modes=((TA, 'guidance'),),
            profile=synthetic.profile(waypoints=[0, 0, 2, 0, 2, 2, 0, 2, 0, 0]))
    assert not r['all_waypoints_visited'] and r['path_time_s'] is None
    assert r['cross_track_max_m'] == pytest.approx(2.0, abs=MM)


def test_no_guidance_mode_is_an_error(tmp_path: Path) -> None:
    t = grid(10.0)
    r = run(tmp_path, t, straight(t, 0.2, 0.0, 1.0, 0.0), PATH, modes=((TA, 'automatic'),),
            profile=synthetic.profile(waypoints=[0.0, 0.0, 4.0, 0.0]))
    assert r['error'] == 'never in guidance mode, or no path'
    assert 'cross_track_rms_m' not in r


# -- the scenario section --------------------------------------------------------------------
def spec_of(**scenario) -> ScenarioSpec:
    return scenario_spec(SimpleNamespace(scenario=scenario, path='/here/s.yaml'))


def spec_error(**scenario) -> str:
    with pytest.raises(ProfileError) as info:
        spec_of(**scenario)
    return str(info.value)


TARGETS = {'mode_changes': {'max': 1}}  # every kind has it


def test_settle_time_is_read() -> None:
    spec = spec_of(duration=90.0, kind='station_keeping', settle_time=20.0,
                   settle_band=[0.05, 2.0], targets=TARGETS)
    assert spec == ScenarioSpec(90.0, 'station_keeping', (0.05, 2.0), 20.0,
                                (Target('mode_changes', high=1.0),))
    assert spec_of(duration=60.0, kind='path', targets=TARGETS).settle_time is None


@pytest.mark.parametrize(('scenario', 'message'), [
    ({'duration': 60.0}, '/here/s.yaml: scenario.settle_time: required for a station_keeping'),
    ({'duration': 60.0, 'settle_time': -1.0},
     '/here/s.yaml: scenario.settle_time: must be >= 0 and below the duration (60.0 s), got -1'),
    ({'duration': 60.0, 'settle_time': 60.0}, 'scenario.settle_time: must be >= 0 and below'),
    ({'duration': 60.0, 'settle_time': 'soon'},
     "/here/s.yaml: scenario.settle_time: expected seconds >= 0, got 'soon'"),
    ({'duration': 60.0, 'settle_time': True}, 'scenario.settle_time: expected seconds >= 0'),
    ({'duration': 60.0, 'kind': 'path', 'settle_time': 5.0},
     'scenario.settle_time: only for a station_keeping scenario'),
    ({'duration': 60.0, 'settle_time': 5.0, 'settle_band': [0.05]},
     'scenario.settle_band: expected two numbers [m, deg], got [0.05]'),
    ({'duration': 60.0, 'settle_time': 5.0, 'settle_band': [0.05, -2.0]},
     'scenario.settle_band: expected two numbers > 0 [m, deg]'),
    ({'duration': 0.0, 'settle_time': 5.0}, 'scenario.duration: must be > 0'),
    ({'settle_time': 5.0}, 'scenario.duration: expected simulated seconds > 0, got None'),
    ({'duration': 60.0, 'kind': 'orbit'},
     "scenario.kind: must be one of station_keeping, path, run, got 'orbit'"),
    ({'duration': 60.0, 'kind': 'run', 'settle_time': 5.0},
     'scenario.settle_time: only for a station_keeping scenario'),
    ({'duration': 60.0, 'settle_tme': 5.0}, "scenario: unknown key 'settle_tme'"),
])
def test_bad_scenario_sections_name_the_file_and_field(scenario, message) -> None:
    assert message in spec_error(**scenario)


SHIPPED = sorted(p.stem for p in (Path(__file__).parents[2] / 'params' / 'scenarios').glob(
    '*.yaml'))


def test_every_shipped_scenario_is_checked_here() -> None:
    assert {'station_keeping', 'box_path', 'perturbed_rov_heavy'} <= set(SHIPPED)


@pytest.mark.parametrize('name', SHIPPED)
def test_shipped_scenarios_state_their_settle_time(name: str) -> None:
    """Every shipped scenario passes the checks and states its targets; a station-keeping one
    leaves a window of at least 10 s (1000 samples at 100 Hz) after its settle time, an RMS of
    the holding rather than of a handful of samples.
    """
    spec = scenario_spec(load_profile(resolve(name)))
    assert spec.targets
    if spec.kind == 'station_keeping':
        assert spec.settle_time is not None and spec.settle_time + 10.0 <= spec.duration


def test_duration_override_must_outlast_the_settle_time() -> None:
    spec = ScenarioSpec(90.0, 'station_keeping', (0.05, 2.0), 20.0)
    assert with_duration(spec, 30.0).duration == 30.0
    with pytest.raises(EnbarrError, match=r"--duration 20.0 s leaves no evaluation window: "
                       r"the scenario's settle_time is 20.0 s"):
        with_duration(spec, 20.0)
    assert with_duration(PATH, 5.0).duration == 5.0  # a path has no settle time


def test_a_run_scenario_has_only_the_common_figures(tmp_path: Path) -> None:
    """kind: run (a test judges the bag): modes and saturation, no window, no error."""
    t = grid(20.0)
    r = run(tmp_path, t, offset(t, 0.5), ScenarioSpec(20.0, 'run', (0.05, 2.0)), modes=())
    assert set(r) == {'initial_mode', 'modes', 'mode_changes', 'thrust_saturation_s',
                      'final_speed_mps'}
    assert r['modes'] == [] and r['mode_changes'] == 0 and r['thrust_saturation_s'] == 0.0
    assert r['initial_mode'] == 'manual'


# -- the picture: north up, east right, compass heading -----------------------------------------

def test_the_plot_puts_north_up_and_reads_headings_as_a_compass(tmp_path: Path,
                                                                monkeypatch) -> None:
    """A vessel at x = 1 east, y = 2 north, turned 10 deg to port of its northward hold
    reference: compass heading 350 deg, reference 0, error -10 (clockwise positive)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from enbarr_core.tools.metrics import plot_run
    figures = []
    monkeypatch.setattr(plt, 'close', figures.append)
    t = grid(2.0)
    eta = np.tile([1.0, 2.0, math.pi / 2 + math.radians(10.0)], (len(t), 1))
    bag = synthetic.write_run(tmp_path / 'bag', t, eta, (1.0, 2.0, math.pi / 2),
                              ((TA, 'automatic'),))
    png = plot_run(bag, hold(), SimpleNamespace(name='run', nodes=(), parameters={}),
                   tmp_path / 'run.png')
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'  # a PNG file's signature
    [fig] = figures
    path = fig.axes[0]  # the first drawn: the path
    axes = {a.get_ylabel(): a for a in fig.axes[1:]}
    heading = axes['heading [deg] (compass)']
    error_twin = axes['heading error [deg], + clockwise']
    assert {'position error [m]', 'thrust [N]'} <= set(axes)
    assert (path.get_xlabel(), path.get_ylabel()) == ('east [m] (odom x)', 'north [m] (odom y)')
    vessel = next(line for line in path.lines if line.get_label() == 'vessel (truth)')
    assert np.allclose(vessel.get_xdata(), 1.0) and np.allclose(vessel.get_ydata(), 2.0)
    truth, ref = heading.lines[:2]
    assert np.allclose(truth.get_ydata(), 350.0) and np.allclose(ref.get_ydata(), 0.0)
    assert np.allclose(error_twin.lines[0].get_ydata(), -10.0)


def drawn(monkeypatch, bag: Path, spec: ScenarioSpec, profile, png: Path, verdict=None):
    """``plot_run``'s figure, kept from ``plt.close``: its axes by title.

    The figure is not rendered: rendering a page of panels costs seconds, and what these
    tests read is in the figure's artists; the north-up test renders one to a real PNG.
    """
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib.figure import Figure
    import matplotlib.pyplot as plt
    from enbarr_core.tools.metrics import plot_run
    figures, saved = [], []
    monkeypatch.setattr(plt, 'close', figures.append)
    monkeypatch.setattr(Figure, 'savefig', lambda fig, path, **kw: saved.append(path))
    assert plot_run(bag, spec, profile, png, verdict=verdict) == png
    [fig] = figures
    assert saved == [png]
    return fig, {a.get_title(): a for a in fig.axes if a.get_title()}


def line(ax, label: str):
    return next(item for item in ax.lines if item.get_label() == label)


SIM = {'current': [0.1, 0.0], 'bias': [0.5, -0.4, 0.08], 'vessel.inertia': [1.0, 1.0, 1.0],
       'vessel.linear_damping': [2.0, 3.0, 0.5], 'vessel.nonlinear_damping': [10.0, 20.0, 5.0]}
BIAS_TITLE = ('observer bias estimate (solid) against the injected disturbance on the still '
              'hull (dashed), world frame')
HOLD_TITLE = 'station keeping: position about the hold point, north up [cm]'


def test_the_station_keeping_plot_draws_what_an_engineer_reads(tmp_path: Path,
                                                               monkeypatch) -> None:
    """Held 1.8 cm east and 2.4 cm north of a northward hold, in a 0.1 m/s current from the
    east and a wind (the simulator's parameters, the case of test_vessel3dof's
    test_disturbance_at_rest_by_hand): the injected disturbance on the still hull is
    (1.0 N, -0.4 N, 0.08 N m) by hand; the observer's estimate, azimuth angles and thrusts
    are drawn as recorded, the angles in degrees from ahead, + to starboard."""
    from enbarr_core.tools.targets import judge
    t = grid(30.0)
    north = math.pi / 2
    eta = np.column_stack((np.full(len(t), 1.018), np.full(len(t), 2.024), np.full(len(t), north)))
    b_hat = np.tile([0.9, -0.35, 0.07], (len(t), 1))
    angle = np.tile([0.5, -1.0], (len(t), 1))
    thrust = np.tile([0.3, -0.2], (len(t), 1))
    bag = synthetic.write_run(tmp_path / 'bag', t, eta, (1.0, 2.0, north), ((TA, 'automatic'),),
                              bias=b_hat, azimuths=(['az_a', 'az_b'], thrust, angle))
    profile = synthetic.profile(simulator=SIM,
                                parameters={'azimuths.az_a.angle_max': math.radians(114.0)})
    spec = ScenarioSpec(30.0, 'station_keeping', (0.05, 2.0), 10.0,
                        (Target('position_error_rms_m', high=0.02),))
    verdict = judge({'position_error_rms_m': 0.03}, spec.targets)
    fig, axes = drawn(monkeypatch, bag, spec, profile, tmp_path / 'p.png', verdict)
    assert fig.get_suptitle() == 'synthetic: FAIL: position_error_rms_m'
    # The bias: the estimate as recorded, the disturbance as computed by hand.
    bias = axes[BIAS_TITLE]
    for name, got, injected in (('east X [N]', 0.9, 1.0), ('north Y [N]', -0.35, -0.4),
                                ('yaw N [N m], + counter-clockwise', 0.07, 0.08)):
        assert np.allclose(line(bias, f'b_hat {name}').get_ydata(), got)
        assert np.allclose(line(bias, f'injected {name}').get_ydata(), injected), name
    # The azimuths: compass-like angles (the allocation's are counter-clockwise), the travel.
    angles = axes['azimuth angles (commanded): 0 = ahead, + to starboard (clockwise)']
    assert angles.get_ylabel() == 'azimuth angle [deg]'
    assert np.allclose(line(angles, 'az_a').get_ydata(), -math.degrees(0.5))
    assert np.allclose(line(angles, 'az_b').get_ydata(), math.degrees(1.0))
    assert any(np.allclose(item.get_ydata(), -114.0) for item in angles.lines)  # servo travel
    thrusts = axes['azimuth thrust (commanded)']
    assert np.allclose(line(thrusts, 'az_b').get_ydata(), -0.2)
    # Station keeping at the scale of its error: centimetres about the hold point, the band.
    hold = axes[HOLD_TITLE]
    assert hold.get_xlabel() == 'east of the hold point [cm]'
    window = line(hold, 'evaluation window')
    assert np.allclose(window.get_xdata(), 1.8) and np.allclose(window.get_ydata(), 2.4)
    [band] = hold.patches
    assert band.get_radius() == pytest.approx(5.0)
    assert hold.get_xlim()[1] == pytest.approx(6.5)   # the band's scale, not the hull's
    # The speed: still, against a reference speed of zero.
    speed = axes['speed over ground against the commanded speed']
    assert np.allclose(line(speed, 'speed over ground (truth)').get_ydata(), 0.0)
    # The verdict as text, the failed target in red.
    table = axes['targets (scenario.targets) and the verdict']
    texts = [(x.get_text(), x.get_color()) for x in table.texts]
    assert texts == [('verdict: FAIL', 'tab:red'),
                     ('position_error_rms_m = 0.03, <= 0.02: FAIL', 'tab:red')]


def test_the_path_plot_draws_the_course_reference_and_the_speed(tmp_path: Path,
                                                                monkeypatch) -> None:
    """Line-of-sight style: the bow points north (compass 0) while the reference velocity is
    to starboard, nu_d = (0, -0.2) m/s: the course reference is east (compass 90), which the
    vessel makes good at 0.2 m/s. A wrong rotation sign would draw west (270)."""
    t = grid(10.0)
    north = math.pi / 2
    x = 0.2 * np.maximum(t - TA, 0.0)
    eta = np.column_stack((x, np.zeros(len(t)), np.full(len(t), north)))
    # The reference: the vessel's own pose (a new one at each sample), velocity nu_d.
    bag = synthetic.write_run(tmp_path / 'bag', t, eta, eta, ((TA, 'guidance'),),
                              nu_d=(0.0, -0.2, 0.0))
    profile = synthetic.profile(waypoints=[0.0, 0.0, 4.0, 0.0], speed=0.25)
    fig, axes = drawn(monkeypatch, bag, PATH, profile, tmp_path / 'p.png')
    heading = axes['compass heading and course: 0 = north, clockwise']
    assert np.allclose(line(heading, 'heading (truth)').get_ydata(), 0.0)
    course = line(heading, 'course reference (R(psi) nu_d; LOS chi_d)')
    assert len(course.get_xdata()) and np.allclose(course.get_ydata(), 90.0)
    made_good = line(heading, 'course over ground (truth)')
    assert np.allclose(made_good.get_ydata(), 90.0)
    speed = axes['speed over ground against the commanded speed']
    sog = line(speed, 'speed over ground (truth)')
    moving = (np.asarray(sog.get_xdata()) > TA - T0 + 0.05)
    assert np.allclose(np.asarray(sog.get_ydata())[moving], 0.2)
    assert np.allclose(line(speed, 'commanded: reference speed |nu_d|').get_ydata(), 0.2)
    assert np.allclose(line(speed, 'path.speed 0.25 m/s').get_ydata(), 0.25)
    assert HOLD_TITLE not in axes  # a path is not drawn about a hold point
    assert fig.get_suptitle() == ''  # not judged: no verdict given


def test_final_speed_and_mode_changes(tmp_path: Path) -> None:
    """Driving along (0, 0) -> (3, 4) at 0.25 m/s to the end: 0.25 m/s over the last second;
    guidance then automatic then guidance again: three changes after the latched manual."""
    t = grid(12.0)
    r = run(tmp_path, t, along(t, [(0.0, 0.0), (3.0, 4.0)], 0.25), PATH,
            modes=((TA, 'guidance'), (TA + 1.0, 'automatic'), (TA + 2.0, 'guidance'),
                   (TA + 2.5, 'guidance')),
            profile=synthetic.profile(waypoints=[0.0, 0.0, 3.0, 4.0]))
    assert r['final_speed_mps'] == pytest.approx(0.25, abs=MM)
    assert r['mode_changes'] == 3
