"""The ROV's vehicle numbers live in its profiles only: a profile that does not give them is
refused before anything runs, with a ProfileError naming the parameter and a file of the
profile (the code has no default that would quietly stand in).
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from enbarr_core.bringup.compose import build_nodes
from enbarr_core.bringup.profile import load_profile
from enbarr_core.framework.errors import ProfileError

def test_a_profile_without_the_vehicle_is_refused_naming_it(context) -> None:
    profile = load_profile('enbarr_sim')
    without = {k: v for k, v in profile.parameters.items() if not k.startswith('vehicle.')}
    assert len(without) < len(profile.parameters)
    with pytest.raises(ProfileError) as info:
        build_nodes(replace(profile, parameters=without), context)
    err = info.value
    assert err.path in profile.files  # one of the profile's files (bringup's blame rule)
    assert "node 'control_loop': parameter 'vehicle.mass' is not set; the profile must give " \
        'it' in str(err)
