"""``enbarr scenario NAME``: a simulated scenario run headless (``enbarr_core.tools.scenario``)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import json
from pathlib import Path

from enbarr_core.commands import Command
from enbarr_core.commands.arguments import check_seconds, wrap
from enbarr_core.framework.errors import EnbarrError

EPILOG = (
    'The JSON line (definitions: enbarr_core/tools/metrics.py, docs/profiles.md): '
    "scenario, verdict (pass or fail: every target of the scenario's scenario.targets met), "
    'failed (the figures whose target failed; error first when the run reported one); '
    'initial_mode, modes, mode_changes, thrust_saturation_s, final_speed_mps (every kind; a '
    'run scenario has only these); '
    'station keeping: position/heading error RMS and max '
    "over the fixed window from the scenario's settle_time after automatic began "
    '(window_s), time_to_settle_s (errors inside settle_band from then on), settled, '
    'settled_in_time, the same errors over the whole automatic period (overall_*) and '
    'dropout_position_error_max_m (with motion-capture dropouts); '
    'path: cross_track_rms_m (active leg, to the arrival), cross_track_max_m, '
    'all_waypoints_visited (in order), path_time_s, final_position_error_m; then '
    "targets (each target's bound, value and pass), simulated_s, wall_s, real_time_factor, "
    'cpu_s, bag, plot. Exit status: 0 when the verdict is pass, 1 when it is fail (the JSON '
    'line and the plot are written all the same), 2 on a mistake (unknown scenario, bad '
    'option or profile).')


class ScenarioCommand(Command):
    """``enbarr scenario NAME``."""

    help = 'run a simulated scenario headless (prints JSON)'
    epilog = EPILOG

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare ``NAME``, ``--output``, ``--set``, ``--duration`` and the recording."""
        from enbarr_core.tools.scenario import known_scenarios
        parser.description = wrap(
            'Run a named simulated scenario faster than real time, record it, judge its '
            'metrics against the targets the scenario states, print them and the verdict as '
            'one JSON line and write a PNG plot; exit 1 when a target failed. Scenarios '
            '(params/scenarios/; '
            f'enbarr list scenarios describes them): {", ".join(known_scenarios())}.')
        parser.add_argument('name', help='scenario name (params/scenarios/NAME.yaml) or path')
        parser.add_argument('-o', '--output', metavar='DIR',
                            help='where the bag and the PNG go (default: '
                            'runs/scenario-NAME-<time>)')
        parser.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                            help='override a node parameter; VALUE is YAML (repeatable)')
        parser.add_argument('--duration', type=float, metavar='S',
                            help="simulated seconds (default: the scenario's own)")
        parser.add_argument('--no-plot', action='store_true', help='skip the PNG')
        parser.add_argument('--record-all', action='store_true',
                            help='record every topic (default: what the metrics and the plot '
                            "read, plus the scenario's record.topics)")

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Run the scenario and print its metrics and verdict as one JSON line.

        Exit status 0 on a pass, ``targets.EXIT_FAILED`` on a fail.
        """
        from enbarr_core.tools.scenario import run
        from enbarr_core.tools.targets import EXIT_FAILED

        check_seconds('--duration', args.duration)
        if args.output is not None:
            out = Path(args.output)
            if out.exists() and not out.is_dir():
                raise EnbarrError(f'--output {out}: exists and is not a directory')
            try:
                out.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                raise EnbarrError(f'--output {out}: cannot create the directory: '
                                  f'{err.strerror or err}') from err
        result = run(args.name, args.output, args.set, plot=not args.no_plot,
                     duration=args.duration, record_all=args.record_all)
        print(json.dumps(result))
        return 0 if result['verdict'] == 'pass' else EXIT_FAILED
