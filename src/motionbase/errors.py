"""The error hierarchy: one root class, specific subclasses.

Every error a user can cause (a bad file, a bad value, a port that will not
open) is a :class:`MotionbaseError`. The command line prints its message on one
line and exits with status 2; a traceback means a bug in motionbase.

Messages name what was wrong and how to fix it, e.g.
``ceart.toml: field 'crank': must be > 0 m, got -0.1 (fix the value)``.
"""


class MotionbaseError(Exception):
    """Root of every error motionbase raises on purpose."""


class ConfigError(MotionbaseError, ValueError):
    """A configuration (geometry, washout, calibration, CLI value) is invalid."""


class CueingInputError(MotionbaseError, ValueError):
    """A cueing was given an input sample it cannot use (wrong shape, NaN or infinite)."""


class SourceError(MotionbaseError):
    """A source (JSBSim, MAVLink, MCAP file, cursor) cannot be opened or read."""


class SinkError(MotionbaseError):
    """A sink (MCAP log, serial port, UDP output) cannot be opened or written."""


class LogFormatError(SourceError):
    """A file is not a readable MCAP recording of motionbase."""
