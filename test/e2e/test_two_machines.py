"""The vessel and the operator's computer as two machines: two network namespaces joined by a
veth pair (a private /30, nothing routed out: the traffic never leaves the namespaces).

The simulated ROV (``enbarr_sim`` without its scripted station) runs in one namespace and
records its bag there; the topside (``enbarr_rov_topside`` with a scripted source in place of
the gamepad, which needs a person) in the other. Judged from the vessel's bag and a probe of
its ``/diagnostics`` in its namespace: discovery across works and the operator's commands
drive the vessel; a cut link (``ip link set DEV down``) ends in the command-loss failsafe
within the receiver's timeout, the vessel comes to rest; when the link returns the commands
drive again. Once with SUBNET discovery (multicast on the veth), once with LOCALHOST and
``ROS_STATIC_PEERS`` naming the other side (docs/deployment.md).

Needs root and ``ip`` (iproute2), as CI has; skipped otherwise, saying which.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
import os
from pathlib import Path
import shutil
import subprocess
import sys
import time
from typing import Any

import pytest
import yaml
from support.bags import read_bag, stamp
from support.cli import ENBARR
from support.processes import Output, stop

from enbarr_core.bringup.profile import resolve_profile

# alone (setup.cfg): a browser or two vessels take the machine; run after the parallel pass
pytestmark = [pytest.mark.e2e, pytest.mark.alone]

#: The private /30 of the tether (RFC 1918): the vessel's end and the operator's end.
VESSEL_IP, OPERATOR_IP, PREFIX = '10.200.0.1', '10.200.0.2', 30
#: The command receiver's failsafe timeout and goal rate (its defaults, which enbarr_sim keeps).
TIMEOUT, GOAL_PERIOD = 0.5, 0.1
#: How long the link stays cut once the failsafe was seen [s]: the vehicle brakes to rest.
OUTAGE = 4.0
#: Surge the topside asks for [m/s].
SURGE = 0.3
#: Largest thruster effort of a vehicle at rest (neutrally buoyant, trimmed level).
AT_REST = 0.02
WATCH = Path(__file__).parents[1] / 'support' / 'failsafe_watch.py'
TOPICS = ['/surface_command/twist', '/trajectory_request', '/thruster_output', '/diagnostics']


def _why_not() -> str | None:
    if sys.platform != 'linux':
        return 'network namespaces are Linux only'
    if os.geteuid() != 0:
        return 'needs root to create network namespaces (ip netns add)'
    if shutil.which('ip') is None:
        return 'needs ip (iproute2) to create network namespaces'
    return None


if _why_not():
    pytest.skip(_why_not(), allow_module_level=True)


def ip(*args: str) -> None:
    r = subprocess.run(['ip', *args], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, f'ip {" ".join(args)}: {r.stderr.strip()}'


@dataclass(frozen=True)
class Tether:
    """Two namespaces, one per computer, and the vessel's end of the cable."""

    vessel: str        # namespace of the vessel
    operator: str      # namespace of the operator's computer
    vessel_dev: str    # the vessel's veth: cut and restored by the test


@pytest.fixture(scope='module')
def tether() -> Iterator[Tether]:
    tag = f'{os.getpid() % 100000}'
    t = Tether(f'enbarr-v{tag}', f'enbarr-o{tag}', f'env{tag}')
    peer = f'eno{tag}'
    made: list[str] = []
    try:
        for ns in (t.vessel, t.operator):
            r = subprocess.run(['ip', 'netns', 'add', ns], capture_output=True, text=True)
            if r.returncode != 0:  # e.g. a container without CAP_SYS_ADMIN
                pytest.skip(f'cannot create a network namespace: {r.stderr.strip()}')
            made.append(ns)
        r = subprocess.run(['ip', 'link', 'add', t.vessel_dev, 'type', 'veth', 'peer', 'name',
                            peer], capture_output=True, text=True)
        if r.returncode != 0:  # a kernel without veth
            pytest.skip(f'cannot create a veth pair: {r.stderr.strip()}')
        ip('link', 'set', t.vessel_dev, 'netns', t.vessel)
        ip('link', 'set', peer, 'netns', t.operator)
        for ns, dev, addr in ((t.vessel, t.vessel_dev, VESSEL_IP),
                              (t.operator, peer, OPERATOR_IP)):
            ip('-n', ns, 'addr', 'add', f'{addr}/{PREFIX}', 'dev', dev)
            ip('-n', ns, 'link', 'set', 'lo', 'up')
            ip('-n', ns, 'link', 'set', dev, 'up')
        yield t
    finally:
        for ns in made:  # deleting a namespace deletes its end of the pair, and so the pair
            subprocess.run(['ip', 'netns', 'del', ns], capture_output=True)
        # a pair left here when moving it into the namespaces failed (else: no such device)
        subprocess.run(['ip', 'link', 'del', t.vessel_dev], capture_output=True)


