"""A second vessel process on one ROS graph with the same node names is refused.

Two real ``bringup`` processes of one profile in one domain: before the fix both ran and
fought over the same topics (a vehicle followed the other run's commands against its own).
"""

from __future__ import annotations

import time
from pathlib import Path

from support.processes import bringup, split_profile, stop

SPLIT_PROFILE = split_profile({'restart_limit': 1, 'restart_delay': 0.2})


def test_second_bringup_of_a_profile_is_refused_before_it_starts() -> None:
    with bringup('--profile', 'enbarr_sim') as (first, first_out):
        first_out.wait_for(r'thrust +[1-9]\d*\.\d N', 90)  # the first one drives
        with bringup('--profile', 'enbarr_sim') as (second, second_out):
            rc = second.wait(timeout=90)
        time.sleep(0.3)
        text = second_out.text
        assert rc == 2, text[-3000:]
        assert 'Traceback' not in text
        assert 'already runs node(s) /' in text and '/command_receiver' in text, text[-3000:]
        assert 'refusing to start a second vessel' in text
        assert ' running: ' not in text  # no source started, nothing published
        assert 'neutral' not in text  # no safe state published into the first one's graph
        mark = len(first_out.lines)
        first_out.wait_for(r'thrust +[1-9]\d*\.\d N', 30, mark)  # the first drives on
        assert first.poll() is None
        assert 'must stop' not in first_out.text
        assert stop(first) == 0


def test_one_of_two_simultaneous_bringups_stops(tmp_path: Path) -> None:
    # Started together, they may miss each other at start (discovery is 0.2 s or 2.5 s):
    # then their claims decide, the later one stops. Either way they do not both run.
    with bringup('--profile', 'enbarr_sim') as (a, a_out), \
            bringup('--profile', 'enbarr_sim') as (b, b_out):
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and a.poll() is None and b.poll() is None:
            time.sleep(0.2)
        time.sleep(8.0)  # a late claim has arrived by now
        codes = [a.poll(), b.poll()]
        assert 2 in codes, (codes, a_out.text[-2000:], b_out.text[-2000:])
        for p, out in ((a, a_out), (b, b_out)):
            if p.poll() is not None:
                assert p.returncode == 2 and 'Traceback' not in out.text, out.text[-3000:]
        for p in (a, b):
            stop(p)


def test_groups_of_one_split_profile_are_not_duplicates(tmp_path: Path) -> None:
    # Two supervisors of one split profile: the second one's groups are refused (exit 2),
    # the first one's own groups never refuse each other.
    profile = tmp_path / 'split.yaml'
    profile.write_text(SPLIT_PROFILE)
    with bringup('--profile', str(profile)) as (first, first_out):
        first_out.wait_for(r'thrust +[1-9]\d*\.\d N', 90)
        with bringup('--profile', str(profile)) as (second, second_out):
            assert second.wait(timeout=90) == 2, second_out.text[-3000:]
        assert 'refusing to start a second vessel' in second_out.text
        assert first.poll() is None
        assert stop(first) == 0
