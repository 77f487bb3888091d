"""``enbarr calibrate pairs``' refusals, each one line naming what to change: the bag's
contents stand in by synthetic scans and images (``_feed_bag`` replaced), the parser is the
real one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from enbarr_core.commands import calibrate_pairs
from enbarr_core.commands import main as cli
from enbarr_core.commands.calibrate_lidar import read_pairs
from enbarr_core.world.model import Circle, Obstacle, World

pytestmark = pytest.mark.unit

RAYS = 360
ANGLES = -math.pi + np.arange(RAYS) * (2.0 * math.pi / RAYS)
SEC = 1_000_000_000


def scenes(places, hold_scans=11):
    """(stamp [ns], ranges, image) at 5 Hz: the post held at each place, then gone 0.4 s."""
    t = 0
    for xy, px in places:
        for _ in range(hold_scans):
            r = World([Obstacle('post', Circle(xy, 0.05))]).raycast((0.0, 0.0), ANGLES, 0.0)
            img = np.zeros((120, 160, 3), np.uint8)
            img[px[1] - 10:px[1] + 11, px[0] - 3:px[0] + 4] = (60, 160, 30)   # green
            yield t, r, img
            t += SEC // 5
        for _ in range(2):
            yield t, np.full(RAYS, np.inf), np.zeros((120, 160, 3), np.uint8)
            t += SEC // 5


PLACES = [((1.5, 0.4), (30, 60)), ((2.5, -0.5), (120, 58)), ((1.2, -0.3), (100, 65)),
          ((2.0, 0.6), (40, 59)), ((2.8, 0.1), (75, 57))]


@pytest.fixture
def bag(monkeypatch):
    """The stand-in bag: ``scenes(places)`` fed to the collector, as the bag's messages are."""
    def use(places, hold_scans=11):
        def feed(collector, bag, scan, image):
            for t, r, img in scenes(places, hold_scans):
                collector.add_scan(t, r, -math.pi, 2 * math.pi / RAYS)
                collector.add_image(t, img)
        monkeypatch.setattr(calibrate_pairs, '_feed_bag', feed)
    return use


def run(capsys, *args):
    rc = cli.main(['calibrate', 'pairs', '--bag', 'b', *args])
    out, err = capsys.readouterr()
    return rc, out, err.strip().splitlines()


def test_the_pairs_are_written_in_the_pnp_format(bag, capsys, tmp_path):
    bag(PLACES)
    csv = tmp_path / 'm.csv'
    rc, out, err = run(capsys, '--colour', 'green', '--mark-radius', '0.05', '-o', str(csv))
    assert rc == 0, err
    xy, uv = read_pairs(str(csv))
    assert xy == pytest.approx(np.array([p[0] for p in PLACES]), abs=2e-3)
    assert uv == pytest.approx(np.array([p[1] for p in PLACES], dtype=float))
    lines = csv.read_text().splitlines()
    assert lines[:2] == ['x,y,u,v', '# enbarr calibrate pairs from b, pixels by colour']
    assert lines[2] == '# place 0: 0.200 to 1.800 s, 9 scans, 9 of 9 images'


def test_a_mark_never_held_still(bag, capsys, tmp_path):
    bag(PLACES, hold_scans=4)     # 0.8 s at each place, 0.4 s of it inside the edges
    rc, _, err = run(capsys, '--colour', 'green', '-o', str(tmp_path / 'x.csv'))
    assert rc == 2 and len(err) == 1
    assert err[0] == ('enbarr calibrate: error: b: the mark was never held still for 1 s '
                      'within 0.08 m (20 of 30 scans showed one mark candidate)')


def test_no_blob_of_the_colour(bag, capsys, tmp_path):
    bag(PLACES)
    rc, _, err = run(capsys, '--colour', 'red', '-o', str(tmp_path / 'x.csv'))
    assert rc == 2 and err == ['enbarr calibrate: error: b: no blob of the colour in the 45 '
                               'images of the still places: check --colour or --hue (OpenCV '
                               'HSV), --min-area']


def test_too_few_pairs_says_how_many(bag, capsys, tmp_path):
    bag(PLACES[:3])
    rc, _, err = run(capsys, '--hue', '45,85', '-o', str(tmp_path / 'x.csv'))
    assert rc == 2 and err == ['enbarr calibrate: error: 3 pairs found (3 places held still): '
                               'PnP needs at least 4 (the manual suggests 10 to 20); hold the '
                               'mark still at more places']
    assert not (tmp_path / 'x.csv').exists()


def test_clicking_needs_a_display(bag, capsys, monkeypatch, tmp_path):
    monkeypatch.delenv('DISPLAY', raising=False)
    monkeypatch.delenv('WAYLAND_DISPLAY', raising=False)
    bag(PLACES)
    rc, _, err = run(capsys, '--pick', 'click', '-o', str(tmp_path / 'x.csv'))
    assert rc == 2 and err == ['enbarr calibrate: error: --pick click needs a display (no '
                               "$DISPLAY here): use --pick colour with the mark's colour, or "
                               'write the CSV x,y,u,v by hand (docs/calibration_lidar.md)']


@pytest.mark.parametrize('args, message', [
    (['--region', '1,2,3'], "--region '1,2,3': expected XMIN,XMAX,YMIN,YMAX"),
    (['--region', '2,1,0,1', '--colour', 'green'], '--region 2,1,0,1: expected xmin < xmax'),
    (['--colour', 'purple'], "--colour 'purple': one of red, green, yellow, orange"),
    ([], "--pick colour needs the mark's colour: --colour NAME or --hue LO,HI"),
    (['--hue', '200,10'], '--hue/--min-saturation/--min-value: hsv_lower: class'),
])
def test_options_are_checked(bag, capsys, args, message, tmp_path):
    bag(PLACES)
    rc, _, err = run(capsys, *args, '-o', str(tmp_path / 'x.csv'))
    assert rc == 2 and len(err) == 1 and message in err[0], err
