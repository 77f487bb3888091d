"""The operator modes a DP vessel can be in: the values the ``mode`` topic carries.

Part of the contract (``topics.MODE``), so that the node that decides the mode (the DP
controller, with its operator rules in ``enbarr_core.control.modes``) and the nodes that follow
it (guidance, an operator station) share one vocabulary without importing each other. Free of
ROS.
"""

from __future__ import annotations

import enum


class Mode(enum.Enum):
    """The operator mode; the value is what ``mode`` carries."""

    MANUAL = 'manual'
    AUTOMATIC = 'automatic'
    GUIDANCE = 'guidance'
