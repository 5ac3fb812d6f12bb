"""Compiled (numba) kernels of the planar 3-RRR kinematics. Internal: use :class:`Rrr3`.

The hot path of :mod:`motionbase.platform.rrr3` (validity check, inverse kinematics by the
tangent half-angle substitution, servo mapping, clamping toward home) and the workspace sweep of
:mod:`motionbase.platform.rrr3_workspace`, one pose at a time with loops for batches. All
kernels take the geometry packed into one float64 array ``p`` (see :func:`pack_geometry`).
They compile lazily on first call and are cached on disk (``cache=True``). No fastmath: NaN must
propagate and comparisons with NaN must stay false.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Status bits returned by :func:`solve_one` and :meth:`Rrr3.status` (0 means the pose is valid).
OK = 0
UNREACHABLE = 1  #: no real inverse kinematics solution for some chain (or a NaN input)
TYPE1 = 2  #: within the type I (inverse) singularity margin
TYPE2 = 4  #: within the type II (direct) singularity margin
SERVO_RANGE = 8  #: some servo's degrees fall outside its range

# Packed parameter layout for the kernels.
_P_A, _P_C, _P_CRANK, _P_ROD = 0, 6, 12, 13
_P_MODE, _P_ZERO, _P_DIR, _P_MIN, _P_MAX = 14, 17, 20, 23, 26
_P_M1, _P_M2, _P_RC = 29, 30, 31
_P_SIZE = 32


def pack_geometry(
    base_points,
    platform_points,
    crank,
    rod,
    modes,
    servo_zero_deg,
    servo_direction,
    servo_min_deg,
    servo_max_deg,
    type1_margin,
    type2_margin,
    platform_radius,
) -> np.ndarray:
    """Pack a 3-RRR geometry into the (32,) float64 array the kernels read.

    Parameters
    ----------
    base_points, platform_points : array_like (3, 2)
        Motor axes ``A_i`` (base frame) and platform joints ``C_i`` (platform frame), m.
    crank, rod : float
        ``a`` and ``b``, m.
    modes, servo_direction : 3 ints (+1 or -1)
    servo_zero_deg : 3 floats, deg
    servo_min_deg, servo_max_deg : 3 ints, servo degrees
    type1_margin, type2_margin : float
        Dimensionless singularity margins.
    platform_radius : float
        ``h / sqrt(3)``, distance of the platform joints from the centroid, m.
    """
    p = np.zeros(_P_SIZE)
    p[_P_A : _P_A + 6] = np.asarray(base_points).ravel()
    p[_P_C : _P_C + 6] = np.asarray(platform_points).ravel()
    p[_P_CRANK] = crank
    p[_P_ROD] = rod
    p[_P_MODE : _P_MODE + 3] = modes
    p[_P_ZERO : _P_ZERO + 3] = servo_zero_deg
    p[_P_DIR : _P_DIR + 3] = servo_direction
    p[_P_MIN : _P_MIN + 3] = servo_min_deg
    p[_P_MAX : _P_MAX + 3] = servo_max_deg
    p[_P_M1] = type1_margin
    p[_P_M2] = type2_margin
    p[_P_RC] = platform_radius
    return p


@njit(cache=True, fastmath=False)
def solve_one(x, y, phi, p, theta, servo):  # pragma: no cover - compiled
    """Inverse kinematics + validity of one pose; writes theta (rad) and servo (deg).

    Returns the status word (0 = valid). Unreachable chains get theta = NaN, servo = -1.
    """
    status = 0
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(phi)):
        for i in range(3):
            theta[i] = math.nan
            servo[i] = -1
        return UNREACHABLE
    a = p[_P_CRANK]
    b = p[_P_ROD]
    c = math.cos(phi)
    s = math.sin(phi)
    # Jx rows for the type II test.
    j00 = j01 = j02 = j10 = j11 = j12 = j20 = j21 = j22 = 0.0
    for i in range(3):
        lx = p[_P_C + 2 * i]
        ly = p[_P_C + 2 * i + 1]
        ex = c * lx - s * ly
        ey = s * lx + c * ly
        cx = x + ex
        cy = y + ey
        ax = p[_P_A + 2 * i]
        ay = p[_P_A + 2 * i + 1]
        xc = cx - ax
        yc = cy - ay
        e1 = -2.0 * a * yc
        e2 = -2.0 * a * xc
        e3 = xc * xc + yc * yc + a * a - b * b
        disc = e1 * e1 + e2 * e2 - e3 * e3
        if disc < 0.0:
            theta[i] = math.nan
            servo[i] = -1
            status |= UNREACHABLE
            continue
        sq = math.sqrt(disc)
        m = p[_P_MODE + i]
        n1 = -e1 + m * sq
        d1 = e3 - e2
        n2 = e3 + e2
        d2 = -e1 - m * sq
        # t = n1/d1 = n2/d2 (product of the roots): take the better-conditioned quotient.
        if abs(n1) + abs(d1) >= abs(n2) + abs(d2):
            th = 2.0 * math.atan2(n1, d1)
        else:
            th = 2.0 * math.atan2(n2, d2)
        if th > math.pi:
            th -= 2.0 * math.pi
        elif th <= -math.pi:
            th += 2.0 * math.pi
        theta[i] = th
        ux = a * math.cos(th)
        uy = a * math.sin(th)
        nx = xc - ux
        ny = yc - uy
        jq = ux * ny - uy * nx
        if abs(jq) < p[_P_M1] * a * b:
            status |= TYPE1
        jr = ex * ny - ey * nx
        if i == 0:
            j00, j01, j02 = nx, ny, jr
        elif i == 1:
            j10, j11, j12 = nx, ny, jr
        else:
            j20, j21, j22 = nx, ny, jr
        # servo mapping
        deg = th * (180.0 / math.pi)
        sd = (p[_P_DIR + i] * (deg - p[_P_ZERO + i])) % 360.0
        r = math.floor(sd + 0.5)
        if r >= 360.0:
            r -= 360.0
        if r < p[_P_MIN + i] or r > p[_P_MAX + i]:
            status |= SERVO_RANGE
        servo[i] = int(r)
    if status & UNREACHABLE:
        return status
    det = (
        j00 * (j11 * j22 - j12 * j21)
        - j01 * (j10 * j22 - j12 * j20)
        + j02 * (j10 * j21 - j11 * j20)
    )
    if abs(det) < p[_P_M2] * b * b * b * p[_P_RC]:
        status |= TYPE2
    return status


@njit(cache=True)
def solve_batch(poses, p):  # pragma: no cover - compiled
    """:func:`solve_one` over poses (n, 3): ``(theta (n, 3), servo (n, 3), status (n,))``."""
    n = poses.shape[0]
    theta = np.empty((n, 3))
    servo = np.empty((n, 3), dtype=np.int64)
    status = np.empty(n, dtype=np.int64)
    for k in range(n):
        status[k] = solve_one(poses[k, 0], poses[k, 1], poses[k, 2], p, theta[k], servo[k])
    return theta, servo, status


@njit(cache=True)
def status_grid(xs, ys, phis, p):  # pragma: no cover - compiled
    """Status of every (x, y, phi) of a grid, shape (len(xs), len(ys), len(phis))."""
    out = np.empty((xs.size, ys.size, phis.size), dtype=np.int8)
    theta = np.empty(3)
    servo = np.empty(3, dtype=np.int64)
    for i in range(xs.size):
        for j in range(ys.size):
            for k in range(phis.size):
                out[i, j, k] = solve_one(xs[i], ys[j], phis[k], p, theta, servo)
    return out


@njit(cache=True)
def clamp_one(x, y, phi, hx, hy, hphi, p, n_samples, n_bisect, theta, servo):  # pragma: no cover
    """Move (x, y, phi) toward home along the segment until valid.

    Returns (x, y, phi, clamped, status). The result is the farthest point from home such that
    every sample of the segment from home to it is valid (n_samples uniform samples, then
    n_bisect bisection steps on the first invalid interval). status != 0 only when home itself
    is invalid or the input is not finite.
    """
    st = solve_one(x, y, phi, p, theta, servo)
    if st == 0:
        return x, y, phi, False, 0
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(phi)):
        st = solve_one(hx, hy, hphi, p, theta, servo)
        return hx, hy, hphi, True, st | UNREACHABLE
    dx = x - hx
    dy = y - hy
    dp = phi - hphi
    lo = 0.0
    hi = 1.0
    for k in range(1, n_samples + 1):
        f = k / n_samples
        if solve_one(hx + f * dx, hy + f * dy, hphi + f * dp, p, theta, servo) != 0:
            hi = f
            break
        lo = f
    for _ in range(n_bisect):
        mid = 0.5 * (lo + hi)
        if solve_one(hx + mid * dx, hy + mid * dy, hphi + mid * dp, p, theta, servo) == 0:
            lo = mid
        else:
            hi = mid
    cx = hx + lo * dx
    cy = hy + lo * dy
    cp = hphi + lo * dp
    st = solve_one(cx, cy, cp, p, theta, servo)
    return cx, cy, cp, True, st


@njit(cache=True)
def clamp_batch(poses, home, p, n_samples, n_bisect):  # pragma: no cover - compiled
    """:func:`clamp_one` over poses (n, 3): ``(poses (n, 3), clamped (n,), status (n,))``."""
    n = poses.shape[0]
    out = np.empty((n, 3))
    clamped = np.empty(n, dtype=np.bool_)
    status = np.empty(n, dtype=np.int64)
    theta = np.empty(3)
    servo = np.empty(3, dtype=np.int64)
    for k in range(n):
        cx, cy, cp, cl, st = clamp_one(
            poses[k, 0],
            poses[k, 1],
            poses[k, 2],
            home[0],
            home[1],
            home[2],
            p,
            n_samples,
            n_bisect,
            theta,
            servo,
        )
        out[k, 0] = cx
        out[k, 1] = cy
        out[k, 2] = cp
        clamped[k] = cl
        status[k] = st
    return out, clamped, status
