"""Plain value objects that cross module boundaries.

:class:`AircraftState` is what a source yields, :class:`PipelineOutput` what the pipeline
hands its sinks each tick; both live here so that the sources and sinks (:mod:`motionbase.io`)
and the pipeline can name them without importing one another.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

#: The pipeline's phases (:attr:`PipelineOutput.phase`), in the order they occur; a phase's
#: code (the pipeline state's ``phase``) is its index.
PHASES = ("starting", "running", "stopping", "parked")

_F64 = np.dtype(np.float64)
_VECTOR_SHAPES = ((9,), (12,))


def _vec3(value: object) -> np.ndarray:
    """A read-only float array of shape (3,) (a copy: the caller's array stays its own)."""
    arr = np.array(value, dtype=float)
    if arr.shape != (3,):
        arr = arr.reshape(3)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class AircraftState:
    """One sample of aircraft motion at the pilot, in SI units and body axes.

    Parameters
    ----------
    t : float
        Time of the sample, s, in the source's clock (simulation time for
        JSBSim and replays).
    specific_force : array_like, shape (3,)
        Specific force f = a - g at the pilot, m/s^2, body axes FRD
        (x forward, y right, z down). Level unaccelerated flight reads
        ``(0, 0, -9.80665)``.
    angular_velocity : array_like, shape (3,)
        Body angular rates (p, q, r), rad/s, body axes FRD.
    attitude : array_like, shape (3,)
        Euler angles (roll, pitch, yaw), rad, Z-Y-X convention.
    angular_acceleration : array_like, shape (3,), optional
        Body angular accelerations, rad/s^2, or None when the source does not
        give them.
    on_ground : bool or None, optional
        The flight phase: True on the ground (weight on wheels), False in the air, None
        when the source does not say (the cueing then keeps its current flight-phase
        profile).
    """

    t: float
    specific_force: np.ndarray
    angular_velocity: np.ndarray
    attitude: np.ndarray = field(default_factory=lambda: _vec3((0.0, 0.0, 0.0)))
    angular_acceleration: np.ndarray | None = None
    on_ground: bool | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "t", float(self.t))
        object.__setattr__(self, "specific_force", _vec3(self.specific_force))
        object.__setattr__(self, "angular_velocity", _vec3(self.angular_velocity))
        object.__setattr__(self, "attitude", _vec3(self.attitude))
        if self.angular_acceleration is not None:
            object.__setattr__(self, "angular_acceleration", _vec3(self.angular_acceleration))
        if self.on_ground is not None:
            object.__setattr__(self, "on_ground", bool(self.on_ground))

    @classmethod
    def from_vector(
        cls, t: float, vector: np.ndarray, on_ground: bool | None = None
    ) -> AircraftState:
        """A state on one float vector, without copies or checks (the sources' fast path).

        Parameters
        ----------
        t : float
            Time, s.
        vector : ndarray of float64, shape (9,) or (12,), C-contiguous
            ``[specific_force, angular_velocity, attitude(, angular_acceleration)]`` in the
            units of the fields. The state takes it over: it is made read-only and its
            fields are views of it; the caller must not keep writing to it.
        on_ground : bool or None, optional
            The flight phase (see the class).

        Raises
        ------
        TypeError
            ``vector`` is not such an array (the pipeline's compiled stages read the fields
            as C-ordered float64 vectors of 3, unchecked).
        """
        if not (
            type(vector) is np.ndarray
            and vector.dtype == _F64
            and vector.shape in _VECTOR_SHAPES
            and vector.flags.c_contiguous
        ):
            raise TypeError(
                "AircraftState.from_vector: expected a C-contiguous float64 array of shape "
                f"(9,) or (12,), got {type(vector).__name__} {getattr(vector, 'dtype', '')} "
                f"{getattr(vector, 'shape', '')}"
            )
        vector.flags.writeable = False
        obj = object.__new__(cls)
        fields_ = obj.__dict__
        fields_["t"] = t
        fields_["specific_force"] = vector[0:3]
        fields_["angular_velocity"] = vector[3:6]
        fields_["attitude"] = vector[6:9]
        fields_["angular_acceleration"] = vector[9:12] if len(vector) == 12 else None
        fields_["on_ground"] = on_ground
        return obj

    def is_finite(self) -> bool:
        """True when every number in the sample is finite."""
        parts = [self.specific_force, self.angular_velocity, self.attitude]
        if self.angular_acceleration is not None:
            parts.append(self.angular_acceleration)
        return bool(np.isfinite(self.t) and all(np.isfinite(p).all() for p in parts))


class PipelineOutput(NamedTuple):
    """Everything one tick produced (what the sinks log and send); immutable.

    Attributes
    ----------
    t : float
        Time, s (source clock).
    state : AircraftState or None
        The sample the source gave this tick, as given (None on park ticks after
        the source ended).
    fresh : bool
        False when the source marked the sample stale.
    accepted : bool
        False when validation rejected the sample (the last valid one was held).
    washout_pose : ndarray, shape (6,)
        The cueing's pose ``[x, y, z, roll, pitch, yaw]`` (m, rad), before the soft start
        and clamping (a watchdog fade acts on its input).
    platform_pose : ndarray, shape (m,)
        The pose the actuators realise, in robot coordinates (6-DOF pose, or planar
        ``[x, y, phi]``).
    clamped : bool
        The workspace clamp moved the pose.
    angles : ndarray, shape (n,)
        Actuator command in the robot's unit (rad for cranks and servos, m for linear
        actuators); always finite and within limits.
    servo_deg : ndarray of int, shape (n,), or None
        Robots driven as hobby servos: the command in integer degrees.
    rate_limited : bool
        The safety stage's speed or acceleration limit changed the command.
    held : bool
        The safety stage replaced an unsafe command by the last safe one.
    phase : str
        One of :data:`PHASES`: ``"starting"``, ``"running"``, ``"stopping"`` or ``"parked"``.
    fade : float
        Watchdog fade in [0, 1]: the share of the held sample's deviation from level
        flight given to the cueing (1 = the aircraft's motion, 0 = level flight).
    cue_status : dict or None
        The cueing's :attr:`~motionbase.washout.cueing.Cueing.status` (flight-phase
        profile and blend), logged with ``washout_pose``.
    """

    t: float
    state: AircraftState | None
    fresh: bool
    accepted: bool
    washout_pose: np.ndarray
    platform_pose: np.ndarray
    clamped: bool
    angles: np.ndarray
    servo_deg: np.ndarray | None
    rate_limited: bool
    held: bool
    phase: str
    fade: float
    cue_status: dict[str, Any] | None = None
