"""Node tier: every shipped profile and scenario builds, as ``bringup --check`` builds it
(``compose.validate``, in-process, in an isolated context: nothing opened or published).

Most scenarios are run whole by no test (``rov_leak``, ``rov_battery``, the ``*_heavy``
variants ...): a parameter renamed in a node, a plugin gone or a value out of its range in
one of their files fails here, naming the file and the key. A fragment and a keyboard
profile off a terminal are refused with the reason a user gets.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from enbarr_core.bringup.compose import validate
from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import ProfileError

pytestmark = pytest.mark.node

PARAMS = Path(__file__).resolve().parents[2] / 'params'
SHIPPED = sorted([*PARAMS.glob('*.yaml'), *(PARAMS / 'scenarios').glob('*.yaml')])
#: Refused here on purpose, with the reason a user reads.
REFUSED = {
    'core': 'a fragment, only for include',
    'saucer_core': 'a fragment, only for include',
    'saucer_ca_core': 'a fragment, only for include',
    'skiff_core': 'a fragment, only for include',
    # The keyboard reads the terminal bringup runs in; pytest's stdin is none.
    'enbarr_teleop': "node 'keyboard': standard input is not a terminal",
    'enbarr_rov_topside_keyboard': "node 'keyboard': standard input is not a terminal",
}


def test_the_shipped_files_are_all_here() -> None:
    names = {p.stem for p in SHIPPED}
    assert {'enbarr_sim', 'saucer_ca_sim', 'rov_leak', 'rov_battery', 'ca_buoy'} <= names
    assert set(REFUSED) <= names
    assert len(SHIPPED) >= 55


@pytest.mark.parametrize('path', SHIPPED, ids=lambda p: p.relative_to(PARAMS).as_posix())
def test_every_shipped_profile_builds(path: Path) -> None:
    if path.stem in REFUSED:
        with pytest.raises(ProfileError, match=REFUSED[path.stem]):
            validate(load_profile(str(path)))
        return
    profile = load_profile(str(path))
    checked = validate(profile)
    assert checked.nodes == len(profile.nodes) > 0
