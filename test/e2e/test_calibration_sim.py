"""The manual's camera calibration (4.1) rehearsed in simulation, as a user runs it:
``enbarr bringup --profile saucer_calibration_sim`` in one process, ``enbarr calibrate camera
--commit`` live against it in another, and the calibration the simulated camera stored in its
calibration_file close to the lens it draws."""

from __future__ import annotations

from pathlib import Path
import re
import time

import pytest

from enbarr_plugins.camera.calibration import load_calibration
from support.cli import enbarr
from support.processes import bringup, stop

pytestmark = pytest.mark.e2e

# The lens sim_camera draws by default (its parameters: 640 x 480, focal_length 500 px,
# centred, the mild barrel k1 -0.12, k2 0.02), typed here rather than read from the code.
TRUE_FX = TRUE_FY = 500.0
TRUE_CX, TRUE_CY = 319.5, 239.5


def test_calibrate_camera_commit_against_the_simulated_camera(tmp_path: Path):
    path = tmp_path / 'saucer_camera.yaml'
    with bringup('--profile', 'saucer_calibration_sim', '--set',
                 f'camera.calibration_file={path}') as (camera, out):
        out.wait_for(r'saucer_calibration_sim running', 120)
        start = time.monotonic()
        result = enbarr('calibrate', 'camera', '--commit', '--views', '10', '--timeout', '60',
                        '--duration', '120', timeout=300)
        took = time.monotonic() - start
        assert result.returncode == 0, result.stderr[-3000:]
        assert stop(camera) == 0, out.text[-3000:]
    # the profile's ten poses cover the image fully: the run ends on its coverage
    assert 'coverage X 1.00 Y 1.00 Size 1.00 Skew 1.00' in result.stdout, result.stdout
    assert 'coverage incomplete' not in result.stderr
    assert f'committed to camera/set_camera_info: stored in {path}' in result.stdout
    rms = float(re.search(r'reprojection RMS ([0-9.]+) px', result.stdout).group(1))
    cal = load_calibration(str(path))
    fx, cx, fy, cy = cal.k[0], cal.k[2], cal.k[4], cal.k[5]
    print(f'calibrate camera took {took:.1f} s: fx {fx:.3f} fy {fy:.3f} cx {cx:.3f} '
          f'cy {cy:.3f} RMS {rms:.3f} px')
    assert fx == pytest.approx(TRUE_FX, rel=0.005)
    assert fy == pytest.approx(TRUE_FY, rel=0.005)
    assert cx == pytest.approx(TRUE_CX, rel=0.005)
    assert cy == pytest.approx(TRUE_CY, rel=0.005)
    assert rms < 0.3
    assert (cal.width, cal.height) == (640, 480)
