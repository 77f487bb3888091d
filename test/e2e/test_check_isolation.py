"""A check touches nothing, and a check or a refused second run never disturbs a running vessel.

- ``bringup --check`` of the real-hardware profiles opens no device, no file under /dev and no
  socket of its own (every driver opens its device at start, none at construction), and says
  which devices it did not check.
- A check of ``enbarr_rov`` (whose profile asks for SUBNET discovery: its topside is another
  machine) sends not one packet out of the machine: its DDS participant discovers nobody.
- Beside a running ``saucer_sim`` in guidance, a ``--check`` of the same profile and a second
  ``bringup`` (refused as a duplicate) leave the vessel in guidance: before, both knocked it
  to manual (the refused run had built its nodes on the live graph, its controller latched
  ``mode: manual`` and its joystick made the running one's contested).
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from support.bags import read_bag
from support.cli import ENBARR, enbarr
from support.processes import bringup

ROOT = Path(__file__).resolve().parents[2]

# A Python that runs ``enbarr`` with an audit hook recording every file it opens under /dev
# and every socket it connects or binds (Python's own audit events: DDS's sockets, opened by
# the middleware in C, are not among them; what a check may not do is open a device or talk
# to a host, which drivers do from Python).
AUDITED = textwrap.dedent("""
    import json, sys
    seen = []
    def hook(event, args):
        if event == 'open' and isinstance(args[0], (str, bytes)):
            path = args[0].decode() if isinstance(args[0], bytes) else args[0]
            if path.startswith('/dev/') and path not in ('/dev/null', '/dev/urandom'):
                seen.append(['open', path])
        elif event in ('socket.connect', 'socket.bind', 'socket.sendto'):
            seen.append([event, repr(args[1])])
    sys.addaudithook(hook)
    from enbarr_core.commands.main import main
    try:
        code = main(sys.argv[1:])
    finally:
        print('AUDIT ' + json.dumps(seen), flush=True)
    sys.exit(code)
""")


def audited_check(profile: str, *extra: str) -> tuple[subprocess.CompletedProcess[str], list]:
    import json
    result = subprocess.run([sys.executable, '-c', AUDITED, 'bringup', '--profile', profile,
                             '--check', *extra], capture_output=True, text=True, timeout=120,
                            stdin=subprocess.DEVNULL)
    line = next(ln for ln in result.stdout.splitlines() if ln.startswith('AUDIT '))
    return result, json.loads(line[len('AUDIT '):])


@pytest.mark.parametrize('profile, devices', [
    ('saucer', ('arduino', 'lidar', 'camera', 'mocap', 'joystick')),
    ('enbarr_rov', ('imu', 'thruster_control', 'depth', 'leak', 'battery', 'hull')),
])
def test_a_check_of_a_hardware_profile_opens_no_device_and_no_socket(profile, devices):
    result, seen = audited_check(profile)
    assert result.returncode == 0, result.stderr[-3000:]
    assert seen == [], seen
    assert 'Traceback' not in result.stderr and ' ERROR' not in result.stderr, result.stderr
    out = result.stdout
    assert re.search(r': ok \(\d+ nodes in \d+ group\(s\)\)', out), out
    said = next(ln for ln in out.splitlines() if ln.startswith('not checked: the devices'))
    for name in devices:
        assert f'{name} (' in said, said
    assert 'enbarr check-device' in said


def test_a_check_of_a_simulated_profile_has_no_devices_to_leave_alone():
    result = enbarr('bringup', '--profile', 'saucer_sim', '--check')
    assert result.returncode == 0, result.stderr[-3000:]
    assert 'not checked' not in result.stdout, result.stdout


# -- nothing leaves the machine ----------------------------------------------------------------
NS_HOST, NS_PEER = 'enbchk-a', 'enbchk-b'

# Counts the UDP packets that arrive on an interface until a line comes on stdin (a raw
# packet socket: no capture tool needed).
SNIFF = textwrap.dedent("""
    import select, socket, struct, sys
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.ntohs(3))
    s.bind((sys.argv[1], 0))
    print('ready', flush=True)
    seen = {}
    while True:
        ready, _, _ = select.select([s, sys.stdin], [], [])
        if sys.stdin in ready:
            break
        pkt = s.recv(65535)
        if struct.unpack('!H', pkt[12:14])[0] == 0x0800 and pkt[23] == 17:
            key = socket.inet_ntoa(pkt[30:34]) + ':' + str(struct.unpack('!H', pkt[36:38])[0])
            seen[key] = seen.get(key, 0) + 1
    print(sum(seen.values()), sorted(seen.items()), flush=True)
""")

# A plain participant with the profile's SUBNET range: the positive control.
PARTICIPANT = textwrap.dedent("""
    import time
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    context = Context()
    rclpy.init(context=context)
    node = Node('neighbour_probe', context=context)
    time.sleep(3.0)
    node.destroy_node()
    rclpy.try_shutdown(context=context)
