"""The vessel's deployment files (deploy/, docs/deployment.md): the systemd unit verifies, and
its command line runs the vessel profile as the service would (``--check``: the profile exists
and validates, bringup accepts the options, no device is opened); the udev rules name the
USB ids of the devices they are for.

e2e: the unit's command and ``systemd-analyze`` are processes.
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import shutil
import subprocess
import sys

import pytest

pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / 'deploy'
UNIT = DEPLOY / 'enbarr-vessel.service'
RULES = DEPLOY / '99-enbarr-serial.rules'
#: Where the unit expects the clone (docs/deployment.md): the tests put this tree there.
INSTALL = '/opt/enbarr'


def unit_entries(text: str) -> list[tuple[str, str, str]]:
    """(section, key, value) of every assignment of a unit file, in order (keys repeat)."""
    entries, section = [], ''
    for line in text.splitlines():
        line = line.strip()
        if not line or line[0] in '#;':
            continue
        m = re.fullmatch(r'\[(\w+)\]', line)
        if m:
            section = m.group(1)
            continue
        key, sep, value = line.partition('=')
        assert sep, f'{UNIT}: not an assignment: {line!r}'
        entries.append((section, key.strip(), value.strip()))
    return entries


def service(key: str) -> list[str]:
    return [v for s, k, v in unit_entries(UNIT.read_text()) if (s, k) == ('Service', key)]


def test_the_unit_verifies(tmp_path: Path) -> None:
    if shutil.which('systemd-analyze') is None:
        pytest.skip('systemd-analyze is not installed (systemd)')
    # The unit names the clone in /opt/enbarr: here, this tree (verify checks ExecStart)
    unit = tmp_path / UNIT.name
    unit.write_text(UNIT.read_text().replace(INSTALL, str(ROOT)))
    r = subprocess.run(['systemd-analyze', 'verify', '--man=no', str(unit)],
                       capture_output=True, text=True, timeout=60)
    # A misspelt key or a bad value is only a warning (exit 0): none may be printed
    assert r.returncode == 0 and not r.stderr.strip(), r.stderr


def test_the_unit_restarts_on_failure_but_not_a_refused_profile() -> None:
    assert service('Restart') == ['on-failure']
    assert service('RestartPreventExitStatus') == ['2']  # bringup's refusal (docs/profiles.md)
    assert service('KillMode') == ['mixed']  # bringup stops its own groups, thrusters neutral
    assert service('ExecStart') == [f'{INSTALL}/deploy/enbarr-vessel-run']


def test_the_units_command_runs_the_vessel_profile(tmp_path: Path) -> None:
    """The unit's ExecStart with its environment, ``--check`` added through ENBARR_ARGS."""
    env = dict(os.environ)
    for assignment in service('Environment'):
        for word in assignment.split():
            name, _, value = word.partition('=')
            env[name] = value.replace(INSTALL, str(ROOT))
    assert env['ENBARR_PROFILE'] == 'enbarr_rov'
    # The venv's console script, as on the Pi (./dev's venv here, or this interpreter's)
    if not Path(env['ENBARR']).exists():
        env['ENBARR'] = str(Path(sys.executable).with_name('enbarr'))
    data = tmp_path / 'data'
    env.update(ENBARR_DATA=str(data), ENBARR_ARGS='--check')
    (command,) = service('ExecStart')
    r = subprocess.run([command.replace(INSTALL, str(ROOT))], env=env, cwd=tmp_path,
                       stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    assert re.search(r'enbarr_rov\.yaml: ok \(\d+ nodes in 1 group\(s\)\)', r.stdout), r.stdout
    assert 'not checked: the devices' in r.stdout  # the IMU, the PWM board, the GPIO pins
    assert not data.exists()  # a check records nothing


def test_the_run_script_puts_each_run_in_a_new_bag_directory(tmp_path: Path) -> None:
    """What the script hands bringup: a bag directory named by the UTC start time."""
    fake = tmp_path / 'enbarr'
    fake.write_text('#!/bin/sh\nprintf "%s\\n" "$@"\n')
    fake.chmod(0o755)
    env = {**os.environ, 'ENBARR': str(fake), 'ENBARR_DATA': '/data',
           'ENBARR_ARGS': '--record-split-size 500'}
    env.pop('ENBARR_PROFILE', None)
    r = subprocess.run([str(DEPLOY / 'enbarr-vessel-run')], env=env, capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    args = r.stdout.splitlines()
    assert args[:4] == ['bringup', '--profile', 'enbarr_rov', '--output']
    assert re.fullmatch(r'/data/bags/\d{8}T\d{6}Z', args[4])
    assert args[5:] == ['--record-split-size', '500']


def test_the_udev_rules_name_the_devices_by_their_usb_ids() -> None:
    rules = [line for line in RULES.read_text().splitlines()
             if line.strip() and not line.startswith('#')]
    links = {}
    for rule in rules:
        keys = dict(re.findall(r'(\w+(?:\{\w+\})?)[=+]=?"([^"]*)"', rule))
        assert keys['SUBSYSTEM'] == 'tty' and keys['GROUP'] == 'dialout'
        links[keys['SYMLINK']] = (keys['ATTRS{idVendor}'], keys['ATTRS{idProduct}'])
    # Arduino SA's USB vendor id 0x2341, the Mega 2560 R3's product id 0x0042 (the by-id name
    # of docs/hardware.md); Silicon Labs' 0x10c4 and the CP2102's 0xea60 (the RPLidar A1's
    # USB bridge, Slamtec's A1 datasheet)
    assert links == {'enbarr-arduino': ('2341', '0042'), 'enbarr-lidar': ('10c4', 'ea60')}
