#!/usr/bin/env python3
"""Mutation scores per module from mutmut's cache, and seeded samples of the unrun mutants.

A full mutmut round takes hours here (docs/testing.md), so a module's mutants that were never
run are estimated from a uniform random sample of them. Run from the repository root, after
``mutmut run`` has generated ``mutants/``:

    python3 scripts/mutation_sample.py pick N [--seed S] [--module MODULE]...
        # draw N of each module's not-yet-run mutants (seeded), record the draw in
        # mutants/samples.json and print their names, one a line, for `mutmut run NAME...`
    python3 scripts/mutation_sample.py table
        # per module: killed / survived / no tests / timeout / not run over all mutants, and
        # for a sampled module the sample's kill share with its 95 % Wilson interval and the
        # module's estimate: (killed outside the draw + share x mutants in the population) / all;
        # drawn mutants left unrun count as not killed in the estimate's low bound. The last
        # row sums the modules (a module neither run in full nor sampled counts its score of
        # run as its estimate, bounded by 0 and 1 for its unrun part); its bounds are the sums
        # of the modules' bounds, wider than a joint 95 % interval.

Only mutmut's result files (``mutants/**/*.py.meta``, JSON ``exit_code_by_key``) are read;
the exit codes are mutmut's (1 and 3 killed, 0 survived, 5 and 33 no tests, None not run,
36, 24, -24, 152 and 255 timeout). ``framework.driver`` counts ``CommandWatchdog`` and
``Backoff`` only (its node classes are not unit-tested). A timeout counts as not killed.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import random

MUTANTS = Path('mutants')
SAMPLES = MUTANTS / 'samples.json'
KILLED, SURVIVED, NO_TESTS, TIMEOUT = {1, 3}, {0}, {5, 33}, {36, 24, -24, 152, 255}
DRIVER_CLASSES = ('\u01c1CommandWatchdog\u01c1', '\u01c1Backoff\u01c1')


def results() -> dict[str, dict[str, int | None]]:
    """Return {module: {mutant name: exit code or None}} from mutmut's cache."""
    out: dict[str, dict[str, int | None]] = {}
    for meta in sorted(MUTANTS.glob('enbarr_core/**/*.py.meta')):
        module = str(meta.relative_to(MUTANTS / 'enbarr_core'))[:-len('.py.meta')]
        module = module.replace('/', '.')
        codes = json.loads(meta.read_text())['exit_code_by_key']
        if module == 'framework.driver':
            codes = {k: v for k, v in codes.items() if any(c in k for c in DRIVER_CLASSES)}
        out[module] = codes
    return out


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Return the 95 % Wilson score interval of a binomial share k / n."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def pick(n: int, seed: int, modules: list[str]) -> None:
    """Draw ``n`` unrun mutants per module; keep the draw (and its population) in samples.json."""
    samples = json.loads(SAMPLES.read_text()) if SAMPLES.exists() else {}
    for module, codes in results().items():
        if modules and module not in modules:
            continue
        population = sorted(k for k, v in codes.items() if v is None)
        if not population:
            continue
        drawn = random.Random(f'{seed}:{module}').sample(population, min(n, len(population)))
        samples[module] = {'seed': seed, 'population': population, 'drawn': sorted(drawn)}
        print('\n'.join(sorted(drawn)))
    SAMPLES.write_text(json.dumps(samples, indent=1))


def table() -> None:
    """Print the per-module table (markdown), with the sample estimates."""
    samples = json.loads(SAMPLES.read_text()) if SAMPLES.exists() else {}
    print('| module | mutants | killed | survived | no tests | timeout | not run | score of run '
          '| sample: killed / run | sample 95 % CI | module estimate (95 % CI) |')
    print('|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|')
    total = [0, 0, 0, 0.0, 0.0, 0.0]  # mutants, killed, run, estimate: point, low, high
    skipped: list[str] = []
    for module, codes in results().items():
        values = list(codes.values())
        count = {name: sum(v in group for v in values) for name, group in
                 (('k', KILLED), ('s', SURVIVED), ('n', NO_TESTS), ('t', TIMEOUT))}
        unrun = sum(v is None for v in values)
        run = len(values) - unrun
        score = f'{100 * count["k"] / run:.0f} %' if run else '-'
        cells = ['', '', '']
        if module in samples:
            drawn = [codes.get(name) for name in samples[module]['drawn']]
            done = [v for v in drawn if v is not None]
            k = sum(v in KILLED for v in done)
            lo, hi = wilson(k, len(done))
            pop = set(samples[module]['population'])
            outside = sum(v in KILLED for name, v in codes.items() if name not in pop)
            if done:
                est = [(outside + share * len(pop)) / len(values)
                       for share in (k / len(done), lo, hi)]
                # Drawn but not run (an interrupted run leaves the slowest): counted as not
                # killed in the low bound, so the interval is not biased by what was left.
                lo_all = wilson(k, len(drawn))[0]
                low = min(est[1], (outside + lo_all * len(pop)) / len(values))
                cells = [f'{k} / {len(done)}' + (f' (of {len(drawn)})' if done != drawn else ''),
                         f'{100 * lo:.0f}-{100 * hi:.0f} %',
                         f'{100 * est[0]:.0f} % ({100 * low:.0f}-{100 * est[2]:.0f} %)']
        print(f'| {module} | {len(values)} | {count["k"]} | {count["s"]} | {count["n"]} | '
              f'{count["t"]} | {unrun} | {score} | ' + ' | '.join(cells) + ' |')
        if not run:
            skipped.append(module)
            continue
        if module in samples and done:
            point, bounds = est[0], (low, est[2])
        else:  # all run, or nothing known of the unrun part: it may be anything
            point = count['k'] / run if run else 0.0
            bounds = (count['k'] / len(values), (count['k'] + unrun) / len(values))
        for i, v in enumerate((len(values), count['k'], run, point * len(values),
                               bounds[0] * len(values), bounds[1] * len(values))):
            total[i] += v
    n = total[0]
    name = 'all' + (f' but {", ".join(skipped)} (none run)' if skipped else '')
    point, low, high = (f'{100 * total[i] / n:.0f}' for i in (3, 4, 5))
    print(f'| {name} | {n} | {total[1]} | | | | {n - total[2]} | '
          f'{100 * total[1] / total[2]:.0f} % | | | {point} % ({low}-{high} %) |')


def main() -> None:
    """Parse the command line and run the sub-command."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    sub = parser.add_subparsers(dest='cmd', required=True)
    p = sub.add_parser('pick')
    p.add_argument('n', type=int)
    p.add_argument('--seed', type=int, default=7)
    p.add_argument('--module', action='append', default=[], help='only this module (repeat)')
    sub.add_parser('table')
    args = parser.parse_args()
    if args.cmd == 'pick':
        pick(args.n, args.seed, args.module)
    else:
        table()


if __name__ == '__main__':
    main()
