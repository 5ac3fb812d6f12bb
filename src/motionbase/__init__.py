"""motionbase: motion-platform middleware for flight simulators.

Aircraft states (JSBSim, MAVLink, MCAP replays) go through a classical washout
filter (:mod:`motionbase.washout`) into the inverse kinematics of a 6-RUS rotary
platform or a planar 3-RRR robot (:mod:`motionbase.platform`); the edges
(:mod:`motionbase.io`) read sources and write sinks; :mod:`motionbase.pipeline`
ties them together at a fixed rate.

Conventions (see README): SI units inside, FRD body and base axes, poses
``[x, y, z, roll, pitch, yaw]`` with Z-Y-X Euler angles, time in float seconds.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("motionbase")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

from motionbase.errors import ConfigError, MotionbaseError  # noqa: E402
from motionbase.state import AircraftState  # noqa: E402

__all__ = ["AircraftState", "ConfigError", "MotionbaseError", "__version__"]
