#!/usr/bin/env python3
"""Record the lidar perception's input in a running profile, then replay it through the pipeline.

The pipeline's CPU per scan inside a running profile is about 1.7x what a back-to-back
benchmark shows on the 2-core VM (docs/benchmarks.md, "Collision avoidance in the whole
profile"): between two scans 182 ms apart the caches go cold. ``replay`` sleeps between scans
for that reason, and ``--check`` compares the obstacles of every scan with a saved reference,
so that a change meant to make the pipeline cheaper is shown to give the same obstacles.

    export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=42
    .venv/bin/python scripts/perception_replay.py record saucer_ca_sim /tmp/scans.pkl --seconds 45
    .venv/bin/python scripts/perception_replay.py replay /tmp/scans.pkl --save /tmp/ref.pkl
    # ... change enbarr_core/perception ...
    .venv/bin/python scripts/perception_replay.py replay /tmp/scans.pkl --check /tmp/ref.pkl

The files are pickles of this machine's own run: read only files you wrote.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import math
import pickle
import statistics
import sys
import time
from typing import Any


def record(profile: str, out: str, seconds: float) -> None:
    """Run ``profile`` under bringup in this process and keep every scan's pipeline input."""
    from enbarr_core.commands.main import main
    from enbarr_core.perception import pipeline

    calls: list[Any] = []
    process = pipeline.ScanObstacles.process

    def recording(self: Any, *args: Any, **kwargs: Any) -> Any:
        calls.append((copy.deepcopy(args), copy.deepcopy(kwargs), self.settings))
        return process(self, *args, **kwargs)

    pipeline.ScanObstacles.process = recording  # type: ignore[method-assign]
    try:
        main(['bringup', '--profile', profile, '--duration', str(seconds)])
    finally:
        with open(out, 'wb') as f:
            pickle.dump(calls, f)
        print(f'{len(calls)} scans written to {out}', file=sys.stderr)


def _rows(outcome: Any) -> list[tuple[Any, ...]]:
    return [dataclasses.astuple(o) for o in outcome.obstacles]


def replay(path: str, repeat: int, sleep_ms: float, save: str | None,
           check: str | None) -> int:
    """Replay the scans ``repeat`` times; print thread CPU per scan; save or check obstacles."""
    from enbarr_core.perception.pipeline import ScanObstacles

    with open(path, 'rb') as f:
        calls = pickle.load(f)
    if not calls:
        print(f'{path}: no scans', file=sys.stderr)
        return 1
    per_scan, outcomes = [], []
    for _ in range(repeat):
        pipe = ScanObstacles(calls[0][2])
        outcomes, cpu = [], 0.0
        for args, kwargs, _settings in calls:
            start = time.thread_time()
            outcomes.append(_rows(pipe.process(*args, **kwargs)))
            cpu += time.thread_time() - start
            if sleep_ms > 0.0:
                time.sleep(sleep_ms * 1e-3)
        per_scan.append(cpu / len(calls) * 1e3)
    print(f'{len(calls)} scans, {repeat} passes, {sleep_ms:g} ms between scans: '
          f'{min(per_scan):.3f} ms per scan best, {statistics.median(per_scan):.3f} median')
    if save:
        with open(save, 'wb') as f:
            pickle.dump(outcomes, f)
    if check:
        with open(check, 'rb') as f:
            reference = pickle.load(f)
        worst = _compare(reference, outcomes)
        if worst is None:
            return 1
        print(f'the same obstacles in every scan; largest difference {worst:.3g}')
    return 0


def _compare(reference: list[Any], outcomes: list[Any]) -> float | None:
    worst = 0.0
    for k, (want, got) in enumerate(zip(reference, outcomes)):
        if len(want) != len(got):
            print(f'scan {k}: {len(got)} obstacles, the reference has {len(want)}')
            return None
        for a, b in zip(want, got):
            for u, v in zip(_flat(a), _flat(b)):
                if isinstance(u, float) and isinstance(v, float):
                    if not (u == v or (math.isnan(u) and math.isnan(v))):
                        worst = max(worst, abs(u - v))
                elif u != v:
                    print(f'scan {k}: {b} differs from the reference {a}')
                    return None
    return worst


def _flat(row: tuple[Any, ...]) -> list[Any]:
    out: list[Any] = []
    for v in row:
        out.extend(_flat(v) if isinstance(v, tuple) else [v])
    return out


def main() -> int:
    """Parse the command line and run."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest='what', required=True)
    r = sub.add_parser('record', help='run a profile and keep every scan the perception took')
    r.add_argument('profile')
    r.add_argument('out', help='the pickle to write')
    r.add_argument('--seconds', type=float, default=45.0)
    q = sub.add_parser('replay', help='replay recorded scans through the pipeline')
    q.add_argument('scans', help='a pickle written by record')
    q.add_argument('--repeat', type=int, default=7, help='passes (default 7)')
    q.add_argument('--sleep-ms', type=float, default=2.0,
                   help='between scans, so that caches go cold as in a run (default 2)')
    q.add_argument('--save', help='write the obstacles of every scan here (a reference)')
    q.add_argument('--check', help='compare the obstacles of every scan with this reference')
    args = p.parse_args()
    if args.what == 'record':
        record(args.profile, args.out, args.seconds)
        return 0
    return replay(args.scans, args.repeat, args.sleep_ms, args.save, args.check)


if __name__ == '__main__':
    sys.exit(main())
