"""Running a shipped scenario as a user does, for the e2e tests that judge its bag."""

from __future__ import annotations

import json
from pathlib import Path
import subprocess
from typing import Any

from support.bags import read_bag
from support.cli import ENBARR

from enbarr_core.bringup.profile import load_profile

SCENARIOS = Path(__file__).resolve().parents[2] / 'params' / 'scenarios'


def run_scenario(name: str, out: Path) -> dict[str, Any]:
    """``enbarr scenario NAME`` as a user runs it; the profile as loaded and the bag."""
    proc = subprocess.run([*ENBARR, 'scenario', name, '--output', str(out), '--no-plot'],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    json.loads(proc.stdout.strip().splitlines()[-1])  # it finished and reported
    profile = load_profile(str(SCENARIOS / f'{name}.yaml'))
    return {'name': name, 'profile': profile, 'msgs': read_bag(out / 'bag')}
