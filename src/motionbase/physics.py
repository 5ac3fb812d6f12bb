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
* :func:`brake_speed`, the discrete braking curve of the safety limiter and the washout's
  tilt tracker, and :func:`smoothstep`, the ramp of the soft start and the watchdog fade
  (compiled; callable from Python and from compiled code);
* rotations in the project's convention (Z-Y-X Euler angles, ``R = Rz(yaw) Ry(pitch)
  Rx(roll)`` maps body or platform vectors to base axes, FRD): :func:`rotation_matrix`,
  quaternions (:func:`quaternion_from_euler_zyx`, :func:`euler_zyx_from_quaternion`,
  defined in :mod:`motionbase.quaternions`, which imports the standard library only, for
  the log's writer process) and the Euler-rate kinematics
  (:func:`body_rates_from_euler_rates`).

The compiled kernels of the 6-RUS and the Stewart platform keep their own scalar rotation
(:mod:`motionbase.platform`), and the classical washout's kernel its inlined one: those are
the hot loops of the pipeline, pinned bit for bit by the recordings.
"""

from __future__ import annotations

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
    "quaternion_from_euler_zyx",
    "rotation_matrix",
    "smoothstep",
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


@numba.njit(cache=True, inline="always")
def smoothstep(x: float) -> float:
    """C1 ramp ``3 x^2 - 2 x^3`` from 0 (``x <= 0``) to 1 (``x >= 1``)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


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
