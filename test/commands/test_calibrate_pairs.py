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


class _Clicks:
    """Stands in for the window: records what it was shown, answers as a user would."""

    def __init__(self, answers):
        self.answers = list(answers)
        self.shown = []

    def __call__(self, image, title, guess):
        from types import SimpleNamespace
        self.shown.append((image.shape, title, guess))
        answer = self.answers.pop(0)
        pixel = guess if answer == 'guess' else None
        return SimpleNamespace(pixel=pixel, skipped=answer == 'skip', quit=answer == 'quit')


CAMERA_INFO = """image_width: 160
image_height: 120
camera_name: test
camera_matrix: {rows: 3, cols: 3, data: [100.0, 0.0, 79.5, 0.0, 100.0, 59.5, 0.0, 0.0, 1.0]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [0.0, 0.0, 0.0, 0.0, 0.0]}
rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
projection_matrix: {rows: 3, cols: 4, data: [100, 0, 79.5, 0, 0, 100, 59.5, 0, 0, 0, 1, 0]}
"""


def test_click_shows_each_place_with_the_guess_and_takes_the_answers(bag, capsys, tmp_path,
                                                                     monkeypatch):
    from enbarr_core.vision import marks
    monkeypatch.setattr(calibrate_pairs, '_check_display', lambda: None)
    clicks = _Clicks(['guess', 'skip', 'guess', 'guess', 'guess'])
    monkeypatch.setattr(marks, 'show_for_click', clicks)
    cam = tmp_path / 'cam.yaml'
    cam.write_text(CAMERA_INFO)
    bag(PLACES)
    csv = tmp_path / 'm.csv'
    rc, out, err = run(capsys, '--pick', 'click', '--mark-radius', '0.05', '--profile',
                       'saucer_marks_sim', '--camera-info', str(cam), '-o', str(csv))
    assert rc == 0, err
    assert [s[0] for s in clicks.shown] == [(120, 160, 3)] * 5
    assert clicks.shown[0][1] == 'place 0 of 5: lidar (1.50, 0.40) m'
    # the guess: saucer_core.yaml's mounts (camera 8 cm behind and 10 cm above the lidar),
    # this 100 px pinhole: u = 79.5 - 100 y / (x + 0.08), v = 59.5 + 100 * 0.10 / (x + 0.08)
    x, y = PLACES[0][0]
    assert clicks.shown[0][2] == pytest.approx((79.5 - 100 * y / (x + 0.08),
                                                59.5 + 10.0 / (x + 0.08)), abs=0.1)
    assert 'place 1: (2.500, -0.500) m: left out (skipped)' in out
    xy, uv = read_pairs(str(csv))
    assert len(xy) == 4 and xy[1] == pytest.approx(PLACES[2][0], abs=2e-3)


def test_quitting_the_clicks_keeps_what_was_picked(bag, capsys, tmp_path, monkeypatch):
    from enbarr_core.vision import marks
    monkeypatch.setattr(calibrate_pairs, '_check_display', lambda: None)
    clicks = _Clicks(['guess', 'quit'])
    monkeypatch.setattr(marks, 'show_for_click', clicks)
    bag(PLACES)
    rc, _, err = run(capsys, '--pick', 'click', '-o', str(tmp_path / 'x.csv'))
    # no profile: no guess, so the stand-in user has nothing to click either
    assert rc == 2 and len(clicks.shown) == 2 and clicks.shown[0][2] is None
    assert err == ['enbarr calibrate: error: 0 pairs found (5 places held still): PnP needs at '
                   'least 4 (the manual suggests 10 to 20); hold the mark still at more places']


def test_a_display_without_an_interactive_backend_is_refused(bag, capsys, tmp_path,
                                                              monkeypatch):
    import matplotlib
    matplotlib.use('Agg')
    monkeypatch.setenv('DISPLAY', ':99')
    bag(PLACES)
    rc, _, err = run(capsys, '--pick', 'click', '-o', str(tmp_path / 'x.csv'))
    assert rc == 2 and err == ['enbarr calibrate: error: --pick click: matplotlib has no '
                               'interactive backend here (install python3-tk, or use --pick '
                               'colour)']