def in_namespace(ns: str, domain: str, argv: list[str]) -> subprocess.Popen[str]:
    """Start ``argv`` in namespace ``ns`` (its own session), its merged output piped."""
    # ip netns exec execs the command: the process is the command itself
    return subprocess.Popen(['ip', 'netns', 'exec', ns, 'env', f'ROS_DOMAIN_ID={domain}',
                             *argv], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def write_profiles(tmp: Path, domain: str, discovery: str) -> tuple[Path, Path]:
    """The vessel's and the topside's profiles, in the test's domain and discovery mode."""
    if discovery == 'subnet':
        vessel_env = operator_env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
    else:  # LOCALHOST and the other side named: OFF would switch the static peers off too
        vessel_env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                      'ROS_STATIC_PEERS': OPERATOR_IP}
        operator_env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                        'ROS_STATIC_PEERS': VESSEL_IP}
    vessel = tmp / 'vessel.yaml'
    vessel.write_text(yaml.safe_dump({
        'profile': 'vessel', 'include': [str(resolve_profile('enbarr_sim'))],
        'environment': {**vessel_env, 'ROS_DOMAIN_ID': domain},
        'nodes': {'surface': {'enabled': False}}}))
    operator = tmp / 'topside.yaml'
    operator.write_text(yaml.safe_dump({
        'profile': 'topside', 'include': [str(resolve_profile('enbarr_rov_topside'))],
        'environment': {**operator_env, 'ROS_DOMAIN_ID': domain},
        'nodes': {'joystick': {'enabled': False}, 'gamepad': {'enabled': False},
                  'station': {'plugin': 'scripted_commands', 'group': 'operator',
                              'parameters': {'script': [f'0.0 twist {SURGE} 0 0 0 0 0']}}}}))
    return vessel, operator


