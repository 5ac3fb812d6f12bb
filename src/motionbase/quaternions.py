"""Quaternions of the project's rotations, in plain Python (the standard library only).

Z-Y-X Euler angles ``(roll, pitch, yaw)``, rad, ``R = Rz(yaw) Ry(pitch) Rx(roll)`` maps
child-frame (body, platform) vectors to the parent frame; quaternions are ``(x, y, z, w)``.
:mod:`motionbase.physics` gives them with the rest of the shared maths; they live here so
that the MCAP log's writer process (:mod:`motionbase.io.log_writer`), which builds the
``/tf`` transforms, needs neither numpy nor numba.
"""

from __future__ import annotations

import math

__all__ = ["euler_zyx_from_quaternion", "quaternion_from_euler_zyx"]


def quaternion_from_euler_zyx(roll: float, pitch: float, yaw: float) -> tuple[float, ...]:
    """Unit quaternion ``(x, y, z, w)`` of R = Rz(yaw) Ry(pitch) Rx(roll).

    Parameters
    ----------
    roll, pitch, yaw : float
        Z-Y-X Euler angles, rad.

    Returns
    -------
    tuple of 4 floats
        ``(x, y, z, w)``, the rotation that maps child-frame vectors to the
        parent frame, with ``w >= 0`` for small angles.
    """
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def euler_zyx_from_quaternion(x: float, y: float, z: float, w: float) -> tuple[float, float, float]:
    """Z-Y-X Euler angles ``(roll, pitch, yaw)``, rad, of the quaternion ``(x, y, z, w)``.

    The inverse of :func:`quaternion_from_euler_zyx` (for pitch inside +-pi/2). The
    quaternion is normalised first; it must not be zero (a caller checks its norm).
    Roll and yaw are in [-pi, pi], pitch in [-pi/2, pi/2].
    """
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw
