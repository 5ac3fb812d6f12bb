"""Shared maths and physical constants, each defined once.

Pure functions, no I/O: the maths (:mod:`motionbase.washout`, :mod:`motionbase.platform`),
the pipeline's stages (:mod:`motionbase.safety`, :mod:`motionbase.stages`) and the edges
(:mod:`motionbase.io`) all take these from here, so changing one changes it everywhere it
is meant to and nowhere else.

* :data:`STANDARD_GRAVITY`, m/s^2;
* the input plausibility bounds (:data:`MAX_SPECIFIC_FORCE`, :data:`MAX_ANGULAR_VELOCITY`,
  :data:`MAX_ATTITUDE`): the defaults of the pipeline's validation
  (:class:`motionbase.safety.InputLimits`) and the bounds the live sources drop values
  beyond;
* :func:`brake_speed`, the discrete braking curve, and :func:`track_toward`, the one-tick
  tracker built on it that the safety limiter, the washout's tilt tracker and its cue
  limiter all run; for steps whose lengths vary (the motor drives' wall-clock frames),
  :func:`uneven_stop_speed`, :func:`least_travel` and :func:`ramp_toward`, the drive-side
  ramp's tracker; :func:`smoothstep`, the ramp of the soft start and the watchdog fade
  (compiled; callable from Python and from compiled code);
* rotations in the project's convention (Z-Y-X Euler angles, ``R = Rz(yaw) Ry(pitch)
  Rx(roll)`` maps body or platform vectors to base axes, FRD): :func:`rotation_matrix`,
  quaternions (:func:`quaternion_from_euler_zyx`, :func:`euler_zyx_from_quaternion`,
  defined in :mod:`motionbase.quaternions`, which imports the standard library only, for
  the log's writer process) and the Euler-rate kinematics
  (:func:`body_rates_from_euler_rates`).

The rotation has two definitions, one per layer: :func:`rotation_matrix` on numpy arrays
and :func:`rotation_terms`, compiled, which the platforms' kinematics kernels and the
classical washout's kernel call (the pipeline's hot loop, pinned bit for bit by the
recordings).

numba's on-disk cache keys a kernel on its own file only, and the compiled functions here
are inlined into kernels elsewhere: after changing one, delete the package's caches
(``find src -name '*.nb[ic]' -delete``) or the callers keep the old code compiled in.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike

from motionbase.quaternions import euler_zyx_from_quaternion, quaternion_from_euler_zyx

__all__ = [
    "MAX_ANGULAR_VELOCITY",
    "MAX_ATTITUDE",
    "MAX_SPECIFIC_FORCE",
    "STANDARD_GRAVITY",
    "body_rates_from_euler_rates",
    "brake_speed",
    "euler_zyx_from_quaternion",
    "least_travel",
    "quaternion_from_euler_zyx",
    "ramp_toward",
    "rotation_matrix",
    "rotation_terms",
    "smoothstep",
    "stop_speed",
    "track_toward",
    "uneven_stop_speed",
]

STANDARD_GRAVITY = 9.80665
"""Standard gravity, m/s^2 (level unaccelerated flight reads ``f = (0, 0, -g)``)."""

MAX_SPECIFIC_FORCE = 150.0
"""Largest plausible specific-force component, m/s^2 (about 15 g)."""
MAX_ANGULAR_VELOCITY = 20.0
"""Largest plausible body rate, rad/s (about 1150 deg/s)."""
MAX_ATTITUDE = 10.0
"""Largest plausible Euler angle, rad (any wrapped angle is below 2 pi)."""


@numba.njit(cache=True, inline="always")
def brake_speed(dist: float, u: float, dt: float) -> float:
    """Largest speed from which an actuator still stops within ``dist``, braking discretely.

    An actuator whose speed changes by at most ``u = a dt`` per tick of ``dt`` covers, from
    a speed ``v`` in ``[n u, (n + 1) u)``, ``d(v) = dt ((n + 1) v - u n (n + 1) / 2)`` before
    it stands still; this is the inverse of ``d``.

    Parameters
    ----------
    dist : float
        Distance left, in the actuator's unit (rad or m); <= 0 gives 0.
    u : float
        Speed change per tick, unit/s (> 0).
    dt : float
        Tick, s (> 0).

    Returns
    -------
    float
        Speed, unit/s (>= 0).
    """
    if dist <= 0.0:
        return 0.0
    n = np.floor((-1.0 + np.sqrt(1.0 + 8.0 * dist / (dt * u))) / 2.0)
    return (dist / dt + u * n * (n + 1.0) / 2.0) / (n + 1.0)


GLIDE_END = 0.1
"""A glide (:func:`stop_speed` with ``k > 0``) lands at this share of one tick's speed change."""


@numba.njit(cache=True, inline="always")
def stop_speed(dist: float, u: float, dt: float, k: float) -> float:
    """Largest speed at ``dist`` from where the motion must stop: :func:`brake_speed`, and
    with ``k > 0`` also the glide ``k dist + GLIDE_END u`` (deceleration proportional to the
    speed, time constant ``1/k``), whichever is lower; no bound (inf) for an infinite
    ``dist`` or ``u`` (no limit that way, no acceleration limit)."""
    if u == np.inf or dist == np.inf:
        return np.inf
    v = brake_speed(dist, u, dt)
    if k > 0.0:
        v = min(v, k * dist + GLIDE_END * u)
    return v


@numba.njit(cache=True, inline="always")
def track_toward(
    q0: float,
    v0: float,
    target_prev: float,
    target: float,
    dt: float,
    lower: float,
    upper: float,
    vmax: float,
    u: float,
    k: float,
) -> tuple[float, bool]:
    """One tick of a position toward a moving target within speed, acceleration and position
    limits: the rule of the safety limiter, the washout's tilt tracker and its cue limiter.

    The target's own speed (limited to ``vmax``) is fed forward; the error left is closed no
    faster than :func:`stop_speed` of it; the position never approaches ``lower`` or
    ``upper`` faster than it can stop before them; the speed changes by at most ``u`` a tick
    and stays within ``vmax``. When every limit allows the whole step the position lands on
    the target exactly (a held target is held bit for bit).

    Parameters
    ----------
    q0, v0 : float
        Position (unit) and speed (unit/s) after the previous tick.
    target_prev, target : float
        The previous tick's target and this tick's, unit (equal: a target at rest).
    dt : float
        Tick, s.
    lower, upper : float
        Position limits, unit (``-inf``, ``inf``: none); ``lower <= q0 <= upper``.
    vmax : float
        Speed limit, unit/s (inf: none).
    u : float
        Speed change allowed per tick, unit/s (``a_max dt``; inf: no acceleration limit).
    k : float
        The glide's ``a_max / v_max``, 1/s (0: the braking curve alone).

    Returns
    -------
    (float, bool)
        The new position, and whether a limit acted (the target was not reached).
    """
    vt = (target - target_prev) / dt
    return _toward(q0, v0, target, vt, dt, lower, upper, lower, upper, vmax, u, k, 0.0, 0.0)


@numba.njit(cache=True, inline="always")
def _toward(
    q0: float,
    v0: float,
    target: float,
    vt: float,
    dt: float,
    lo: float,
    hi: float,
    lower: float,
    upper: float,
    vmax: float,
    u: float,
    k: float,
    a: float,
    dt_min: float,
) -> tuple[float, bool]:
    """The one rule of :func:`track_toward` (fixed ticks, ``dt_min = 0``: stopping distances
    by :func:`stop_speed` of ``u`` and ``k``) and :func:`ramp_toward` (steps of at least
    ``dt_min``: by :func:`uneven_stop_speed` of the acceleration limit ``a``); ``lo`` and
    ``hi`` are what the position must be able to stop within, ``lower`` and ``upper`` its
    limits, ``u`` the speed change allowed in this step."""
    vt = min(max(vt, -vmax), vmax)
    e = target - q0 - vt * dt
    if dt_min > 0.0:
        cap = uneven_stop_speed(abs(e), a, dt, dt_min)
        v_hi = uneven_stop_speed(hi - q0, a, dt, dt_min)
        v_lo = -uneven_stop_speed(q0 - lo, a, dt, dt_min)
    else:
        cap = stop_speed(abs(e), u, dt, k)
        v_hi = stop_speed(hi - q0, u, dt, k)
        v_lo = -stop_speed(q0 - lo, u, dt, k)
    v_full = (target - q0) / dt
    if (
        abs(e) / dt <= cap
        and abs(v_full) <= vmax
        and abs(v_full - v0) <= u
        and v_lo <= v_full <= v_hi
    ):
        return target, False
    fb = min(cap, abs(e) / dt)
    v = vt + fb if e >= 0.0 else vt - fb
    v = min(max(v, v_lo), v_hi)
    v = min(max(v, v0 - u), v0 + u)
    v = min(max(v, -vmax), vmax)
    # safety net against rounding: never outside the limits
    return min(max(q0 + v * dt, lower), upper), True


