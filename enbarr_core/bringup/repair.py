"""After a group was killed: make its recorder's bag whole as of its last flush."""

from __future__ import annotations

import logging

from enbarr_core.framework.errors import EnbarrError
from enbarr_core.bringup.compose import RECORDER_NODE
from enbarr_core.bringup.profile import Profile

log = logging.getLogger('enbarr.bringup')


def repair_recording(profile: Profile, group: str, how: str) -> None:
    """After ``group`` was killed: make its recorder's bag whole as of its last flush.

    A recorder killed while it rewrote its file's index (once per flush) leaves a torn tail
    that readers refuse; ``recording.bag.repair_bag`` cuts it and rebuilds the index. A bag
    that was intact is not written to.
    """
    from enbarr_core.recording.bag import repair_bag
    for n in profile.nodes:
        if n.name != RECORDER_NODE or n.group != group or 'path' not in n.parameters:
            continue
        path = str(n.parameters['path'])
        try:
            repaired = [r for r in repair_bag(path) if r.repaired or r.indexed]
        except EnbarrError as err:
            log.error('group %s died (%s): its bag could not be repaired: %s', group, how, err)
            continue
        for r in repaired:
            if r.repaired:
                log.warning('group %s died (%s) while writing %s: repaired, %d messages '
                            'kept, %d torn bytes cut', group, how, r.name, r.messages,
                            r.dropped_bytes)
            else:
                log.warning('group %s died (%s) while writing %s: intact, %d messages, its '
                            'index written', group, how, r.name, r.messages)
