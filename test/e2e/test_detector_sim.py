"""``saucer_detector_sim`` as a user runs it (a real process): the simulated camera draws the
ca_buoy world's orange buoy ahead and the detector, with its default parameters, answers every
frame; judged from the bag.
"""

from __future__ import annotations

import subprocess
from typing import Any

import numpy as np
import pytest
from support.bags import read_bag
from support.cli import ENBARR

from enbarr_interfaces.detections import from_cloud

# alone (setup.cfg): judged against real time, the emulators starve beside another worker
pytestmark = [pytest.mark.e2e, pytest.mark.alone]

DURATION = 15.0
TOPICS = ['/detections', '/camera/camera_info', '/diagnostics']   # not the images


@pytest.fixture(scope='module')
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    bag = tmp_path_factory.mktemp('saucer_detector_sim') / 'bag'
    record = [a for t in TOPICS for a in ('--record-topic', t)]
    proc = subprocess.run(
        [*ENBARR, 'bringup', '--profile', 'saucer_detector_sim', '--duration', str(DURATION),
         '--output', str(bag), *record], capture_output=True, text=True, timeout=150)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return {'msgs': read_bag(bag), 'log': proc.stderr + proc.stdout}


def ns(msg: Any) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_every_frame_is_answered_with_its_stamp_and_the_buoy(run: dict[str, Any]) -> None:
    assert 'Traceback' not in run['log']
    frames = {ns(m) for _, m in run['msgs']['/camera/camera_info']}
    clouds = [m for _, m in run['msgs']['/detections']]
    assert len(clouds) >= 5 * DURATION          # the camera draws 15 frames a second
    assert {ns(c) for c in clouds} <= frames    # each the stamp of a frame the camera sent
    orange = 3                                   # class_names: red, green, yellow, orange
    seen = [from_cloud(c) for c in clouds]
    with_buoy = [rows for rows in seen if len(rows)]
    # the buoy is ahead at the start of the path; the vessel turns away from it later
    assert len(with_buoy) >= 0.5 * len(seen)
    for rows in with_buoy:
        assert set(rows['class_id'].tolist()) == {orange}
        assert np.all(rows['x_min'] >= 0) and np.all(rows['x_max'] <= 640)
        assert np.all(rows['y_max'] - rows['y_min'] > rows['x_max'] - rows['x_min'])  # upright


def test_the_detector_reports_no_fault(run: dict[str, Any]) -> None:
    last = None
    for _, m in run['msgs']['/diagnostics']:
        for s in m.status:
            if s.hardware_id == 'detector':
                last = (s.level, {v.key: v.value for v in s.values})
    assert last is not None
    level, values = last
    assert level == 0 and values['backend_failures'] == '0' and values['bad_images'] == '0'
    assert int(values['answered']) == int(values['frames']) > 0
