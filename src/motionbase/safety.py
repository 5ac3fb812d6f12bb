"""The safety stage: the last thing every actuator command passes through.

Pure math, no I/O. Given the previous command and the new target crank (or servo)
angles, :func:`limit_command` returns the next command so that

* it is finite and inside the angle limits (a non-finite or out-of-limit target is
  replaced by the last safe command: the *whole* vector is held, never one leg alone);
* the speed ``|q_k - q_{k-1}| / dt`` never exceeds ``max_speed``;
* the acceleration ``|v_k - v_{k-1}| / dt`` never exceeds ``max_accel``;
* a moving target is tracked without lag (its speed is fed forward) and the
  remaining error is closed no faster than the speed from which the actuator can
  still stop in time (the exact discrete braking curve,
  :func:`motionbase.physics.brake_speed`), so a limited actuator converges to a fixed
  target without overshoot or oscillation;
* it never approaches an angle limit faster than it can stop before it.

Per actuator this is :func:`motionbase.physics.track_toward`, the tracker the washout's
tilt and cue limiters run too.

The motor drives' senders ramp each wall-clock frame toward the latest of these commands
with :func:`ramp_command` (:func:`motionbase.physics.ramp_toward`): the same limits, for
steps whose lengths vary, and never past a command that comes to rest.

All angles in rad, speeds in rad/s, accelerations in rad/s^2, ``dt`` in s. Arrays
have shape ``(n,)`` for ``n`` actuators (6 for the 6-RUS, 3 for the 3-RRR).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from motionbase.config import as_float
from motionbase.physics import (
    MAX_ANGULAR_VELOCITY,
    MAX_ATTITUDE,
    MAX_SPECIFIC_FORCE,
    least_travel,
    ramp_toward,
    track_toward,
)

# Command status bits returned by limit_command.
OK = 0
RATE_LIMITED = 1  # speed or acceleration limit changed the command
UNSAFE_TARGET = 2  # target was non-finite or outside the angle limits: held instead


@dataclass(frozen=True)
class ActuatorLimits:
    """Per-actuator limits.

    Parameters
    ----------
    lower, upper : ndarray, shape (n,)
        Angle limits, rad.
    max_speed : ndarray, shape (n,)
        Speed limit, rad/s (> 0).
    max_accel : ndarray, shape (n,)
        Acceleration limit, rad/s^2 (> 0).
    """

    lower: np.ndarray
    upper: np.ndarray
    max_speed: np.ndarray
    max_accel: np.ndarray

    @classmethod
    def broadcast(cls, n: int, lower, upper, max_speed, max_accel) -> ActuatorLimits:
        """Build limits for ``n`` actuators from scalars or arrays."""

        def arr(x):
            a = np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=float), (n,)))
            a.setflags(write=False)
            return a

        return cls(arr(lower), arr(upper), arr(max_speed), arr(max_accel))


@numba.njit(cache=True, inline="always")
def _unsafe(target, lower, upper) -> bool:  # pragma: no cover - compiled
    """Whether any of ``target`` is non-finite or outside ``[lower, upper]``: the limiter and
    the drive-side ramp then hold the whole vector (:data:`UNSAFE_TARGET`)."""
    for i in range(target.shape[0]):
        x = target[i]
        if not (np.isfinite(x) and lower[i] <= x <= upper[i]):
            return True
    return False


@numba.njit(cache=True)
def limit_kernel(q_prev, v_prev, target_prev, target, dt, lower, upper, vmax, amax, q_out, v_out):
    """The compiled limiter: :func:`limit_command` on arrays, writing ``q_out`` and ``v_out``.

    ``lower``, ``upper``, ``vmax``, ``amax`` are :class:`ActuatorLimits`'s arrays; returns
    the status bits (``OK``, ``RATE_LIMITED``, ``UNSAFE_TARGET``). Each actuator's inputs
    are read before its outputs are written, so ``q_out`` may be ``q_prev`` and ``v_out``
    ``v_prev`` (updated in place). Called by
    :func:`limit_command` and by the pipeline's limit stage (:mod:`motionbase.stages`).
    """
    n = q_prev.shape[0]
    # 1. The target must be finite and inside the limits, or the whole vector is held.
    status = 2 if _unsafe(target, lower, upper) else 0
    for i in range(n):
        q_i = q_prev[i]
        # a held vector brakes to a stop where it is (a target at rest at its position)
        tgt = q_i if status == 2 else target[i]
        was = q_i if status == 2 else target_prev[i]
        lo, hi = lower[i], upper[i]
        u = amax[i] * dt
        q, limited = track_toward(q_i, v_prev[i], was, tgt, dt, lo, hi, vmax[i], u, 0.0)
        if limited and status != 2:
            status = 1
        v_out[i] = (q - q_i) / dt
        q_out[i] = q
    return status


def limit_command(
    q_prev: np.ndarray,
    v_prev: np.ndarray,
    target_prev: np.ndarray,
    target: np.ndarray,
    dt: float,
    limits: ActuatorLimits,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Next safe actuator command toward ``target``.

    Parameters
    ----------
    q_prev : ndarray, shape (n,)
        Previous command, rad (must itself be safe).
    v_prev : ndarray, shape (n,)
        Previous command speed, rad/s.
    target_prev : ndarray, shape (n,)
        The previous tick's (safe) target, rad; its difference to ``target`` is the
        target's speed, fed forward so that a moving target is tracked without lag.
        Pass ``q_prev`` when there is none.
    target : ndarray, shape (n,)
        Wanted command, rad; may contain NaN or out-of-limit values.
    dt : float
        Time step, s (> 0).
    limits : ActuatorLimits

    Returns
    -------
    q : ndarray, shape (n,)
        The command to send, rad.
    v : ndarray, shape (n,)
        Its speed ``(q - q_prev) / dt``, rad/s.
    status : int
        ``OK``, ``RATE_LIMITED`` or ``UNSAFE_TARGET`` (bit values).
    """
    q = np.empty_like(q_prev)
    v = np.empty_like(q_prev)
    status = limit_kernel(
        q_prev,
        v_prev,
        target_prev,
        np.asarray(target, dtype=float),
        float(dt),
        limits.lower,
        limits.upper,
        limits.max_speed,
        limits.max_accel,
        q,
        v,
    )
    return q, v, int(status)


