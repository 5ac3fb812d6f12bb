"""Compiled (numba) kernels of the 6-UPS Stewart platform. Internal: use :class:`Stewart6`.

All kernels take the geometry packed into one array ``G`` of shape (6, NG) (see
:func:`pack_geometry`) and work on rows of poses ``[x, y, z, roll, pitch, yaw]`` (m, rad; FRD
base axes; ``R = Rz(yaw) Ry(pitch) Rx(roll)``). Leg ``i`` joins the base joint ``B_i`` to the
platform joint ``P_i = O + p + R q_i``; its actuator length is ``|P_i - B_i|``. This module is
the one definition of that formula: the class, the clamp and the forward kinematics all call
:func:`_platform_joints`. The rotation, the angle wrap and the 6x6 solver are shared with the
6-RUS (``_pose_kernels``); :func:`solve` is the robot plug-in's kernel.

They compile lazily on first call and are cached on disk (``cache=True``). No fastmath: NaN
must propagate and comparisons with NaN must stay false. numba's on-disk cache keys a kernel
on its own file only: after changing ``_pose_kernels.py``, delete this module's cache
(``__pycache__/_stewart6_kernels*.nb[ic]``) or it keeps the old code compiled in.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from motionbase.platform._pose_kernels import rotation, solve6, wrap

# Columns of the packed geometry array.
BX, BY, BZ, QX, QY, QZ, OX, OY, OZ, LO, HI = range(11)
NG = 11

#: Upward scan of the clamp: samples of the scale s in (0, 1] before bisection.
N_SCAN = 32


def pack_geometry(base, local, origin, lo, hi) -> np.ndarray:
    """Pack the per-leg geometry into a contiguous (6, 11) float64 array."""
    g = np.zeros((6, NG))
    g[:, BX : BZ + 1] = base
    g[:, QX : QZ + 1] = local
    g[:, OX : OZ + 1] = origin
    g[:, LO] = lo
    g[:, HI] = hi
    return np.ascontiguousarray(g)


@njit(cache=True, nogil=True, error_model="numpy")
def _platform_joints(p, G, R, J):
    """Rotation ``R`` (3, 3) and platform joints ``J`` (6, 3) in base axes of pose ``p``."""
    rotation(p[3], p[4], p[5], R)
    for i in range(6):
        qx, qy, qz = G[i, QX], G[i, QY], G[i, QZ]
        J[i, 0] = G[i, OX] + p[0] + R[0, 0] * qx + R[0, 1] * qy + R[0, 2] * qz
        J[i, 1] = G[i, OY] + p[1] + R[1, 0] * qx + R[1, 1] * qy + R[1, 2] * qz
        J[i, 2] = G[i, OZ] + p[2] + R[2, 0] * qx + R[2, 1] * qy + R[2, 2] * qz


@njit(cache=True, nogil=True, error_model="numpy")
def _lengths(p, G, R, J, out):
    """Actuator lengths ``|P_i - B_i|`` (m) of pose ``p`` into ``out`` (6,); NaN in, NaN out."""
    _platform_joints(p, G, R, J)
    for i in range(6):
        ex = J[i, 0] - G[i, BX]
        ey = J[i, 1] - G[i, BY]
        ez = J[i, 2] - G[i, BZ]
        out[i] = math.sqrt(ex * ex + ey * ey + ez * ez)


@njit(cache=True, nogil=True, error_model="numpy")
def _ok(p, G, R, J, L):
    """Reachable: every length within its limits, every platform joint above its base joint
    (FRD: smaller z) and the platform upright (its normal points up, ``R[2, 2] > 0``).

    The last two exclude the mirror solutions of the length equations (the platform below the
    base, or upside down) that no real hexapod reaches. False for NaN.
    """
    _lengths(p, G, R, J, L)
    if not R[2, 2] > 0.0:
        return False
    for i in range(6):
        if not (G[i, LO] <= L[i] <= G[i, HI]):
            return False
        if not J[i, 2] < G[i, BZ]:
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def inverse_batch(poses, G, out):
    """Actuator lengths (n, 6), m, of poses (n, 6); NaN rows for non-finite poses."""
    R = np.empty((3, 3))
    J = np.empty((6, 3))
    for k in range(poses.shape[0]):
        _lengths(poses[k], G, R, J, out[k])


@njit(cache=True, nogil=True, error_model="numpy")
def joints_batch(poses, G, out):
    """Platform joints (n, 6, 3) in base axes, m, of poses (n, 6)."""
    R = np.empty((3, 3))
    for k in range(poses.shape[0]):
        _platform_joints(poses[k], G, R, out[k])


@njit(cache=True, nogil=True, error_model="numpy")
def reachable_batch(poses, G, out):
    """out[k] = pose k is reachable (see :func:`_ok`)."""
    R = np.empty((3, 3))
    J = np.empty((6, 3))
    L = np.empty(6)
    for k in range(poses.shape[0]):
        out[k] = _ok(poses[k], G, R, J, L)


@njit(cache=True, nogil=True, error_model="numpy")
def _clamp_row(p, G, out):
    """Scale one pose toward neutral until reachable, into ``out``; True if out != p.

    1. Non-finite input -> the neutral pose.
    2. Reachable as given -> unchanged.
    3. Euler angles wrapped to [-pi, pi) (the same rotation); reachable -> that.
    4. Otherwise the whole (wrapped) pose ``w`` is scaled, ``out = s * w``: ``s`` samples
       (0, 1] upward in ``N_SCAN`` steps to the first unreachable sample, then bisection
       between the last reachable scale (0 = neutral at worst) and it, down to adjacent
       floats. So the result is the point where the line from neutral first leaves the
       workspace (to the scan's resolution), never one leg's clamp.
    The result was tested reachable by the same code :func:`reachable_batch` runs, so it is
    reachable bit for bit.
    """
    R = np.empty((3, 3))
    J = np.empty((6, 3))
    L = np.empty(6)
    trial = np.empty(6)
    for j in range(6):
        if not math.isfinite(p[j]):
            for m in range(6):
                out[m] = 0.0
            return True
    if _ok(p, G, R, J, L):
        for j in range(6):
            out[j] = p[j]
        return False
    for j in range(3):
        out[j] = p[j]
        out[3 + j] = wrap(p[3 + j])
    if _ok(out, G, R, J, L):
        return True
    lo = 0.0
    hi = 1.0
    for k in range(1, N_SCAN + 1):
        s = k / N_SCAN
        for j in range(6):
            trial[j] = s * out[j]
        if not _ok(trial, G, R, J, L):
            hi = s
            break
        lo = s
    for _ in range(1100):  # enough to reach adjacent floats even for a 1e300 input
        mid = 0.5 * (lo + hi)
        if not (lo < mid < hi):
            break
        for j in range(6):
            trial[j] = mid * out[j]
        if _ok(trial, G, R, J, L):
            lo = mid
        else:
            hi = mid
    for j in range(6):
        out[j] = lo * out[j]
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def clamp_batch(poses, G, out, flags):
    for k in range(poses.shape[0]):
        flags[k] = _clamp_row(poses[k], G, out[k])


@njit(cache=True, nogil=True, error_model="numpy")
def clamp_inverse_one(p, G, out_pose, out_lengths):
    """Clamp one pose and compute its actuator lengths in one call (the real-time path)."""
    R = np.empty((3, 3))
    J = np.empty((6, 3))
    clamped = _clamp_row(p, G, out_pose)
    _lengths(out_pose, G, R, J, out_lengths)
    return clamped


@njit(cache=True, nogil=True, error_model="numpy")
def _residual(x, lengths, G, R, J, jac, res):
    """Leg equations ``g_i = |P_i - B_i|^2 - L_i^2`` (m^2) and their analytic Jacobian.

    ``jac[i, :3] = 2 e_i`` and ``jac[i, 3 + k] = 2 ((R q_i) x e_i) . a_k`` with
    ``e_i = P_i - B_i`` and ``a_k`` the angular velocity (base axes) per unit rate of Euler
    angle k: roll -> Rz Ry e_x, pitch -> Rz e_y, yaw -> e_z. Returns the worst length error,
    m (``|g_i| / (2 L_i)``, to first order ``| |e_i| - L_i |``).
    """
    _platform_joints(x, G, R, J)
    cp, sp = math.cos(x[4]), math.sin(x[4])
    cy, sy = math.cos(x[5]), math.sin(x[5])
    a0x, a0y, a0z = cy * cp, sy * cp, -sp
    a1x, a1y = -sy, cy
    worst = 0.0
    for i in range(6):
        ex = J[i, 0] - G[i, BX]
        ey = J[i, 1] - G[i, BY]
        ez = J[i, 2] - G[i, BZ]
        rqx = J[i, 0] - G[i, OX] - x[0]
        rqy = J[i, 1] - G[i, OY] - x[1]
        rqz = J[i, 2] - G[i, OZ] - x[2]
        res[i] = ex * ex + ey * ey + ez * ez - lengths[i] * lengths[i]
        jac[i, 0] = 2.0 * ex
        jac[i, 1] = 2.0 * ey
        jac[i, 2] = 2.0 * ez
        cx_ = rqy * ez - rqz * ey
        cy_ = rqz * ex - rqx * ez
        cz_ = rqx * ey - rqy * ex
        jac[i, 3] = 2.0 * (cx_ * a0x + cy_ * a0y + cz_ * a0z)
        jac[i, 4] = 2.0 * (cx_ * a1x + cy_ * a1y)
        jac[i, 5] = 2.0 * cz_
        err = abs(res[i]) / (2.0 * lengths[i])
        if not err <= worst:  # NaN becomes the worst
            worst = err
    return worst


@njit(cache=True, nogil=True, error_model="numpy")
def forward_batch(lengths, guesses, G, tol, max_iter, out, iters):
    """Forward kinematics by damped Newton on the leg-length equations.

    Converged when the Newton step is below ``tol`` (m, rad) and every length error is below
    ``tol`` (m). Rows that do not converge (or have non-finite or non-positive lengths, or a
    non-finite guess) become NaN; ``iters[k]`` is the iteration count (-1 for a failure).
    """
    R = np.empty((3, 3))
    J = np.empty((6, 3))
    jac = np.empty((6, 6))
    res = np.empty(6)
    rhs = np.empty(6)
    dx = np.empty(6)
    x = np.empty(6)
    trial = np.empty(6)
    for k in range(lengths.shape[0]):
        ln = lengths[k]
        ok = True
        for j in range(6):
            x[j] = guesses[k, j]
            if not (math.isfinite(ln[j]) and ln[j] > 0.0 and math.isfinite(x[j])):
                ok = False
        converged = False
        n = 0
        if ok:
            err = _residual(x, ln, G, R, J, jac, res)
            while n < max_iter and math.isfinite(err):
                n += 1
                for i in range(6):
                    rhs[i] = -res[i]
                if not solve6(jac, rhs, dx):
                    break
                step = 0.0
                for j in range(6):
                    if abs(dx[j]) > step:
                        step = abs(dx[j])
                # backtracking: accept the first step length that lowers the error
                t = 1.0
                new_err = err
                for _ in range(30):
                    for j in range(6):
                        trial[j] = x[j] + t * dx[j]
                    new_err = _residual(trial, ln, G, R, J, jac, res)
                    if new_err < err or new_err <= tol:
                        break
                    t *= 0.5
                for j in range(6):
                    x[j] = trial[j]
                err = new_err
                if step * t <= tol and err <= tol:
                    converged = True
                    break
        if converged:
            for j in range(6):
                out[k, j] = x[j]
            iters[k] = n
        else:
            for j in range(6):
                out[k, j] = np.nan
            iters[k] = -1


@njit(
    "boolean(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1])",
    cache=True,
    nogil=True,
    error_model="numpy",
)
def solve(params, target, cue_out, pose_out, q_out):
    """The robot plug-in's kernel (:data:`motionbase.platform.robot.SOLVE_SIGNATURE`):
    clamp the cue pose, solve the actuator lengths; the platform renders the cue pose as
    it is (robot pose = cue pose)."""
    clamped = clamp_inverse_one(target, params.reshape((6, NG)), pose_out, q_out)
    for j in range(6):
        cue_out[j] = pose_out[j]
    return clamped
