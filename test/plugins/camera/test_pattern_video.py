"""End-to-end tier: the emulated camera's test video, written in a child process."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import pytest

from enbarr_plugins.camera import pattern_video
from enbarr_plugins.camera.pattern_video import read_counter, write_in_child

pytestmark = pytest.mark.e2e  # each test runs the writer as a child process


def test_the_child_writes_a_video_whose_frames_carry_their_numbers(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def not_here(*_: object) -> str:
        raise AssertionError('the video was written in this process')
    monkeypatch.setattr(pattern_video, 'write_test_video', not_here)
    path = write_in_child(str(tmp_path), 320, 240, 15.0, 6)
    assert path == str(tmp_path / 'test_pattern.avi') and not list(tmp_path.glob('*partial*'))
    cap = cv2.VideoCapture(path)
    counters = []
    ok, frame = cap.read()
    while ok:
        assert frame.shape == (240, 320, 3)
        counters.append(read_counter(frame))
        ok, frame = cap.read()
    cap.release()
    assert counters == list(range(6))


def test_a_failure_in_the_child_is_an_error_naming_it(tmp_path: Path) -> None:
    missing = tmp_path / 'no' / 'such' / 'directory'
    with pytest.raises(OSError, match=f'{missing}.*OpenCV cannot write Motion-JPEG AVI'):
        write_in_child(str(missing), 320, 240, 15.0, 3)


def test_the_child_runs_this_copy_of_the_package(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv('PYTHONPATH', '/elsewhere')
    path = pattern_video.child_environment()['PYTHONPATH'].split(os.pathsep)
    here = Path(pattern_video.__file__).resolve().parents[2]
    assert path == [str(here), '/elsewhere'] and (here / 'enbarr_plugins').is_dir()
