"""``enbarr calibrate ACTION ...``: the calibration procedures of the CS Saucer manual (4).

Each action is a ``CalibrationAction`` listed in ``ACTIONS`` (name -> ``'module:Class'``),
imported only when ``enbarr calibrate`` builds its parser; a new procedure is a module with
one class and a line here. See docs/calibration.md.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import importlib

from enbarr_core.commands import Command
from enbarr_core.commands.arguments import wrap

#: name -> 'module:Class' of the calibration actions, in the order ``--help`` lists them.
ACTIONS: dict[str, str] = {
    'camera': 'enbarr_core.commands.calibrate_camera:CameraCalibration',
}


class CalibrationAction:
    """One ``enbarr calibrate ACTION`` (subclass it): its options and its run."""

    help: str = ''
    description: str = ''

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare the action's options on ``parser``."""

    def run(self, args: argparse.Namespace) -> int:
        """Run the action with the parsed ``args``; the exit code."""
        raise NotImplementedError


def load_action(name: str) -> CalibrationAction:
    """Import and instantiate the action ``name`` of ``ACTIONS``."""
    module_name, _, attr = ACTIONS[name].partition(':')
    action = getattr(importlib.import_module(module_name), attr)()
    if not isinstance(action, CalibrationAction):
        raise TypeError(f'{ACTIONS[name]} is not a CalibrationAction')
    return action


class CalibrateCommand(Command):
    """``enbarr calibrate ACTION``."""

    help = 'calibrate a sensor (camera intrinsics)'
    description = ('Calibration procedures of the CS Saucer manual, chapter 4; '
                   'docs/calibration.md maps them to these commands.')

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare one sub-parser per action of ``ACTIONS``."""
        sub = parser.add_subparsers(dest='action', required=True, metavar='ACTION')
        for name in ACTIONS:
            action = load_action(name)
            p = sub.add_parser(name, help=action.help,
                               description=wrap(action.description or action.help),
                               formatter_class=argparse.RawDescriptionHelpFormatter)
            action.add_arguments(p)
            p.set_defaults(calibration_action=action)

    def main(self, *, args: argparse.Namespace, argv: Sequence[str]) -> int:
        """Run the action asked for."""
        action: CalibrationAction = args.calibration_action
        return action.run(args)