#: Rounding allowed in a command's steps before :func:`ramp_command` takes them for a jump:
#: relative to the limits, and absolute (rad or m).
STEP_ROUNDING = (1e-6, 1e-12)


_IN = numba.types.Array(numba.float64, 1, "A", readonly=True)  # (a writable array converts)
_OUT = numba.float64[::1]


# Typed, so loaded with this module: a motor output's sender thread first calls it seconds
# into a run (its first ramped frame), and lazily it was loaded, or compiled, there.
@numba.njit(numba.int64(*[_IN] * 5, *[numba.float64] * 3, *[_IN] * 4, _OUT, _OUT), cache=True)
def ramp_kernel(
    q_prev, v_prev, target, step, step_before, dt, dt_min, command_dt,
    lower, upper, vmax, amax, q_out, v_out,
):  # fmt: skip
    """The compiled drive-side ramp: :func:`ramp_command` on arrays, writing ``q_out`` and
    ``v_out`` (which may be ``q_prev`` and ``v_prev``); returns the status bits."""
    n = q_prev.shape[0]
    status = 2 if _unsafe(target, lower, upper) else 0
    rel, eps = STEP_ROUNDING
    for i in range(n):
        q_i = q_prev[i]
        c = q_i if status == 2 else target[i]
        du = amax[i] * command_dt * command_dt
        d = 0.0 if status == 2 else step[i]
        if not (
            abs(d) <= vmax[i] * command_dt * (1.0 + rel) + eps
            and abs(d - step_before[i]) <= du * (1.0 + rel) + eps
        ):
            d = 0.0  # not the steps of a command within the limits: a jump, to a command at rest
        hi = min(upper[i], c + least_travel(d, du)) if d > 0.0 else c
        lo = max(lower[i], c - least_travel(-d, du)) if d < 0.0 else c
        q, limited = ramp_toward(
            q_i, v_prev[i], c, d / command_dt, lo, hi, dt, dt_min,
            lower[i], upper[i], vmax[i], amax[i],
        )  # fmt: skip
        if limited and status != 2:
            status = 1
        v_out[i] = (q - q_i) / dt
        q_out[i] = q
    return status


