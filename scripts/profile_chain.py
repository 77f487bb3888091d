#!/usr/bin/env python3
"""Where a chain's CPU goes per sample: the chain of ``enbarr bench`` stepped by hand.

The chain is composed as ``enbarr bench --chain`` composes it, but its simulator is stepped
here (at ``--rate``, sleeping between steps so that the sensors' rate limits behave as in a
run) instead of by its own thread. Prints the chain thread's CPU per cycle without and with
the profiler, then cProfile's top functions (``--sort tottime`` or ``cumulative``): the
per-sample work of every node around the algorithms, which ``ros_overhead_ratio`` sums up.

    export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=42
    .venv/bin/python scripts/profile_chain.py saucer --rate 50 --sort cumulative
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time


def main() -> None:
    """Step the chain, print CPU per cycle and the profile."""
    from enbarr_core.bringup.compose import composed
    from enbarr_core.bringup.profile import apply_environment
    from enbarr_core.bench import chain as bench

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('chain', choices=sorted(bench.CHAINS))
    p.add_argument('--rate', type=float, default=50.0, help='steps per second (default 50)')
    p.add_argument('--seconds', type=float, default=6.0, help='stepped for this long')
    p.add_argument('--sort', choices=('tottime', 'cumulative'), default='tottime')
    p.add_argument('--top', type=int, default=40, help='functions listed (default 40)')
    args = p.parse_args()
    chain = bench.CHAINS[args.chain]
    prof = bench._chain_profile(chain, args.rate)
    apply_environment(prof)
    with composed(prof) as c:
        sim = c.node('simulator')
        c.start(skip=[sim])

        def run(profiler: cProfile.Profile | None) -> float:
            cpu, n = 0.0, int(args.rate * args.seconds)
            for _ in range(n):
                t0 = time.thread_time()
                if profiler is not None:
                    profiler.enable()
                sim.step()
                if profiler is not None:
                    profiler.disable()
                cpu += time.thread_time() - t0
                c.executor.spin_once(timeout_sec=0.0)
                time.sleep(1.0 / args.rate)
            return cpu / n

        run(None)  # warm-up: the estimate, the references, the first messages
        plain = run(None)
        profiler = cProfile.Profile()
        profiled = run(profiler)
    print(f'{args.chain} chain at {args.rate:g} Hz: {plain * 1e3:.3f} ms of chain-thread CPU '
          f'per cycle ({profiled * 1e3:.3f} ms under the profiler)')
    pstats.Stats(profiler).sort_stats(args.sort).print_stats(args.top)


if __name__ == '__main__':
    main()