@numba.njit(cache=True, inline="always")
def uneven_stop_speed(dist: float, a: float, dt: float, dt_min: float) -> float:
    """Largest speed for a step of ``dt`` after which an actuator still stops within ``dist``,
    whatever the lengths of its later steps, each at least ``dt_min``.

    A step of length ``h`` changes the speed by at most ``a h``. From a speed ``v`` the
    actuator covers ``v dt`` in this step; after it, braking fully at every step covers a
    right Riemann sum of ``v - a t``, at most ``(v - a dt_min / 2)^2 / (2 a)`` when every
    step is at least ``dt_min`` long, and nothing when ``v <= a dt_min`` (the next step
    stops it). The speed returned keeps ``v dt`` plus that bound within ``dist``; braking
    fully from it at the next step, however long, keeps the next step's bound within what
    is left, so steps that vary never carry the actuator past ``dist`` (unlike
    :func:`brake_speed`, whose curve holds for steps of one length).

    Parameters
    ----------
    dist : float
        Distance left, in the actuator's unit; <= 0 gives 0.
    a : float
        Acceleration limit, unit/s^2 (> 0; inf: no bound).
    dt : float
        This step, s (>= ``dt_min``).
    dt_min : float
        The shortest of the later steps, s (> 0).

    Returns
    -------
    float
        Speed, unit/s (>= 0).
    """
    if dist <= 0.0:
        return 0.0
    if a == np.inf or dist == np.inf:
        return np.inf
    um = a * dt_min
    v = min(dist / dt, um)
    # v dt + (v - um / 2)^2 / (2 a) = dist, for v >= um / 2
    w = np.sqrt(max(a * dt * (a * dt - um) + 2.0 * a * dist, 0.0)) - a * dt
    if w >= 0.0:
        v = max(v, 0.5 * um + w)
    return v


@numba.njit(cache=True, inline="always")
def least_travel(step: float, du: float) -> float:
    """How far a command that moved ``step`` on its last tick goes on at least, when its step
    changes by at most ``du`` a tick (``a_max dt^2``: commands that keep the acceleration
    limit, as the pipeline's do): ``sum over i >= 1 of max(step - i du, 0)``, the travel of
    braking at once. A command can come to rest no nearer than this; 0 for ``step <= du``.

    Parameters
    ----------
    step : float
        The last tick's step, in the actuator's unit (>= 0).
    du : float
        Largest change of the step from one tick to the next, same unit (> 0).
    """
    if step <= du:
        return 0.0
    n = np.floor(step / du)
    return n * step - du * n * (n + 1.0) / 2.0


