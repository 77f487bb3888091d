"""The error hierarchy of Enbarr.

Every error a user can cause (a profile, a parameter, a message, device bytes) is an
``EnbarrError`` whose message names what is wrong and where. The command line prints it
without a traceback and exits non-zero.
"""

from __future__ import annotations


class EnbarrError(Exception):
    """Base class of all errors Enbarr raises on purpose."""


class ProfileError(EnbarrError):
    """A vessel profile is invalid: names the file, the key path and what was expected."""

    def __init__(self, message: str, *, path: str | None = None, key: str | None = None):
        self.path = path
        self.key = key
        where = ': '.join(part for part in (path, key) if part)
        super().__init__(f'{where}: {message}' if where else message)


class RegistryError(EnbarrError):
    """A plugin or core node name is unknown or its entry point is broken."""


class ConfigurationError(EnbarrError):
    """A node's parameters are wrong or inconsistent (e.g. a geometry that cannot yaw).

    ``parameter`` names the parameter at fault when one is, so that bringup can point at the
    profile file that set it.
    """

    def __init__(self, message: str, *, parameter: str | None = None):
        self.parameter = parameter
        super().__init__(message)


class AllocationError(ConfigurationError):
    """A thruster layout cannot produce a required degree of freedom."""


class DeviceError(EnbarrError):
    """A device answered with bytes that break its protocol, or did not answer."""


class RecorderError(EnbarrError):
    """A bag cannot be written where asked."""


class FrameError(EnbarrError):
    """A frame tree is inconsistent, or a frame asked for is not in it."""


class CalibrationError(EnbarrError):
    """Calibration data give no answer: the message says what to change.

    No board seen, too few views, a degenerate set, input that cannot be read.
    """
