"""Unit tests: ``enbarr check-device arduino`` against the emulated board, and its failures."""

from __future__ import annotations

import pytest

from enbarr_core.commands.main import main
from enbarr_core.framework.errors import DeviceError
from enbarr_plugins.arduino import firmware
from enbarr_plugins.arduino.emulator import ArduinoEmulator
from enbarr_plugins.arduino.check import check_device
from enbarr_plugins.check import CheckTarget


@pytest.fixture(scope='session', autouse=True)
def built() -> None:
    """Compile the firmware for the host once, before the unit tier forbids processes."""
    firmware.load()


@pytest.fixture
def board():
    b = ArduinoEmulator()
    b.start()
    yield b
    b.stop()


def test_check_emulated_prints_identity_and_the_acknowledged_neutral():
    lines = check_device(CheckTarget(port='emulated'))
    assert len(lines) == 2
    assert 'protocol 1, board id 0x4D45, 6 channels, watchdog 250 ms' in lines[0]
    assert 'acknowledged' in lines[1] and 'outputs neutral' in lines[1]


def test_check_a_pty_path_like_a_real_port(board):
    lines = check_device(CheckTarget(port=board.path))
    assert lines[0].startswith(f'{board.path}: Enbarr PWM board')
    assert board.counters()['frames'] >= 3  # HELLO_REQ, CONFIG, SET_DUTY


def test_check_absent_port_names_it():
    with pytest.raises(DeviceError, match='/dev/ttyNOPE: cannot open'):
        check_device(CheckTarget(port='/dev/ttyNOPE'))


def test_check_wrong_identity_names_port_and_value(board):
    board.wrong_identity(board_id=0x1234)
    with pytest.raises(DeviceError, match=f'{board.path}: not an Enbarr PWM board: read '
                                          'protocol 1, board id 0x1234'):
        check_device(CheckTarget(port=board.path))


def test_check_silent_board_is_no_hello(board):
    board.stall()
    with pytest.raises(DeviceError, match=f'{board.path}: no HELLO from the board within 0.4 s'):
        check_device(CheckTarget(port=board.path, timeout=0.4))


def test_cli_check_device_emulated_exits_0(capsys):
    assert main(['check-device', 'arduino', '--port', 'emulated']) == 0
    out = capsys.readouterr().out
    assert 'emulated: Enbarr PWM board, protocol 1, board id 0x4D45' in out


def test_cli_check_device_absent_exits_2_with_one_line(capsys):
    assert main(['check-device', 'arduino', '--port', '/dev/ttyNOPE']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('enbarr check-device: error: /dev/ttyNOPE:')
