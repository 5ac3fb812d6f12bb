"""Compiled (numba) kernels of the 6-UPS Stewart platform. Internal: use :class:`Stewart6`.

All kernels take the geometry packed into one array ``G`` of shape (6, NG) (see
:func:`pack_geometry`) and work on rows of poses ``[x, y, z, roll, pitch, yaw]`` (m, rad; FRD
base axes; ``R = Rz(yaw) Ry(pitch) Rx(roll)``). Leg ``i`` joins the base joint ``B_i`` to the
platform joint ``P_i = O + p + R q_i``; its actuator length is ``|P_i - B_i|``. This module is
the one definition of that formula for the class and the clamp (:func:`_platform_joints`).
The rotation, the angle wrap and the forward kinematics (damped Newton on the leg
lengths) are shared with the 6-RUS (``_pose_kernels``); :func:`solve` is the robot
plug-in's kernel.

They compile lazily on first call and are cached on disk (``cache=True``). No fastmath: NaN
must propagate and comparisons with NaN must stay false. numba's on-disk cache keys a kernel
on its own file only: after changing ``_pose_kernels.py``, delete this module's cache
(``__pycache__/_stewart6_kernels*.nb[ic]``) or it keeps the old code compiled in.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from motionbase.platform._pose_kernels import close_legs_batch, rotation, wrap
from motionbase.platform.conditioning import MIN_LINE_CONDITIONING

# Columns of the packed geometry array (SCALE: the length dividing the legs' moments in
# the line conditioning, m, the same in every row).
BX, BY, BZ, QX, QY, QZ, OX, OY, OZ, LO, HI, SCALE = range(12)
NG = 12

#: Upward scan of the clamp: samples of the scale s in (0, 1] before bisection.
N_SCAN = 32


def pack_geometry(base, local, origin, lo, hi, scale) -> np.ndarray:
    """Pack the per-leg geometry into a contiguous (6, 12) float64 array (``scale``: the
    length, m, that turns the legs' moments into forces in the line conditioning)."""
    g = np.zeros((6, NG))
    g[:, BX : BZ + 1] = base
    g[:, QX : QZ + 1] = local
    g[:, OX : OZ + 1] = origin
    g[:, LO] = lo
    g[:, HI] = hi
    g[:, SCALE] = scale
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
def _holds(p, G, J, L):
    """Whether the legs' lines at the platform joints ``J`` (lengths ``L``, both of pose ``p``)
    hold the platform: ``1 / cond_2`` of the rows ``M_i = [u_i, (R q_i x u_i) / scale]`` at
    least :data:`~motionbase.platform.conditioning.MIN_LINE_CONDITIONING` (``c``), the
    measure and the bound the geometry check applies at the neutral pose
    (:func:`~motionbase.platform.conditioning.line_conditioning`). Near 0 the platform is at a
    singularity (yawed 90 deg, say): the legs cannot resist some motion of it.

    On ``A = M^T M`` (eigenvalues the squared singular values): ``lambda_min >= c^2
    lambda_max``. Fast path: ``A - c^2 trace(A) I`` positive definite (a Cholesky
    factorisation), since ``trace(A) >= lambda_max``; else the least and largest eigenvalues
    (``np.linalg.eigvalsh``)."""
    M = np.empty((6, 6))
    for i in range(6):
        ux = (J[i, 0] - G[i, BX]) / L[i]
        uy = (J[i, 1] - G[i, BY]) / L[i]
        uz = (J[i, 2] - G[i, BZ]) / L[i]
        rx = J[i, 0] - G[i, OX] - p[0]  # R q_i: the joint from the platform centre
        ry = J[i, 1] - G[i, OY] - p[1]
        rz = J[i, 2] - G[i, OZ] - p[2]
        M[i, 0], M[i, 1], M[i, 2] = ux, uy, uz
        M[i, 3] = (ry * uz - rz * uy) / G[i, SCALE]
        M[i, 4] = (rz * ux - rx * uz) / G[i, SCALE]
        M[i, 5] = (rx * uy - ry * ux) / G[i, SCALE]
    A = np.empty((6, 6))
    trace = 0.0
    for a in range(6):
        for b in range(a, 6):
            v = 0.0
            for i in range(6):
                v += M[i, a] * M[i, b]
            A[a, b] = v
            A[b, a] = v
        trace += A[a, a]
    c2 = MIN_LINE_CONDITIONING * MIN_LINE_CONDITIONING
    # Cholesky of A - c^2 trace I (in M's storage): every pivot > 0 -> positive definite
    definite = True
    for j in range(6):
        d = A[j, j] - c2 * trace
        for k in range(j):
            d -= M[j, k] * M[j, k]
        if not d > 0.0:
            definite = False
            break
        M[j, j] = math.sqrt(d)
        for i in range(j + 1, 6):
            v = A[i, j]
            for k in range(j):
                v -= M[i, k] * M[j, k]
            M[i, j] = v / M[j, j]
    if definite:
        return True
    w = np.linalg.eigvalsh(A)  # (ascending; LAPACK's, through numba)
    return w[0] >= c2 * w[5]


@njit(cache=True, nogil=True, error_model="numpy")
def _ok(p, G, R, J, L):
    """Reachable: every length within its limits, every platform joint above its base joint
    (FRD: smaller z), the platform upright (its normal points up, ``R[2, 2] > 0``) and the
    legs holding it (:func:`_holds`: not at or near a singularity).

    The second and third exclude the mirror solutions of the length equations (the platform
    below the base, or upside down) that no real hexapod reaches. False for NaN.
    """
    _lengths(p, G, R, J, L)
    if not R[2, 2] > 0.0:
        return False
    for i in range(6):
        if not (G[i, LO] <= L[i] <= G[i, HI]):
            return False
        if not J[i, 2] < G[i, BZ]:
            return False
    return _holds(p, G, J, L)


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
def forward_batch(lengths, guesses, G, tol, max_iter, out, iters):
    """Forward kinematics from actuator lengths (k, 6): the shared damped Newton
    (:func:`._pose_kernels.close_legs_batch`: its convergence rule, NaN rows for a failure
    or a non-finite or non-positive length, ``iters``) from the base joints."""
    n = lengths.shape[0]
    base = np.empty((n, 6, 3))
    for k in range(n):
        for i in range(6):
            base[k, i, 0] = G[i, BX]
            base[k, i, 1] = G[i, BY]
            base[k, i, 2] = G[i, BZ]
    close_legs_batch(
        base, lengths, G[:, QX : QZ + 1], G[:, OX : OZ + 1], guesses, tol, max_iter, out, iters
    )


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
