"""motionbase: motion-platform middleware for flight simulators.

Aircraft states (JSBSim, MAVLink, FlightGear, X-Plane, MCAP replays) go through a
cueing plug-in, the classical washout or model-predictive cueing
(:mod:`motionbase.washout`), into the inverse kinematics of a robot plug-in, the
6-RUS rotary platform, the 6-UPS Stewart platform or the planar 3-RRR robot
(:mod:`motionbase.platform`); the edges
(:mod:`motionbase.io`) read sources and write sinks; :mod:`motionbase.pipeline`
ties them together at a fixed rate.

Conventions (see README): SI units inside, FRD body and base axes, poses
``[x, y, z, roll, pitch, yaw]`` with Z-Y-X Euler angles, time in float seconds.
"""

from motionbase.errors import ConfigError, MotionbaseError

__all__ = ["AircraftState", "ConfigError", "MotionbaseError", "__version__"]


def __getattr__(name: str) -> object:
    """``__version__`` and ``AircraftState``, loaded on first use: importing the package
    stays cheap (no numpy, no package metadata), so a command can install its Ctrl-C
    handling before anything slow runs (``motionbase.cli``)."""
    if name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("motionbase")
        except PackageNotFoundError:  # running from a source tree that is not installed
            value = "0.0.0+unknown"
    elif name == "AircraftState":
        from motionbase.state import AircraftState as value
    else:
        raise AttributeError(f"module 'motionbase' has no attribute {name!r}")
    globals()[name] = value
    return value