@pytest.fixture(scope='module', params=['subnet', 'static_peers'])
def outage(request: pytest.FixtureRequest, tether: Tether, module_domain: str,
           tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Run both sides, cut the link once the commands drive, restore it; what was seen."""
    tmp = tmp_path_factory.mktemp(request.param)
    vessel_profile, operator_profile = write_profiles(tmp, module_domain, request.param)
    bag = tmp / 'bag'
    record = [a for t in TOPICS for a in ('--record-topic', t)]
    procs: list[subprocess.Popen[str]] = []
    seen: dict[str, Any] = {'bag': bag}
    try:
        vessel = in_namespace(tether.vessel, module_domain, [
            *ENBARR, 'bringup', '--profile', str(vessel_profile), '--output', str(bag),
            *record])
        procs.append(vessel)
        vessel_out = Output(vessel)
        vessel_out.wait_for(r'vessel running: ', 120)
        # The probe sees what the vessel's namespace sees: the profile's discovery settings
        probe_env = yaml.safe_load(vessel_profile.read_text())['environment']
        watch = in_namespace(tether.vessel, module_domain, [
            'env', *(f'{k}={v}' for k, v in probe_env.items()), sys.executable, str(WATCH)])
        procs.append(watch)
        watch_out = Output(watch)
        watch_out.wait_for('failsafe True', 60)  # nobody commands yet
        operator = in_namespace(tether.operator, module_domain, [
            *ENBARR, 'bringup', '--profile', str(operator_profile)])
        procs.append(operator)
        operator_out = Output(operator)
        operator_out.wait_for('topside running: station', 120)
        watch_out.wait_for('failsafe False', 60)  # across: discovered, and driving
        mark = len(watch_out.lines)
        seen['cut'] = time.time_ns()
        ip('-n', tether.vessel, 'link', 'set', tether.vessel_dev, 'down')
        watch_out.wait_for('failsafe True', 60, start=mark)
        time.sleep(OUTAGE)  # the outage itself, not a wait for a condition
        mark = len(watch_out.lines)
        seen['restored'] = time.time_ns()
        ip('-n', tether.vessel, 'link', 'set', tether.vessel_dev, 'up')
        watch_out.wait_for('failsafe False', 60, start=mark)  # driving again
        seen['recovered'] = time.time_ns()
        # The vessel's bag ends after the recovery: let it hold a second of driving
        time.sleep(1.0)
        seen['vessel_rc'] = stop(vessel)  # first: its bag ends with the commands driving
        seen['operator_rc'] = stop(operator)
        seen['log'] = vessel_out.text + operator_out.text
    finally:
        for p in procs:
            stop(p, timeout=20)
    seen['msgs'] = read_bag(bag)
    return seen


def test_both_sides_end_cleanly(outage: dict[str, Any]) -> None:
    assert outage['operator_rc'] == 0 and outage['vessel_rc'] == 0, outage['log'][-3000:]
    assert 'Traceback' not in outage['log']


def test_the_operators_commands_drive_the_vessel_across(outage: dict[str, Any]) -> None:
    before = [m for t, m in outage['msgs']['/trajectory_request'] if t < outage['cut']]
    assert any(m.twist.linear.x == pytest.approx(SURGE) for m in before)


def test_nothing_crosses_a_cut_link(outage: dict[str, Any]) -> None:
    # A command in flight when the link went down may still land: half a second of margin
    crossed = [t for t, _ in outage['msgs']['/surface_command/twist']
               if outage['cut'] + 500_000_000 < t < outage['restored']]
    assert not crossed


def test_a_cut_link_ends_in_the_failsafe_within_the_timeout(outage: dict[str, Any]) -> None:
    last = max(t for t, _ in outage['msgs']['/surface_command/twist'] if t < outage['restored'])
    # Goals are stamped with the receiver's clock when published: every goal stamped past the
    # last command's arrival plus the timeout (and a goal period, and one for the recorder's
    # arrival time against the receiver's) is zero, up to the link's return.
    deadline = last * 1e-9 + TIMEOUT + 2 * GOAL_PERIOD
    goals = [m for t, m in outage['msgs']['/trajectory_request']
             if stamp(m) > deadline and t < outage['restored']]
    assert goals, 'no goal published during the outage'
    assert all(m.twist.linear.x == 0.0 for m in goals)


def test_the_vessel_comes_to_rest_during_the_outage(outage: dict[str, Any]) -> None:
    last_second = [max(abs(e) for e in m.effort) for t, m in outage['msgs']['/thruster_output']
                   if outage['restored'] - 1_000_000_000 < t < outage['restored']]
    assert last_second and max(last_second) < AT_REST


def test_the_commands_drive_again_when_the_link_returns(outage: dict[str, Any]) -> None:
    after = [m for t, m in outage['msgs']['/trajectory_request'] if t > outage['recovered']]
    assert after and all(m.twist.linear.x == pytest.approx(SURGE) for m in after[-5:])
    failsafe = [kv.value for _, m in outage['msgs']['/diagnostics'] for s in m.status
                if s.hardware_id == 'command_receiver' for kv in s.values
                if kv.key == 'failsafe']
    # the receiver's own report: nobody yet, driving, lost, driving again
    changes = [v for i, v in enumerate(failsafe) if i == 0 or failsafe[i - 1] != v]
    assert changes == ['True', 'False', 'True', 'False']