def ramp_command(
    q_prev: np.ndarray,
    v_prev: np.ndarray,
    target: np.ndarray,
    step: np.ndarray,
    step_before: np.ndarray,
    dt: float,
    limits: ActuatorLimits,
    *,
    dt_min: float,
    command_dt: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """One wall-clock frame of a motor drive toward the latest command, within the limits:
    the drive-side ramp of :class:`motionbase.io.motor_output.MotorOutput`.

    The command's own speed, ``step / command_dt`` (its step from the command of the tick
    before, on the pipeline's tick), is fed forward; never the speed between the frames
    that happened to sample it (a command sampled twice would look stopped, the next one
    twice as fast). Commands within the limits, as the pipeline's are, change their step
    by at most ``a_max command_dt^2`` a tick, so one that moved ``step`` comes to rest no
    nearer than :func:`motionbase.physics.least_travel` of it: the drive never approaches
    that point faster than it can stop before it, whatever the lengths of its later steps
    (each at least ``dt_min``), so it never passes a command that comes to rest. Steps
    beyond the limits (a jump, commands that do not come from the limiter) make a command
    at rest: the drive heads for it and stops there. A non-finite or out-of-limit target
    holds the whole vector (the drive brakes to rest where it is), as in
    :func:`limit_command`.

    Parameters
    ----------
    q_prev, v_prev : ndarray, shape (n,)
        What the drive last received, and its speed, rad and rad/s (or m, m/s).
    target : ndarray, shape (n,)
        The latest command.
    step, step_before : ndarray, shape (n,)
        Its step from the command of the tick before, and that command's own step (zeros:
        a command at rest, or one whose ticks before are not known).
    dt : float
        This frame's step, s (>= ``dt_min``).
    limits : ActuatorLimits
    dt_min : float
        The shortest step the sender takes, s (> 0).
    command_dt : float
        The commands' tick, s (the pipeline's ``dt``).

    Returns
    -------
    q : ndarray, shape (n,)
        The frame's command.
    v : ndarray, shape (n,)
        Its speed ``(q - q_prev) / dt``.
    status : int
        ``OK``, ``RATE_LIMITED`` or ``UNSAFE_TARGET`` (bit values).
    """
    q = np.empty_like(q_prev)
    v = np.empty_like(q_prev)
    status = ramp_kernel(
        q_prev, v_prev, np.asarray(target, dtype=float), step, step_before, float(dt),
        float(dt_min), float(command_dt), limits.lower, limits.upper, limits.max_speed,
        limits.max_accel, q, v,
    )  # fmt: skip
    return q, v, int(status)


@dataclass(frozen=True)
class InputLimits:
    """Bounds beyond which an aircraft sample is absurd and rejected.

    Parameters
    ----------
    max_specific_force : float
        m/s^2; default 150 (about 15 g).
    max_angular_velocity : float
        rad/s; default 20 (about 1150 deg/s).
    max_attitude : float
        rad, on each Euler angle; default 10 (any wrapped angle is below 2 pi).
    """

    max_specific_force: float = MAX_SPECIFIC_FORCE
    max_angular_velocity: float = MAX_ANGULAR_VELOCITY
    max_attitude: float = MAX_ATTITUDE

    def __post_init__(self) -> None:
        # a NaN bound would let every sample through (no comparison with NaN is true)
        for name in ("max_specific_force", "max_angular_velocity", "max_attitude"):
            value = as_float(
                "input limits", name, getattr(self, name), min_value=0.0, strict_min=True
            )
            object.__setattr__(self, name, value)


#: Sample times the pipeline accepts: 0 <= t <= MAX_SAMPLE_TIME_S (9.2e9 s, about 292 years).
#: A log time is a count of nanoseconds that must fit 64 bits (signed in the log's writer,
#: unsigned in MCAP): 2**63 ns is 9.22e9 s, and the margin covers the ticks after the last
#: sample. A time outside is rejected like any invalid sample and never reaches the log.
MAX_SAMPLE_TIME_S = 9.2e9

INPUT_PROBLEMS = (
    None,
    "time is not finite",
    "time did not advance",
    "specific force is not finite",
    "specific force beyond its bound",
    "angular velocity is not finite",
    "angular velocity beyond its bound",
    "attitude is not finite",
    "attitude beyond its bound",
    f"time is outside 0..{MAX_SAMPLE_TIME_S:.3g} s (a log time must fit 64-bit nanoseconds)",
)


@numba.njit(cache=True)
def input_code(t, last_t, f, w, att, max_f, max_w, max_att):
    """The compiled validation: the index in :data:`INPUT_PROBLEMS` of why a sample is
    rejected (0 when it is usable); see :func:`input_problem` (``last_t`` is -inf before
    the first tick). Called by it and by the pipeline's input stage."""
    if not np.isfinite(t):
        return 1
    if not (0.0 <= t <= MAX_SAMPLE_TIME_S):
        return 9
    if t <= last_t:
        return 2
    code = 3
    for vec, bound in ((f, max_f), (w, max_w), (att, max_att)):
        for k in range(3):
            if not np.isfinite(vec[k]):
                return code
        for k in range(3):
            if abs(vec[k]) > bound:
                return code + 1
        code += 2
    return 0


def input_problem(
    t: float,
    specific_force: np.ndarray,
    angular_velocity: np.ndarray,
    attitude: np.ndarray,
    last_t: float | None,
    limits: InputLimits,
) -> str | None:
    """Why an aircraft sample must be rejected, or None when it is usable.

    Parameters
    ----------
    t : float
        Sample time, s; must be finite, within ``0..MAX_SAMPLE_TIME_S`` (what a log time
        holds) and later than ``last_t``.
    specific_force, angular_velocity, attitude : ndarray, shape (3,)
        m/s^2, rad/s, rad; each finite and within its bound in ``limits``.
    last_t : float or None
        Time of the previous tick, s (None before the first).
    limits : InputLimits
    """
    code = input_code(
        float(t),
        -np.inf if last_t is None else float(last_t),
        specific_force,
        angular_velocity,
        attitude,
        limits.max_specific_force,
        limits.max_angular_velocity,
        limits.max_attitude,
    )
    return INPUT_PROBLEMS[code]
