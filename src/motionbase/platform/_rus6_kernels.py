"""Compiled (numba) kernels of the 6-RUS kinematics. Internal: use :class:`Rus6`.

All kernels take the geometry packed into one array ``G`` of shape (6, NG) (see
:func:`pack_geometry`) and work on rows of poses ``[x, y, z, roll, pitch, yaw]``.
They compile lazily on first call and are cached on disk (``cache=True``). No fastmath:
NaN must propagate and comparisons with NaN must stay false. The rotation, the angle wrap
and the forward kinematics' damped Newton are shared with the Stewart platform
(:mod:`._pose_kernels`; after changing them there, delete this module's numba cache).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from motionbase.physics import rotation_terms
from motionbase.platform._pose_kernels import close_legs_batch, leg_closure, wrap

# Columns of the packed geometry array.
AX, AY, AZ, CX, CY, PX, PY, PZ, RC, RR, LO, HI, OX, OY, OZ = range(15)
NG = 16


def pack_geometry(pivots, cdir, joints_local, origin, crank, rod, lo, hi) -> np.ndarray:
    """Pack the per-leg geometry into a contiguous (6, 16) float64 array."""
    g = np.zeros((6, NG))
    g[:, AX : AZ + 1] = pivots
    g[:, CX] = cdir[:, 0]
    g[:, CY] = cdir[:, 1]
    g[:, PX : PZ + 1] = joints_local
    g[:, RC] = crank
    g[:, RR] = rod
    g[:, LO] = lo
    g[:, HI] = hi
    g[:, OX : OZ + 1] = origin
    return np.ascontiguousarray(g)


@njit(cache=True, nogil=True, error_model="numpy")
def _inverse_row(p, G, out):
    """Closed-form inverse kinematics of one pose (thesis eq. 8.57) into ``out`` (6,).

    For leg i with I = platform joint - crank pivot (base axes, m):
        u = 2 r (I . c)           (in-plane horizontal component, c = crank direction at 0)
        v = 2 r (I . up)          (vertical component, up = -z)
        w = R^2 - |I|^2 - r^2     (eq. 8.39)
        q = sqrt(u^2 + v^2 - w^2) (eq. 8.46; negative radicand: the leg cannot close)
    The closure u cos(theta) + v sin(theta) = -w gives theta = atan2(v, u) - atan2(q, -w)
    (eq. 8.57 written with atan2), evaluated as a single atan2 of the angle difference.
    Returns 0 if every leg closes, 1 if not (then the whole row is NaN).
    """
    x, y, z = p[0], p[1], p[2]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation_terms(p[3], p[4], p[5])
    bad = False
    for i in range(6):
        px, py, pz = G[i, PX], G[i, PY], G[i, PZ]
        ix = G[i, OX] + x + r00 * px + r01 * py + r02 * pz - G[i, AX]
        iy = G[i, OY] + y + r10 * px + r11 * py + r12 * pz - G[i, AY]
        iz = G[i, OZ] + z + r20 * px + r21 * py + r22 * pz - G[i, AZ]
        rc = G[i, RC]
        rr = G[i, RR]
        u = 2.0 * rc * (ix * G[i, CX] + iy * G[i, CY])
        v = -2.0 * rc * iz
        w = rr * rr - (ix * ix + iy * iy + iz * iz) - rc * rc
        disc = u * u + v * v - w * w
        if not disc >= 0.0:  # also catches NaN
            bad = True
            break
        q = math.sqrt(disc)
        out[i] = math.atan2(-v * w - u * q, -u * w + v * q)
    if bad:
        for i in range(6):
            out[i] = np.nan
        return 1
    return 0


@njit(cache=True, nogil=True, error_model="numpy")
def _within(out, G):
    for i in range(6):
        if not (G[i, LO] <= out[i] <= G[i, HI]):
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def inverse_batch(poses, G, out):
    """Crank angles (n, 6) of poses (n, 6); NaN rows where a leg cannot close."""
    for k in range(poses.shape[0]):
        _inverse_row(poses[k], G, out[k])


@njit(cache=True, nogil=True, error_model="numpy")
def reachable_batch(poses, G, out):
    """out[k] = every leg closes and every crank is within its limits."""
    tmp = np.empty(6)
    for k in range(poses.shape[0]):
        out[k] = _inverse_row(poses[k], G, tmp) == 0 and _within(tmp, G)


@njit(cache=True, nogil=True, error_model="numpy")
def _ok(p, G, tmp):
    return _inverse_row(p, G, tmp) == 0 and _within(tmp, G)


@njit(cache=True, nogil=True, error_model="numpy")
def _bisect_scale(base, delta, G, tmp, trial, n_iter, n_scan=32):
    """Largest s in [0, 1] with base + s*delta reachable, or -1 when none is found.

    The scale is scanned downward from 1 in ``n_scan`` uniform steps, then geometrically
    toward 0 (the reachable set along the segment need not start at s = 0: a translation
    can make a rotation reachable), then refined by bisection to 2^-n_iter between the
    largest reachable sample and the unreachable one above it. The pose
    ``base + s*delta`` was tested reachable with this very code.
    """
    for j in range(6):
        trial[j] = base[j] + delta[j]
    if _ok(trial, G, tmp):
        return 1.0
    lo = -1.0
    hi = 1.0
    sk = 1.0
    step = 1.0 / n_scan
    while sk > 0.0:
        # uniform steps down to `step`, then geometric ones (about 16 % apart) toward 0,
        # so a reachable stretch close to neutral is found for far-out inputs too
        if sk > 1.5 * step:
            sk -= step
        elif sk > 1e-9:
            sk *= 0.84
        else:
            sk = 0.0
        for j in range(6):
            trial[j] = base[j] + sk * delta[j]
        if _ok(trial, G, tmp):
            lo = sk
            break
        hi = sk
    if lo < 0.0:
        return -1.0
    for _ in range(n_iter):
        mid = 0.5 * (lo + hi)
        for j in range(6):
            trial[j] = base[j] + mid * delta[j]
        if _ok(trial, G, tmp):
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True, error_model="numpy")
def _clamp_row(p, G, out):
    """Priority-aware clamp of one pose into ``out``; returns True if out != p.

    1. Non-finite input -> neutral pose.
    2. Reachable as given -> unchanged.
    3. Euler angles wrapped to [-pi, pi) (same rotation); reachable -> that.
    4. Keep the rotation and scale the translation toward zero: the largest reachable
       scale, found by a scan and bisection.
    5. If no scale makes it reachable: zero translation and scale the rotation toward zero.
    The result was tested reachable (legs close, cranks within limits) by the same code
    ``reachable`` uses, so it is reachable bit for bit.
    """
    tmp = np.empty(6)
    trial = np.empty(6)
    base = np.zeros(6)
    delta = np.zeros(6)
    finite = True
    for j in range(6):
        if not math.isfinite(p[j]):
            finite = False
    if not finite:
        for j in range(6):
            out[j] = 0.0
        return True
    if _ok(p, G, tmp):
        for j in range(6):
            out[j] = p[j]
        return False
    for j in range(3):
        out[j] = p[j]
        out[3 + j] = wrap(p[3 + j])
    if _ok(out, G, tmp):
        return True
    # keep the rotation, scale the translation toward zero
    for j in range(3):
        base[j] = 0.0
        base[3 + j] = out[3 + j]
        delta[j] = out[j]
        delta[3 + j] = 0.0
    s = _bisect_scale(base, delta, G, tmp, trial, 52)
    if s < 0.0:
        # no translation makes the rotation reachable: zero translation, scale the rotation
        for j in range(6):
            delta[j] = base[j]
            base[j] = 0.0
        s = max(_bisect_scale(base, delta, G, tmp, trial, 52), 0.0)
    for j in range(6):
        out[j] = base[j] + s * delta[j]
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def joint_points_batch(poses, G, pivots, tips, joints):
    """Crank pivots, crank tips and platform joints (base axes, m) of poses (k, 6) into
    arrays (k, 6, 3); NaN tips where a pose cannot be closed (the joints are still the
    rigid-body positions)."""
    theta = np.empty(6)
    for k in range(poses.shape[0]):
        p = poses[k]
        _inverse_row(p, G, theta)
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation_terms(p[3], p[4], p[5])
        for i in range(6):
            px, py, pz = G[i, PX], G[i, PY], G[i, PZ]
            joints[k, i, 0] = G[i, OX] + p[0] + r00 * px + r01 * py + r02 * pz
            joints[k, i, 1] = G[i, OY] + p[1] + r10 * px + r11 * py + r12 * pz
            joints[k, i, 2] = G[i, OZ] + p[2] + r20 * px + r21 * py + r22 * pz
            c, s = math.cos(theta[i]), math.sin(theta[i])
            rc = G[i, RC]
            pivots[k, i, 0] = G[i, AX]
            pivots[k, i, 1] = G[i, AY]
            pivots[k, i, 2] = G[i, AZ]
            tips[k, i, 0] = G[i, AX] + rc * c * G[i, CX]
            tips[k, i, 1] = G[i, AY] + rc * c * G[i, CY]
            tips[k, i, 2] = G[i, AZ] - rc * s  # up is -z (FRD)


@njit(cache=True, nogil=True, error_model="numpy")
def clamp_batch(poses, G, out, flags):
    for k in range(poses.shape[0]):
        flags[k] = _clamp_row(poses[k], G, out[k])


@njit(cache=True, nogil=True, error_model="numpy")
def clamp_inverse_one(p, G, out_pose, out_angles):
    """Clamp one pose and solve its crank angles in one call (the real-time path)."""
    clamped = _clamp_row(p, G, out_pose)
    _inverse_row(out_pose, G, out_angles)
    return clamped


@njit(cache=True, nogil=True, error_model="numpy")
def _crank_tips(theta, G, tips, rods):
    """Crank tips (6, 3) (base axes, m) of the crank angles ``theta`` (6,), and the rod
    lengths (6,): the base-side ends of the legs that :func:`._pose_kernels.leg_closure`
    closes onto the platform."""
    for i in range(6):
        c, s = math.cos(theta[i]), math.sin(theta[i])
        rc = G[i, RC]
        tips[i, 0] = G[i, AX] + rc * c * G[i, CX]
        tips[i, 1] = G[i, AY] + rc * c * G[i, CY]
        tips[i, 2] = G[i, AZ] - rc * s  # up is -z (FRD)
        rods[i] = G[i, RR]


@njit(cache=True, nogil=True, error_model="numpy")
def _constraint_jacobian(p, theta, G, R, tips, rods, jx, jq, resid, omega=False):
    """Leg-closure constraints g_i = |P_i - B_i|^2 - R_i^2 and their derivatives.

    jx[i, :] = dg_i/d(pose rate): columns 3..5 per unit Euler-angle rate (omega=False) or per
    unit angular velocity in base axes (omega=True); jq[i] = dg_i/dtheta_i; resid[i] = g_i (m^2).
    ``tips`` (6, 3) and ``rods`` (6,): scratch.
    """
    _crank_tips(theta, G, tips, rods)
    leg_closure(p, tips, rods, G[:, PX : PZ + 1], G[:, OX : OZ + 1], R, jx, resid, omega)
    for i in range(6):
        rc = G[i, RC]
        ct, st = math.cos(theta[i]), math.sin(theta[i])
        ex, ey, ez = 0.5 * jx[i, 0], 0.5 * jx[i, 1], 0.5 * jx[i, 2]
        # dB/dtheta = r (-sin c + cos up), up = (0, 0, -1)
        dbx = -rc * st * G[i, CX]
        dby = -rc * st * G[i, CY]
        dbz = -rc * ct
        jq[i] = -2.0 * (ex * dbx + ey * dby + ez * dbz)


@njit(cache=True, nogil=True, error_model="numpy")
def jacobian_batch(poses, G, omega, out, lines, jqs):
    """d(theta)/d(pose rate) (n, 6, 6) plus the raw constraint derivatives.

    omega=False: pose rate = [xdot, ydot, zdot, roll rate, pitch rate, yaw rate] (Euler rates).
    omega=True: the last three are the angular velocity in base axes.
    ``lines[k]`` = dg/d[v, omega] (6, 6) (the rod lines, scaled by 2 |rod|), ``jqs[k]`` =
    dg/dtheta (6,). NaN where the pose cannot be closed; inf entries at an exact singularity.
    """
    theta = np.empty(6)
    R = np.empty((3, 3))
    tips = np.empty((6, 3))
    rods = np.empty(6)
    jx = np.empty((6, 6))
    jq = np.empty(6)
    res = np.empty(6)
    for k in range(poses.shape[0]):
        p = poses[k]
        if _inverse_row(p, G, theta) != 0:
            out[k, :, :] = np.nan
            lines[k, :, :] = np.nan
            jqs[k, :] = np.nan
            continue
        _constraint_jacobian(p, theta, G, R, tips, rods, jx, jq, res, True)
        for i in range(6):
            jqs[k, i] = jq[i]
            for j in range(6):
                lines[k, i, j] = jx[i, j]
        if not omega:
            _constraint_jacobian(p, theta, G, R, tips, rods, jx, jq, res, False)
        for i in range(6):
            for j in range(6):
                out[k, i, j] = -jx[i, j] / jq[i]


@njit(cache=True, nogil=True, error_model="numpy")
def forward_batch(angles, guesses, G, tol, max_iter, out, iters):
    """Forward kinematics: the crank tips of the angles (k, 6), then the rods closed onto
    the platform by the shared damped Newton (:func:`._pose_kernels.close_legs_batch`: its
    convergence rule, NaN rows for a failure or a non-finite angle, ``iters``)."""
    n = angles.shape[0]
    tips = np.empty((n, 6, 3))
    rods = np.empty((n, 6))
    for k in range(n):
        _crank_tips(angles[k], G, tips[k], rods[k])
    close_legs_batch(
        tips, rods, G[:, PX : PZ + 1], G[:, OX : OZ + 1], guesses, tol, max_iter, out, iters
    )


@njit(
    "boolean(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1])",
    cache=True,
    nogil=True,
    error_model="numpy",
)
def solve(params, target, cue_out, pose_out, q_out):
    """The robot plug-in's kernel (:data:`motionbase.platform.robot.SOLVE_SIGNATURE`):
    clamp the cue pose, solve the cranks; the 6-RUS renders the cue pose as it is."""
    G = params.reshape((6, NG))
    if _inverse_row(target, G, q_out) == 0 and _within(q_out, G):
        clamped = False  # reachable as it is (what the clamp finds first): solved once
        for j in range(6):
            pose_out[j] = target[j]
    else:
        clamped = clamp_inverse_one(target, G, pose_out, q_out)
    for j in range(6):
        cue_out[j] = pose_out[j]
    return clamped