@numba.njit(cache=True, inline="always")
def ramp_toward(
    q0: float,
    v0: float,
    target: float,
    vt: float,
    lo: float,
    hi: float,
    dt: float,
    dt_min: float,
    lower: float,
    upper: float,
    vmax: float,
    a: float,
) -> tuple[float, bool]:
    """One step of a motor drive toward its latest command, the steps' lengths varying (the
    wall-clock frames of :class:`motionbase.io.motor_output.MotorOutput`).

    As :func:`track_toward`: the command's own speed ``vt`` is fed forward, the error left is
    closed no faster than the drive can still stop, the position never approaches ``lo``
    or ``hi`` faster than it can stop before them, the speed changes by at most ``a dt``
    and stays within ``vmax``, and the drive lands on the command exactly when every limit
    allows the whole step. Every stopping distance is :func:`uneven_stop_speed`'s, which
    holds whatever the later steps' lengths (each at least ``dt_min``). ``lo`` and ``hi``
    are where the command could come to rest at the nearest (:func:`least_travel`; or the
    command itself), within the angle limits: a drive that never approaches them faster
    than it can stop never passes a command that comes to rest. They bound the speed
    only: the acceleration limit comes first, and the result is within ``lower`` and
    ``upper``.

    Parameters
    ----------
    q0, v0 : float
        Position (unit) and speed (unit/s) after the previous step.
    target : float
        The latest command, unit (within ``lower``, ``upper``).
    vt : float
        The command's own speed, unit/s (0: a command at rest).
    lo, hi : float
        Bounds the drive must be able to stop within, unit (``lo <= target <= hi``).
    dt : float
        This step, s (>= ``dt_min``).
    dt_min : float
        The shortest step, s.
    lower, upper : float
        Position limits, unit.
    vmax : float
        Speed limit, unit/s.
    a : float
        Acceleration limit, unit/s^2.

    Returns
    -------
    (float, bool)
        The new position, and whether a limit acted (the command was not reached).
    """
    return _toward(q0, v0, target, vt, dt, lo, hi, lower, upper, vmax, a * dt, 0.0, a, dt_min)


@numba.njit(cache=True, inline="always")
def smoothstep(x: float) -> float:
    """C1 ramp ``3 x^2 - 2 x^3`` from 0 (``x <= 0``) to 1 (``x >= 1``)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def rotation_terms(roll: float, pitch: float, yaw: float) -> tuple[float, ...]:
    """The nine entries ``(r00, r01, r02, r10, r11, r12, r20, r21, r22)`` of
    ``R = Rz(yaw) Ry(pitch) Rx(roll)``, row by row (angles in rad; compiled, for kernels:
    the platforms' kinematics and the washout's translational channel)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return (
        cy * cp,
        cy * sp * sr - sy * cr,
        cy * sp * cr + sy * sr,
        sy * cp,
        sy * sp * sr + cy * cr,
        sy * sp * cr - cy * sr,
        -sp,
        cp * sr,
        cp * cr,
    )


def rotation_matrix(rpy: ArrayLike) -> np.ndarray:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` for Euler angles ``(..., 3)`` -> ``(..., 3, 3)``.

    Parameters
    ----------
    rpy : array_like, shape (..., 3)
        Roll, pitch, yaw, rad (non-finite angles give NaN entries, quietly).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Maps body (platform) vectors to base axes.
    """
    a = np.asarray(rpy, dtype=np.float64)
    with np.errstate(invalid="ignore"):  # inf -> NaN entries, quietly
        cr, sr = np.cos(a[..., 0]), np.sin(a[..., 0])
        cp, sp = np.cos(a[..., 1]), np.sin(a[..., 1])
        cy, sy = np.cos(a[..., 2]), np.sin(a[..., 2])
    R = np.empty(a.shape[:-1] + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def body_rates_from_euler_rates(phi, theta, phidot, thetadot, psidot):
    """Body rates ``(p, q, r)`` from Z-Y-X Euler angle rates, rad/s.

    The inverse of ``phidot = p + (q sin phi + r cos phi) tan theta``,
    ``thetadot = q cos phi - r sin phi``, ``psidot = (q sin phi + r cos phi) / cos theta``.

    Parameters
    ----------
    phi, theta : float or ndarray
        Roll and pitch, rad.
    phidot, thetadot, psidot : float or ndarray
        Euler angle rates, rad/s (arrays broadcast together).

    Returns
    -------
    p, q, r : float or ndarray
        rad/s, body axes FRD.
    """
    sphi, cphi = np.sin(phi), np.cos(phi)
    sth, cth = np.sin(theta), np.cos(theta)
    p = phidot - sth * psidot
    q = cphi * thetadot + sphi * cth * psidot
    r = -sphi * thetadot + cphi * cth * psidot
    return p, q, r