""")


def _ip(*args: str) -> None:
    subprocess.run(['ip', *args], check=True, capture_output=True)


@pytest.fixture
def two_hosts():
    """Two network namespaces joined by a veth pair: the vessel's and a neighbour's.

    Private addresses inside the namespaces only; both deleted afterwards.
    """
    if os.geteuid() != 0 or shutil.which('ip') is None:
        pytest.skip('network namespaces need root and iproute2 (CI runs as root)')
    for ns in (NS_HOST, NS_PEER):
        subprocess.run(['ip', 'netns', 'del', ns], capture_output=True)
    try:
        _ip('netns', 'add', NS_HOST)
        _ip('netns', 'add', NS_PEER)
        _ip('link', 'add', 'enbchk0', 'type', 'veth', 'peer', 'name', 'enbchk1')
        _ip('link', 'set', 'enbchk0', 'netns', NS_HOST)
        _ip('link', 'set', 'enbchk1', 'netns', NS_PEER)
        for ns, dev, addr in ((NS_HOST, 'enbchk0', '10.231.0.1/24'),
                              (NS_PEER, 'enbchk1', '10.231.0.2/24')):
            _ip('netns', 'exec', ns, 'ip', 'addr', 'add', addr, 'dev', dev)
            _ip('netns', 'exec', ns, 'ip', 'link', 'set', dev, 'up')
            _ip('netns', 'exec', ns, 'ip', 'link', 'set', 'lo', 'up')
        # Multicast (DDS discovery) leaves through the veth, as on a vessel's network.
        _ip('netns', 'exec', NS_HOST, 'ip', 'route', 'add', '224.0.0.0/4', 'dev', 'enbchk0')
        yield
    finally:
        for ns in (NS_HOST, NS_PEER):
            subprocess.run(['ip', 'netns', 'del', ns], capture_output=True)


def udp_packets_during(*command: str) -> tuple[int, subprocess.CompletedProcess[str]]:
    """Run ``command`` in the vessel's namespace; count the UDP packets the neighbour got."""
    sniffer = subprocess.Popen(['ip', 'netns', 'exec', NS_PEER, sys.executable, '-c', SNIFF,
                                'enbchk1'], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               text=True)
    try:
        assert sniffer.stdout is not None and sniffer.stdout.readline().strip() == 'ready'
        env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
        run = subprocess.run(['ip', 'netns', 'exec', NS_HOST, *command], env=env,
                             capture_output=True, text=True, timeout=120,
                             stdin=subprocess.DEVNULL)
        time.sleep(0.5)  # a packet sent at the very end is on the wire by now
        out, _ = sniffer.communicate('stop\n', timeout=10)
    finally:
        if sniffer.poll() is None:
            sniffer.kill()
            sniffer.wait()
    return int(out.split()[0]), run


def test_a_check_of_a_subnet_profile_sends_nothing_out_of_the_machine(two_hosts):
    """enbarr_rov sets SUBNET discovery (its topside is another machine); validating it
    must still not announce anything on the network."""
    packets, check = udp_packets_during(*ENBARR, 'bringup', '--profile', 'enbarr_rov',
                                        '--check')
    assert check.returncode == 0, check.stderr[-3000:]
    assert packets == 0
    # The neighbour does hear a participant that is not a check: the sniffer is not blind.
    packets, probe = udp_packets_during(sys.executable, '-c', PARTICIPANT)
    assert probe.returncode == 0, probe.stderr[-3000:]
    assert packets > 0


# -- beside a running vessel -------------------------------------------------------------------

def test_a_check_and_a_refused_run_leave_a_running_vessel_in_guidance(tmp_path: Path):
    bag = tmp_path / 'bag'
    # Generous staleness limits: on a loaded machine the other processes' start can starve
    # the vessel of CPU long enough to trip the joystick or estimate timeout, which is not
    # what this test is about (a contested joystick and a latched mode do not wait for them).
    with bringup('--profile', 'saucer_sim', '--output', str(bag), '--set',
                 'dp_control.joy_timeout=5.0', '--set',
                 'dp_control.estimate_max_age=5.0') as (vessel, out):
        out.wait_for(r'mode automatic -> guidance', 120)  # 20 s into the script
        mark = len(out.lines)
        t0 = time.time_ns()
        check = enbarr('bringup', '--profile', 'saucer_sim', '--check', timeout=120)
        assert check.returncode == 0, check.stderr[-3000:]
        second = enbarr('bringup', '--profile', 'saucer_sim', '--duration', '5', timeout=120)
        assert second.returncode == 2, second.stderr[-3000:]
        assert 'refusing to start a second vessel' in second.stderr
        time.sleep(3.0)  # what a disturbance does, it has done by now
        t1 = time.time_ns()
        assert vessel.poll() is None
        vessel.send_signal(signal.SIGINT)
        assert vessel.wait(timeout=60) == 0, out.text[-3000:]
    after = ''.join(out.lines[mark:])
    assert 'contested' not in after and 'mode guidance ->' not in after, after[-3000:]
    recorded = read_bag(bag)
    modes = [m.data for t, m in recorded['/mode'] if t0 <= t <= t1]
    assert modes == [], modes  # no mode was latched into the running vessel's graph
    forces = [t for t, _ in recorded['/force_command'] if t0 <= t <= t1]
    gaps = [(b - a) / 1e9 for a, b in zip(forces, forces[1:])]
    assert forces and max(gaps) < 1.0, max(gaps)  # it stopped for 1.5 s when disturbed
