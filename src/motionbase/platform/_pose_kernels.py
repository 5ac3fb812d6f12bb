"""Pose maths shared by the 6-DOF platforms' kernels and classes (6-RUS, 6-UPS Stewart).

Compiled (numba) pieces: the Z-Y-X rotation :func:`rotation` (from
:func:`motionbase.physics.rotation_terms`, its nine entries as scalars, which kernels that
keep them in registers call directly), the angle wrap
:func:`wrap`, the 6x6 linear solver :func:`solve6` and the forward kinematics of a
platform on six legs, :func:`close_legs_batch` (damped Newton). Python pieces: the argument checks
and batch plumbing every 6-DOF kinematics class uses (:func:`as_poses`, :func:`run_inverse`,
:func:`run_reachable`, :func:`run_clamp`, :func:`run_forward`). The numpy rotation matrix
is :func:`motionbase.physics.rotation_matrix`.

Conventions (DESIGN.md): a pose is ``[x, y, z, roll, pitch, yaw]`` (m, rad; FRD base axes)
and ``R = Rz(yaw) Ry(pitch) Rx(roll)`` maps platform-frame vectors to base axes.

numba's on-disk cache keys a kernel on its own file only: after changing a kernel here,
delete the callers' caches (``__pycache__/_rus6_kernels*.nb[ic]``,
``__pycache__/_stewart6_kernels*.nb[ic]``) or they keep the old code compiled in.
No fastmath: NaN must propagate and comparisons with NaN must stay false.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from motionbase.errors import ConfigError
from motionbase.physics import rotation_terms

__all__ = [
    "as_poses",
    "close_legs_batch",
    "leg_closure",
    "rotation",
    "run_clamp",
    "run_forward",
    "run_inverse",
    "run_reachable",
    "solve6",
    "wrap",
]


# --------------------------------------------------------------------------- compiled


@njit(cache=True, nogil=True, error_model="numpy")
def rotation(roll, pitch, yaw, R):
    """R = Rz(yaw) Ry(pitch) Rx(roll) into the 3x3 array R."""
    t = rotation_terms(roll, pitch, yaw)
    R[0, 0], R[0, 1], R[0, 2] = t[0], t[1], t[2]
    R[1, 0], R[1, 1], R[1, 2] = t[3], t[4], t[5]
    R[2, 0], R[2, 1], R[2, 2] = t[6], t[7], t[8]


@njit(cache=True, nogil=True, error_model="numpy")
def wrap(a):
    """Wrap an angle to [-pi, pi); angles already in range are returned bit for bit."""
    if -math.pi <= a < math.pi:
        return a
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True, nogil=True, error_model="numpy")
def solve6(A, b, x):
    """Solve A x = b (6x6) by Gaussian elimination with partial pivoting; False if singular.

    Overwrites A and b.
    """
    n = 6
    for c in range(n):
        piv = c
        best = abs(A[c, c])
        for r in range(c + 1, n):
            if abs(A[r, c]) > best:
                best = abs(A[r, c])
                piv = r
        if not best > 1e-300:
            return False
        if piv != c:
            for j in range(n):
                A[c, j], A[piv, j] = A[piv, j], A[c, j]
            b[c], b[piv] = b[piv], b[c]
        for r in range(c + 1, n):
            f = A[r, c] / A[c, c]
            if f != 0.0:
                for j in range(c, n):
                    A[r, j] -= f * A[c, j]
                b[r] -= f * b[c]
    for r in range(n - 1, -1, -1):
        s = b[r]
        for j in range(r + 1, n):
            s -= A[r, j] * x[j]
        x[r] = s / A[r, r]
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def leg_closure(x, base, length, local, origin, R, jac, res, omega=False):
    """Leg-closure equations ``g_i = |O_i + p + R q_i - b_i|^2 - l_i^2`` (m^2) of pose ``x``
    into ``res`` (6,), their analytic Jacobian into ``jac`` (6, 6), the worst length error.

    ``jac[i, :3] = 2 e_i`` (so ``e_i`` is ``jac[i, :3] / 2``, exactly) and
    ``jac[i, 3 + k] = 2 ((R q_i) x e_i) . a_k`` with ``e_i = O_i + p + R q_i - b_i`` and
    ``a_k`` the angular velocity (base axes) per unit rate of Euler angle k: roll ->
    Rz Ry e_x, pitch -> Rz e_y, yaw -> e_z; with ``omega``, per unit angular velocity in
    base axes (``a_k = e_k``). Returns the worst length error, m (``|g_i| / (2 l_i)``, to
    first order ``| |e_i| - l_i |``; a NaN is the worst).
    """
    rotation(x[3], x[4], x[5], R)
    cp, sp = math.cos(x[4]), math.sin(x[4])
    cy, sy = math.cos(x[5]), math.sin(x[5])
    a0x, a0y, a0z = cy * cp, sy * cp, -sp
    a1x, a1y, a1z = -sy, cy, 0.0
    worst = 0.0
    for i in range(6):
        qx, qy, qz = local[i, 0], local[i, 1], local[i, 2]
        rqx = R[0, 0] * qx + R[0, 1] * qy + R[0, 2] * qz
        rqy = R[1, 0] * qx + R[1, 1] * qy + R[1, 2] * qz
        rqz = R[2, 0] * qx + R[2, 1] * qy + R[2, 2] * qz
        ex = origin[i, 0] + x[0] + rqx - base[i, 0]
        ey = origin[i, 1] + x[1] + rqy - base[i, 1]
        ez = origin[i, 2] + x[2] + rqz - base[i, 2]
        res[i] = ex * ex + ey * ey + ez * ez - length[i] * length[i]
        jac[i, 0] = 2.0 * ex
        jac[i, 1] = 2.0 * ey
        jac[i, 2] = 2.0 * ez
        # d(Rq)/d(angle_k) = a_k x Rq; dg = 2 e . (a_k x Rq) = 2 (Rq x e) . a_k
        cx_ = rqy * ez - rqz * ey
        cy_ = rqz * ex - rqx * ez
        cz_ = rqx * ey - rqy * ex
        if omega:
            jac[i, 3] = 2.0 * cx_
            jac[i, 4] = 2.0 * cy_
        else:
            jac[i, 3] = 2.0 * (cx_ * a0x + cy_ * a0y + cz_ * a0z)
            jac[i, 4] = 2.0 * (cx_ * a1x + cy_ * a1y + cz_ * a1z)
        jac[i, 5] = 2.0 * cz_
        err = abs(res[i]) / (2.0 * length[i])
        if not err <= worst:  # NaN becomes the worst
            worst = err
    return worst


@njit(cache=True, nogil=True, error_model="numpy")
def close_legs_batch(base, length, local, origin, guesses, tol, max_iter, out, iters):
    """Forward kinematics of a platform held by six legs of known length: damped Newton.

    Row ``k`` is the pose ``x = [x, y, z, roll, pitch, yaw]`` (m, rad) that puts each
    platform joint ``O_i + p + R q_i`` at the distance ``length[k, i]`` (m) from the
    base-side point ``base[k, i]`` (m, base axes), found from ``guesses[k]``. The robots
    differ only in those two: the 6-RUS's base-side points are its crank tips and its
    lengths the rods; the Stewart platform's are its base joints and actuator lengths.

    Parameters
    ----------
    base : ndarray, shape (k, 6, 3)
    length : ndarray, shape (k, 6)
    local : ndarray, shape (6, 3)
        Platform joints ``q_i`` in platform axes, m.
    origin : ndarray, shape (6, 3)
        The platform frame's origin ``O_i`` (base axes, m) of each leg's joint at the zero pose.
    guesses : ndarray, shape (k, 6)
    tol : float
        Converged when the Newton step is below ``tol`` (m, rad) and every length error
        is below ``tol`` (m).
    max_iter : int
    out : ndarray, shape (k, 6)
        The poses; NaN rows where Newton did not converge or an input was not finite (or a
        length not positive).
    iters : ndarray of int64, shape (k,)
        Iterations per row; -1 for a failure.
    """
    R = np.empty((3, 3))
    jac = np.empty((6, 6))
    res = np.empty(6)
    rhs = np.empty(6)
    dx = np.empty(6)
    x = np.empty(6)
    trial = np.empty(6)
    for k in range(guesses.shape[0]):
        b, ln = base[k], length[k]
        ok = True
        for j in range(6):
            x[j] = guesses[k, j]
            finite = math.isfinite(b[j, 0]) and math.isfinite(b[j, 1]) and math.isfinite(b[j, 2])
            if not (finite and math.isfinite(ln[j]) and ln[j] > 0.0 and math.isfinite(x[j])):
                ok = False
        converged = False
        n = 0
        if ok:
            err = leg_closure(x, b, ln, local, origin, R, jac, res)
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
                    new_err = leg_closure(trial, b, ln, local, origin, R, jac, res)
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


# --------------------------------------------------------------------------- batch plumbing


def as_poses(pose: ArrayLike, what: str = "pose") -> tuple[np.ndarray, tuple[int, ...]]:
    """Rows ``(k, 6)`` (C-contiguous float64) of one pose or a batch, and the leading shape.

    Raises
    ------
    ConfigError
        The last axis is not 6 long.
    """
    p = np.asarray(pose, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] != 6:
        raise ConfigError(
            f"{what}: expected shape (6,) or (..., 6) "
            f"[x, y, z, roll, pitch, yaw], got shape {p.shape}"
        )
    return kernel_rows(p, 6), p.shape[:-1]


def kernel_rows(p: np.ndarray, width: int) -> np.ndarray:
    """``p`` (float64) as rows ``(k, width)`` of the one array type the robots' kernels are
    compiled for: C-contiguous and writable (a read-only array, ``robot.neutral_pose`` say,
    would have numba load a second version of the kernel, mid-run)."""
    flat = np.ascontiguousarray(p.reshape(-1, width))
    return flat if flat.flags.writeable else flat.copy()


def run_inverse(kernel: Callable, G: np.ndarray, pose: ArrayLike) -> np.ndarray:
    """``kernel(poses (k, 6), G, out (k, 6))`` over one pose or a batch: shape (..., 6)."""
    p = np.asarray(pose, dtype=np.float64)
    if p.shape == (6,):
        out = np.empty(6)
        kernel(as_poses(p)[0], G, out.reshape(1, 6))
        return out
    flat, lead = as_poses(p)
    out = np.empty_like(flat)
    kernel(flat, G, out)
    return out.reshape(lead + (6,))


def run_reachable(kernel: Callable, G: np.ndarray, pose: ArrayLike) -> np.ndarray | bool:
    """``kernel(poses, G, out bool (k,))``: a bool for one pose, a bool array (...) else."""
    flat, lead = as_poses(pose)
    out = np.empty(flat.shape[0], dtype=np.bool_)
    kernel(flat, G, out)
    if lead == ():
        return bool(out[0])
    return out.reshape(lead)


def run_clamp(
    kernel: Callable, G: np.ndarray, pose: ArrayLike
) -> tuple[np.ndarray, np.ndarray | bool]:
    """``kernel(poses, G, out (k, 6), flags (k,))``: clamped poses and whether each moved."""
    p = np.asarray(pose, dtype=np.float64)
    if p.shape == (6,):
        out = np.empty(6)
        flags = np.empty(1, dtype=np.bool_)
        kernel(as_poses(p)[0], G, out.reshape(1, 6), flags)
        return out, bool(flags[0])
    flat, lead = as_poses(p)
    out = np.empty_like(flat)
    flags = np.empty(flat.shape[0], dtype=np.bool_)
    kernel(flat, G, out, flags)
    return out.reshape(lead + (6,)), flags.reshape(lead)


def run_forward(
    kernel: Callable,
    G: np.ndarray,
    q: ArrayLike,
    guess: ArrayLike | None,
    tol: float,
    max_iter: int,
    what: str,
) -> np.ndarray:
    """``kernel(q (k, 6), guesses (k, 6), G, tol, max_iter, out, iters)`` over actuator rows
    ``q`` named ``what``, from ``guess`` (broadcast; zero pose by default): shape (..., 6)."""
    if (
        type(q) is np.ndarray
        and type(guess) is np.ndarray
        and q.shape == guess.shape == (6,)
        and q.dtype == guess.dtype == np.float64
    ):  # one pose from one guess, as a rate-limited tick asks: no broadcasting
        out, iters = np.empty((1, 6)), np.empty(1, dtype=np.int64)
        kernel(q.reshape(1, 6), guess.reshape(1, 6), G, float(tol), int(max_iter), out, iters)
        return out[0]
    flat, lead = as_poses(q, what)
    if guess is None:
        g = np.zeros_like(flat)
    else:
        gp = np.asarray(guess, dtype=np.float64)
        if gp.ndim == 0 or gp.shape[-1] != 6:
            raise ConfigError(f"guess: expected shape (6,) or (..., 6), got {gp.shape}")
        try:
            g = np.ascontiguousarray(np.broadcast_to(gp, lead + (6,)).reshape(-1, 6))
        except ValueError:
            raise ConfigError(
                f"guess: shape {gp.shape} does not broadcast to {what}' {lead + (6,)}"
            ) from None
    out = np.empty_like(flat)
    iters = np.empty(flat.shape[0], dtype=np.int64)
    kernel(flat, g, G, float(tol), int(max_iter), out, iters)
    return out.reshape(lead + (6,))
