"""A Foxglove client for benchmarks: subscribe to a few topics of a bridge and count them.

    python3 scripts/foxglove_client.py [--port 8765] [--seconds 26] [--topics /scan ...]

Waits (up to a minute) for the ``foxglove_bridge`` at ``ws://127.0.0.1:PORT`` to serve,
takes two seconds of advertisements, subscribes to the ``--topics`` it found and reads for
``--seconds`` (or until the server goes away), then prints one JSON line: each topic's
messages per second and the bytes per second received. Stands in for Foxglove during
``enbarr bench --profile`` (docs/benchmarks.md, "Foxglove"): start it, then the bench.
Speaks the protocol with the ``websockets`` test dependency (requirements-test.txt).
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import time

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

#: The topics Foxglove's Saucer layout shows (docs/foxglove_saucer_layout.json) and /tf.
TOPICS = ['/scan', '/observer/odometry', '/mode', '/diagnostics', '/obstacles/markers', '/tf']


def main() -> int:
    """Parse the options, then connect, subscribe, count and print."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--port', type=int, default=8765)
    parser.add_argument('--seconds', type=float, default=26.0)
    parser.add_argument('--topics', nargs='+', default=TOPICS)
    args = parser.parse_args()
    deadline = time.monotonic() + 60.0
    while True:
        try:
            ws = connect(f'ws://127.0.0.1:{args.port}', subprotocols=['foxglove.sdk.v1'],
                         open_timeout=5)
            break
        except OSError:
            if time.monotonic() > deadline:
                print(f'no server on port {args.port}', file=sys.stderr)
                return 1
            time.sleep(0.5)
    with ws:
        channels: dict[str, int] = {}
        start = time.monotonic()
        while time.monotonic() - start < 2.0:
            try:
                m = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(m, str) and json.loads(m).get('op') == 'advertise':
                channels.update((c['topic'], c['id']) for c in json.loads(m)['channels'])
        wanted = [t for t in args.topics if t in channels]
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': i, 'channelId': channels[t]} for i, t in enumerate(wanted)]}))
        counts = dict.fromkeys(wanted, 0)
        received = 0
        start = time.monotonic()
        while time.monotonic() - start < args.seconds:
            try:
                m = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            except ConnectionClosed:
                break
            if isinstance(m, bytes) and m[0] == 0x01:  # message data: opcode, uint32 sub id
                counts[wanted[struct.unpack_from('<I', m, 1)[0]]] += 1
                received += len(m)
        seconds = time.monotonic() - start
    print(json.dumps({'per_second': {t: round(n / seconds, 1) for t, n in counts.items()},
                      'bytes_per_second': round(received / seconds)}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
