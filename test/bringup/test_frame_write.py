"""Writing a calibrated frame back into a profile (pure): one entry changes, nothing else."""

from __future__ import annotations

import difflib
import math
from pathlib import Path
import shutil

import pytest

from enbarr_core.bringup.frame_write import entry_text, write_fragment, write_frame
from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import ProfileError
from enbarr_core.framework.frames import Transform

PARAMS = Path(__file__).resolve().parents[2] / 'params'
CALIBRATED = Transform.from_rpy((-0.0712, 0.0043, 0.2391), (0.0123, -0.0345, 0.0067))

pytestmark = pytest.mark.unit


@pytest.fixture
def saucer(tmp_path: Path) -> Path:
    """The shipped saucer profiles, copied (the write must not touch the tree's files)."""
    for name in ('saucer_core.yaml', 'saucer_sim.yaml'):
        shutil.copy(PARAMS / name, tmp_path / name)
    return tmp_path


def test_the_entry_is_rewritten_in_place_and_reads_back(saucer: Path) -> None:
    core = saucer / 'saucer_core.yaml'
    before = core.read_text()
    written = write_frame(str(saucer / 'saucer_sim.yaml'), 'camera_link', CALIBRATED,
                          note='calibrated (test)')
    assert written.path == str(core)
    after = core.read_text()
    # one line changed, the rest of the file (its comments) byte for byte
    diff = [d for d in difflib.ndiff(before.splitlines(), after.splitlines())
            if d.startswith(('-', '+'))]
    assert len(diff) == 2, diff
    assert diff[0].startswith('-   camera_link: {parent: base_link, xyz: [-0.08, 0.0, 0.25]}')
    assert diff[1] == ('+   camera_link: {parent: base_link, xyz: [-0.0712, 0.0043, 0.2391], '
                       'rpy: [0.0123, -0.0345, 0.0067]}   # calibrated (test)')
    tree = load_profile(str(saucer / 'saucer_sim.yaml')).frames
    assert tree.frame('camera_link').transform.is_close(CALIBRATED, tol=1e-6)
    assert tree.frame('camera_link').parent == 'base_link'


def test_a_block_entry_keeps_the_comment_on_its_key_line(saucer: Path) -> None:
    core = saucer / 'saucer_core.yaml'
    before = core.read_text()
    t = Transform.from_rpy((0.0, 0.0, 0.0), (-math.pi / 2, 0.0, -math.pi / 2 + 0.01))
    write_frame(str(saucer / 'saucer_sim.yaml'), 'camera_optical_frame', t)
    after = core.read_text()
    assert '  camera_optical_frame:                                       # REP-103' in after
    assert after.count('\n') == before.count('\n') - 1   # two lines became one
    assert '  mocap_body: {parent: base_link}' in after
    tree = load_profile(str(saucer / 'saucer_sim.yaml')).frames
    assert tree.frame('camera_optical_frame').transform.is_close(t, tol=1e-6)


def test_a_quaternion_entry_stays_a_quaternion(tmp_path: Path) -> None:
    p = tmp_path / 'v.yaml'
    p.write_text('profile: v\nnodes: {frames: {plugin: frame_publisher}}\n'
                 'frames:\n  base_link: {}\n'
                 '  cam: {parent: base_link, quaternion: [0.0, 0.0, 0.0, 1.0]}  # guess\n')
    write_frame(str(p), 'cam', CALIBRATED)
    text = p.read_text()
    assert 'quaternion: [' in text and 'rpy' not in text and '# guess' in text
    tree = load_profile(str(p)).frames
    assert tree.frame('cam').transform.is_close(CALIBRATED, tol=1e-6)


def test_an_entry_set_in_two_files_is_refused(saucer: Path) -> None:
    sim = saucer / 'saucer_sim.yaml'
    sim.write_text(sim.read_text() + '\nframes:\n  camera_link: {xyz: [-0.1, 0.0, 0.3]}\n')
    before = (saucer / 'saucer_core.yaml').read_text()
    with pytest.raises(ProfileError, match='frames.camera_link is set in .* and in .*'
                                           '--fragment'):
        write_frame(str(sim), 'camera_link', CALIBRATED)
    assert (saucer / 'saucer_core.yaml').read_text() == before


def test_a_dynamic_or_missing_frame_is_refused(saucer: Path) -> None:
    sim = str(saucer / 'saucer_sim.yaml')
    with pytest.raises(ProfileError, match='root or dynamic'):
        write_frame(sim, 'base_link', CALIBRATED)
    with pytest.raises(Exception, match="no frame 'camera'"):
        write_frame(sim, 'camera', CALIBRATED)


def test_the_fragment_merges_over_the_entry(saucer: Path) -> None:
    frag = saucer / 'saucer_extrinsics.yaml'
    write_fragment(str(frag), 'camera_link', 'base_link', CALIBRATED, note='test')
    sim = saucer / 'saucer_sim.yaml'
    sim.write_text(sim.read_text().replace('include: [saucer_core.yaml]',
                                           'include: [saucer_core.yaml, saucer_extrinsics.yaml]'))
    tree = load_profile(str(sim)).frames
    assert tree.frame('camera_link').transform.is_close(CALIBRATED, tol=1e-6)
    with pytest.raises(ProfileError, match='a fragment'):
        load_profile(str(frag))


def test_entry_text_is_what_frames_parses() -> None:
    assert entry_text('base_link', Transform.from_rpy((1.0, 0.0, -0.5), (0.0, 0.0, 0.25))) == \
        '{parent: base_link, xyz: [1.0, 0.0, -0.5], rpy: [0.0, 0.0, 0.25]}'
