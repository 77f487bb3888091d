"""``enbarr calibrate ACTION ...``: the calibration procedures of the CS Saucer manual (4).

Each action is a ``CalibrationAction`` listed in ``ACTIONS`` (name -> ``'module:Class'``),
imported only when ``enbarr calibrate`` builds its parser; a new procedure is a module with
one class and a line here. ``camera`` (manual 4.1) is ``calibrate_camera``; ``lidar`` and
``reproject`` (manual 4.2) are ``calibrate_lidar``'s functions and ``pairs`` (the marks of
4.2, for ``lidar --method pnp``) ``calibrate_pairs``', hung here by small classes. See
docs/calibration.md and docs/calibration_lidar.md.
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
    'pairs': 'enbarr_core.commands.calibrate:PairsCalibration',
    'lidar': 'enbarr_core.commands.calibrate:LidarCalibration',
    'reproject': 'enbarr_core.commands.calibrate:ReprojectCalibration',
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


class LidarCalibration(CalibrationAction):
    """``enbarr calibrate lidar``: ``calibrate_lidar.add_lidar_arguments`` / ``run_lidar``."""

    def __init__(self) -> None:
        from enbarr_core.commands import calibrate_lidar
        self._module = calibrate_lidar
        self.help = calibrate_lidar.LIDAR_HELP

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare ``calibrate lidar``'s options."""
        self._module.add_lidar_arguments(parser)

    def run(self, args: argparse.Namespace) -> int:
        """Solve the lidar's pose in the camera frame."""
        return self._module.run_lidar(args)


class ReprojectCalibration(CalibrationAction):
    """``enbarr calibrate reproject``: ``calibrate_lidar``'s reprojection."""

    def __init__(self) -> None:
        from enbarr_core.commands import calibrate_lidar
        self._module = calibrate_lidar
        self.help = calibrate_lidar.REPROJECT_HELP

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare ``calibrate reproject``'s options."""
        self._module.add_reproject_arguments(parser)

    def run(self, args: argparse.Namespace) -> int:
        """Draw the scans onto the images."""
        return self._module.run_reproject(args)


class PairsCalibration(CalibrationAction):
    """``enbarr calibrate pairs``: ``calibrate_pairs``' collection of the manual's marks."""

    def __init__(self) -> None:
        from enbarr_core.commands import calibrate_pairs
        self._module = calibrate_pairs
        self.help = calibrate_pairs.PAIRS_HELP
        self.description = calibrate_pairs.PAIRS_DESCRIPTION

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Declare ``calibrate pairs``' options."""
        self._module.add_pairs_arguments(parser)

    def run(self, args: argparse.Namespace) -> int:
        """Collect the pairs into the CSV."""
        return self._module.run_pairs(args)


def load_action(name: str) -> CalibrationAction:
    """Import and instantiate the action ``name`` of ``ACTIONS``."""
    module_name, _, attr = ACTIONS[name].partition(':')
    action = getattr(importlib.import_module(module_name), attr)()
    if not isinstance(action, CalibrationAction):
        raise TypeError(f'{ACTIONS[name]} is not a CalibrationAction')
    return action


class CalibrateCommand(Command):
    """``enbarr calibrate ACTION``."""

    help = 'calibrate a sensor: camera intrinsics, the lidar in the camera frame'
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
