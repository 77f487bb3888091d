"""What bringup needs to know of a recorder node: that it is one, and how to close it.

A node that records what the other nodes publish subclasses ``Recorder`` (the built-in
``RecorderNode`` does; so may a third-party plugin). Bringup destroys recorders after every
other node, so that the bag holds the others' last messages (thrusters neutral), and closes
them through ``close``. Pure: no rclpy here.
"""

from __future__ import annotations

import abc


class Recorder(abc.ABC):
    """A node that writes other nodes' messages to storage; bringup takes it down last."""

    @abc.abstractmethod
    def close(self) -> None:
        """Write what is queued and close the storage (idempotent)."""

    def still_receiving(self) -> bool:
        """Whether other nodes still send it messages to record.

        A recorder group whose supervisor was killed records until this is False (or a
        bounded grace passed), so that the bag holds the other groups' safe state.
        """
        return False
