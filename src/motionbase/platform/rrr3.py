"""Kinematics of the planar 3-RRR parallel robot (thesis chapters 4, 5 and 7).

Frames and conventions
----------------------
Base frame (planar, metres): motor 1 at the origin ``A1 = (0, 0)``, motor 2 at ``A2 = (L, 0)``,
motor 3 at ``A3 = (L/2, L*sqrt(3)/2)``. A pose is ``[x, y, phi]``: the position of the platform
centroid ``P`` in the base frame (m) and the platform's orientation ``phi`` (rad,
counter-clockwise). The platform joints are, as in the thesis (appendix A.1),
``C1 = P - (h/sqrt(3)) (cos(pi/6 + phi), sin(pi/6 + phi))``, ``C2 = C1 + h (cos phi, sin phi)``,
``C3 = C1 + h (cos(phi + pi/3), sin(phi + pi/3))``. The joint angle ``theta_i`` (rad) is the
absolute angle of the crank ``A_i B_i`` from the base +x axis, counter-clockwise, in (-pi, pi].

Inverse kinematics is the tangent half-angle (Weierstrass) closed form (eqs. 4.18-4.29): with
``(xc, yc) = C_i - A_i``, ``e1 = -2 a yc``, ``e2 = -2 a xc``, ``e3 = xc^2 + yc^2 + a^2 - b^2``,
the loop closure ``e1 sin(theta) + e2 cos(theta) + e3 = 0`` becomes, with ``t = tan(theta/2)``,
``(e3 - e2) t^2 + 2 e1 t + (e3 + e2) = 0``, so
``t = (-e1 + m sqrt(e1^2 + e2^2 - e3^2)) / (e3 - e2)``, where ``m = +-1`` is the chain's
working mode. The ``+`` root is ``theta = atan2(yc, xc) + delta``
and the ``-`` root ``atan2(yc, xc) - delta`` with ``delta`` the crank-to-``A_iC_i`` angle, so a
mode is one elbow side for the whole annulus the chain can reach.

Jacobians (eqs. 5.10-5.11, derived again here, signs included): with the crank ``u_i = B_i - A_i``,
the rod ``n_i = C_i - B_i`` and ``e_i = C_i - P``, differentiating ``|n_i|^2 = b^2`` gives
``Jx xdot = Jq qdot`` with ``Jx`` rows ``[n_ix, n_iy, e_ix n_iy - e_iy n_ix]`` and
``Jq = diag(u_ix n_iy - u_iy n_ix)``; ``qdot = Jq^-1 Jx xdot``. Type I (inverse) singularity:
a diagonal entry of ``Jq`` vanishes (chain straight or folded), monitored as in the thesis by
``|a_ix b_iy - a_iy b_ix|``, here normalised by ``a b``. Type II (direct) singularity:
``det(Jx) = 0``, normalised by ``b^3 h / sqrt(3)``. Poses within the margins are refused like
unreachable ones.

Servo mapping (per motor ``i``): ``servo_deg = round((direction_i (theta_deg - zero_deg_i)) mod
360)`` must lie in ``[min_deg_i, max_deg_i]`` (0..180 for the Futaba S3003); outside, the pose
is refused, never wrapped or clipped. Rounding is half-up (``floor(x + 0.5)``).

The hot path (validity check, inverse kinematics, servo mapping, clamping) is one compiled
kernel (numba, ``_rrr3_kernels``) used for single poses and for batches alike; Jacobians, joint
points and the forward kinematics are plain numpy. The geometry and its TOML files are in
:mod:`motionbase.platform.rrr3_geometry`, the workspace sweep in
:mod:`motionbase.platform.rrr3_workspace`.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numba
import numpy as np

from motionbase.errors import ConfigError, MotionbaseError
from motionbase.platform import _rrr3_kernels as _k
from motionbase.platform import rrr3_workspace as _ws
from motionbase.platform._pose_kernels import kernel_rows
from motionbase.platform._rrr3_kernels import OK, SERVO_RANGE, TYPE1, TYPE2, UNREACHABLE
from motionbase.platform.robot import Robot
from motionbase.platform.rrr3_geometry import Rrr3Geometry
from motionbase.safety import ActuatorLimits

__all__ = [
    "Rrr3Robot",
    "Rrr3",
    "JointPoints",
    "Singularity",
    "UnreachablePoseError",
    "OK",
    "UNREACHABLE",
    "TYPE1",
    "TYPE2",
    "SERVO_RANGE",
    "describe_status",
]

_SQRT3 = math.sqrt(3.0)


def describe_status(status: int) -> str:
    """Human-readable list of the reasons encoded in a status word."""
    if status == OK:
        return "valid"
    names = []
    if status & UNREACHABLE:
        names.append("unreachable")
    if status & TYPE1:
        names.append("near a type I (inverse) singularity")
    if status & TYPE2:
        names.append("near a type II (direct) singularity")
    if status & SERVO_RANGE:
        names.append("servo degrees out of range")
    return ", ".join(names)


class UnreachablePoseError(MotionbaseError, ValueError):
    """A pose or joint angle the robot cannot take (unreachable, singular, out of servo range)."""


# --------------------------------------------------------------------------------------------
# The robot
# --------------------------------------------------------------------------------------------


class JointPoints(NamedTuple):
    """Joint positions of the three chains, each of shape (..., 3, 2), m (NaN if unreachable).

    ``A``: motor axes; ``B``: crank tips (crank-rod joints); ``C``: platform joints.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray


class Singularity(NamedTuple):
    """Singularity measures of poses.

    Attributes
    ----------
    type1 : ndarray (..., 3)
        ``|a_ix b_iy - a_iy b_ix| / (a b)`` per chain: the sine of the crank-rod angle (0 at a
        type I singularity: chain straight or folded).
    type2 : ndarray (...)
        ``|det(Jx)| / (b^3 h / sqrt(3))`` (0 at a type II singularity).
    type1_raw : ndarray (..., 3)
        The thesis's monitor ``|a_ix b_iy - a_iy b_ix|``, m^2.
    det_jx : ndarray (...)
        ``det(Jx)``, signed, m^4.
    """

    type1: np.ndarray
    type2: np.ndarray
    type1_raw: np.ndarray
    det_jx: np.ndarray


def _as_poses(pose: Any, what: str = "pose") -> tuple[np.ndarray, tuple[int, ...]]:
    arr = np.asarray(pose, dtype=float)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ConfigError(
            f"{what}: expected [x, y, phi] or an array of shape (..., 3), got shape {arr.shape}"
        )
    return kernel_rows(arr, 3), arr.shape[:-1]


class Rrr3:
    """Kinematics of a planar 3-RRR robot (see the module docstring for the conventions).

    Parameters
    ----------
    geometry : Rrr3Geometry, optional
        The robot; the thesis's ``udesc`` preset by default.

    Raises
    ------
    ConfigError
        If the home pose is not valid for this geometry (unreachable, singular or out of the
        servo ranges): clamping needs a valid home.
    """

    def __init__(self, geometry: Rrr3Geometry | None = None) -> None:
        self.geometry = geometry if geometry is not None else Rrr3Geometry.preset("udesc")
        self._p = self.geometry.packed()
        self._A = self.geometry.base_points
        self._c = self.geometry.platform_points
        self.home = self.geometry.home
        self._tbuf = np.empty(3)
        self._sbuf = np.empty(3, dtype=np.int64)
        st = self.status(self.home)
        if st != OK:
            raise ConfigError(
                f"rrr3 geometry {self.geometry.name!r}: home pose {self.home.tolist()} is "
                f"{describe_status(int(st))} (fix the lengths, modes, servo mapping or margins)"
            )

    # -- inverse kinematics -----------------------------------------------------------------
    def solve(self, pose: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inverse kinematics, servo degrees and status in one pass.

        Parameters
        ----------
        pose : array_like (..., 3)
            ``[x, y, phi]``, m and rad, base frame.

        Returns
        -------
        theta : ndarray (..., 3)
            Joint angles, rad (NaN for an unreachable chain).
        servo_deg : ndarray (..., 3) int64
            Servo degrees as the mapping gives them (-1 for an unreachable chain; may lie
            outside the servo range: check ``status``).
        status : ndarray (...) int64
            Status word, 0 when valid (bits UNREACHABLE, TYPE1, TYPE2, SERVO_RANGE).
        """
        flat, batch = _as_poses(pose)
        theta, servo, status = _k.solve_batch(flat, self._p)
        return theta.reshape(batch + (3,)), servo.reshape(batch + (3,)), status.reshape(batch)

    def inverse(self, pose: Any) -> np.ndarray:
        """Joint angles (rad, (..., 3)) of poses ``[x, y, phi]``; NaN where unreachable.

        Only the existence of a real solution is required here; use :meth:`status` or
        :meth:`reachable` to also refuse singular or servo-invalid poses.
        """
        return self.solve(pose)[0]

    def status(self, pose: Any) -> np.ndarray:
        """Status word of poses (..., 3): 0 when valid, else OR of the reason bits."""
        return self.solve(pose)[2]

    def reachable(self, pose: Any) -> np.ndarray:
        """True where the pose is reachable, outside both singularity margins, servo-valid."""
        return self.status(pose) == OK

    # -- servo mapping ------------------------------------------------------------------------
    @property
    def angle_limits(self) -> np.ndarray:
        """Joint-angle interval per motor allowed by the servo ranges, (3, 2) rad, base frame.

        Row ``i`` is ``(lo, hi)`` with ``lo <= hi``; the interval may extend beyond
        (-pi, pi] (compare angles modulo 2 pi).
        """
        g = self.geometry
        out = np.empty((3, 2))
        for i in range(3):
            ends = g.servo_zero_deg[i] + g.servo_direction[i] * np.array(
                [g.servo_min_deg[i], g.servo_max_deg[i]], dtype=float
            )
            out[i] = np.radians(np.sort(ends))
        return out

    def to_servo_masked(self, angles: Any) -> tuple[np.ndarray, np.ndarray]:
        """Servo degrees of joint angles, with a validity mask instead of an error.

        Parameters
        ----------
        angles : array_like (..., 3)
            Joint angles, rad, base frame.

        Returns
        -------
        servo_deg : ndarray (..., 3) int64
            Integer degrees; -1 where the angle is NaN or its degrees fall outside the range.
        ok : ndarray (..., 3) bool
        """
        g = self.geometry
        th = np.asarray(angles, dtype=float)
        if th.ndim == 0 or th.shape[-1] != 3:
            raise ConfigError(f"angles: expected shape (..., 3), got {th.shape}")
        with np.errstate(invalid="ignore"):
            sd = np.mod(np.asarray(g.servo_direction) * (np.degrees(th) - g.servo_zero_deg), 360.0)
            r = np.floor(sd + 0.5)
            r = np.where(r >= 360.0, r - 360.0, r)
            ok = np.isfinite(r) & (r >= g.servo_min_deg) & (r <= g.servo_max_deg)
        deg = np.where(ok, np.nan_to_num(r, nan=-1.0), -1.0).astype(np.int64)
        return deg, ok

    def to_servo(self, angles: Any) -> np.ndarray:
        """Integer servo degrees (..., 3) of joint angles (rad); refuses rather than clips.

        Raises
        ------
        UnreachablePoseError
            If any angle is NaN or maps outside its servo's ``[min_deg, max_deg]``; the message
            names the first offending motor. Use :meth:`to_servo_masked` for a mask instead.
        """
        deg, ok = self.to_servo_masked(angles)
        if not ok.all():
            th = np.asarray(angles, dtype=float).reshape(-1, 3)
            bad = np.argwhere(~ok.reshape(-1, 3))[0]
            k, i = int(bad[0]), int(bad[1])
            g = self.geometry
            raise UnreachablePoseError(
                f"servo {i + 1}: joint angle {math.degrees(th[k, i]):.2f} deg maps outside "
                f"{g.servo_min_deg[i]}..{g.servo_max_deg[i]} servo degrees (refused, not clipped)"
            )
        return deg

    # -- clamping -----------------------------------------------------------------------------
    def clamp(self, pose: Any, *, n_samples: int = 32, n_bisect: int = 20):
        """Move targets toward home along the straight segment until they are valid.

        Parameters
        ----------
        pose : array_like (..., 3)
            Targets ``[x, y, phi]``, m and rad.
        n_samples, n_bisect : int
            The segment from home to the target is sampled at ``n_samples`` points; the first
            invalid interval is refined by ``n_bisect`` bisection steps. The result is the
            farthest point such that every sample from home to it is valid, so the clamped
            pose never jumps across an unreachable or singular region.

        Returns
        -------
        pose : ndarray (..., 3)
            The valid pose (the target itself when it was valid; home for a non-finite target).
        clamped : ndarray (...) bool
            True where the target was moved.
        """
        flat, batch = _as_poses(pose)
        out, clamped, _ = _k.clamp_batch(flat, self.home, self._p, int(n_samples), int(n_bisect))
        return out.reshape(batch + (3,)), clamped.reshape(batch)

    def clamp_one(self, x: float, y: float, phi: float) -> tuple[float, float, float, bool]:
        """Scalar fast path of :meth:`clamp` (no array allocation): ``(x, y, phi, clamped)``."""
        cx, cy, cp, cl, _ = _k.clamp_one(
            x,
            y,
            phi,
            self.home[0],
            self.home[1],
            self.home[2],
            self._p,
            32,
            20,
            self._tbuf,
            self._sbuf,
        )
        return cx, cy, cp, cl

    def solve_one(self, x: float, y: float, phi: float) -> tuple[int, np.ndarray, np.ndarray]:
        """Scalar fast path of :meth:`solve`: ``(status, theta (3,), servo_deg (3,))``.

        The arrays returned are fresh copies.
        """
        theta = np.empty(3)
        servo = np.empty(3, dtype=np.int64)
        st = _k.solve_one(float(x), float(y), float(phi), self._p, theta, servo)
        return int(st), theta, servo

    # -- geometry of a pose -------------------------------------------------------------------
    def platform_joints(self, pose: Any) -> np.ndarray:
        """Platform joints ``C_i`` of poses, (..., 3, 2), m."""
        P = np.asarray(pose, dtype=float)
        c, s = np.cos(P[..., 2]), np.sin(P[..., 2])
        lx, ly = self._c[:, 0], self._c[:, 1]
        cx = P[..., 0, None] + c[..., None] * lx - s[..., None] * ly
        cy = P[..., 1, None] + s[..., None] * lx + c[..., None] * ly
        return np.stack([cx, cy], axis=-1)

    def joint_points(self, pose: Any, angles: Any | None = None) -> JointPoints:
        """A, B, C of every chain for poses (..., 3); each (..., 3, 2), m.

        ``angles`` (..., 3) rad may be given to skip the inverse kinematics; otherwise the
        working modes of the geometry choose them. Unreachable chains give NaN in ``B``.
        """
        P = np.asarray(pose, dtype=float)
        _as_poses(P)
        th = self.inverse(P) if angles is None else np.asarray(angles, dtype=float)
        C = self.platform_joints(P)
        A = np.broadcast_to(self._A, C.shape).copy()
        a = self.geometry.crank
        B = A + a * np.stack([np.cos(th), np.sin(th)], axis=-1)
        return JointPoints(A, B, C)

    def jacobians(self, pose: Any, angles: Any | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Jx and Jq (each (..., 3, 3)) of eqs. 5.10-5.11: ``Jx xdot = Jq qdot``.

        Rows of Jx: ``[n_ix, n_iy, e_ix n_iy - e_iy n_ix]`` (m, m, m^2), Jq diagonal
        ``u_ix n_iy - u_iy n_ix`` (m^2), with crank ``u_i = B_i - A_i``, rod ``n_i = C_i - B_i``
        and ``e_i = C_i - P``. The inverse-kinematics Jacobian is ``Jq^-1 Jx``.
        """
        P = np.asarray(pose, dtype=float)
        A, B, C = self.joint_points(P, angles)
        u = B - A
        n = C - B
        e = C - P[..., None, :2]
        Jx = np.stack([n[..., 0], n[..., 1], e[..., 0] * n[..., 1] - e[..., 1] * n[..., 0]], -1)
        jq = u[..., 0] * n[..., 1] - u[..., 1] * n[..., 0]
        Jq = jq[..., :, None] * np.eye(3)
        return Jx, Jq

    def singularity(self, pose: Any) -> Singularity:
        """Type I and type II singularity measures of poses (..., 3); see :class:`Singularity`."""
        Jx, Jq = self.jacobians(pose)
        g = self.geometry
        raw = np.abs(np.diagonal(Jq, axis1=-2, axis2=-1))
        with np.errstate(invalid="ignore"):
            det = np.linalg.det(Jx)
        scale2 = g.rod**3 * g.platform_side / _SQRT3
        return Singularity(raw / (g.crank * g.rod), np.abs(det) / scale2, raw, det)

    # -- forward kinematics -------------------------------------------------------------------
    def forward(
        self, angles: Any, guess: Any | None = None, *, tol: float = 1e-16, max_iter: int = 50
    ) -> np.ndarray:
        """Pose (..., 3) from joint angles (..., 3) rad, by Newton's method.

        Parameters
        ----------
        angles : array_like (..., 3)
            Joint angles, rad.
        guess : array_like (..., 3), optional
            Starting pose (home by default); Newton converges to the assembly mode nearest it.
        tol : float
            Convergence on the constraint residual ``max_i | |C_i - B_i|^2 - b^2 |``, m^2.

        Returns
        -------
        ndarray (..., 3)
            The pose; NaN where Newton did not converge (no assembly, or a singular path).
        """
        th = np.asarray(angles, dtype=float)
        if th.ndim == 0 or th.shape[-1] != 3:
            raise ConfigError(f"angles: expected shape (..., 3), got {th.shape}")
        x = np.broadcast_to(self.home if guess is None else np.asarray(guess, float), th.shape)
        x = x.astype(float).copy()
        a, b = self.geometry.crank, self.geometry.rod
        B = self._A + a * np.stack([np.cos(th), np.sin(th)], axis=-1)
        done = np.zeros(th.shape[:-1], dtype=bool)
        for _ in range(max_iter):
            C = self.platform_joints(x)
            n = C - B
            e = C - x[..., None, :2]
            F = np.einsum("...ij,...ij->...i", n, n) - b * b
            done = np.all(np.abs(F) < tol, axis=-1)
            if done.all():
                break
            Jx = np.stack([n[..., 0], n[..., 1], e[..., 0] * n[..., 1] - e[..., 1] * n[..., 0]], -1)
            with np.errstate(all="ignore"):
                det = np.linalg.det(Jx)
                ok = np.abs(det) > 1e-30
                Jsafe = np.where(ok[..., None, None], Jx, np.eye(3))
                dx = np.linalg.solve(2.0 * Jsafe, F[..., None])[..., 0]
            dx = np.where(ok[..., None], dx, 0.0)
            x = np.where(done[..., None], x, x - dx)
        else:
            C = self.platform_joints(x)
            n = C - B
            F = np.einsum("...ij,...ij->...i", n, n) - b * b
            done = np.all(np.abs(F) < tol, axis=-1)
        x[..., 2] = (x[..., 2] + np.pi) % (2 * np.pi) - np.pi
        return np.where(done[..., None] & np.isfinite(x), x, np.nan)

    def forward_all(self, angles: Any, *, n_phi: int = 1440) -> np.ndarray:
        """All real assembly modes for one set of joint angles (3,) rad: poses (k, 3).

        Method: for each of ``n_phi`` orientations, ``C1`` lies on the circle about ``B1`` and
        on the circle about ``B2 - R(phi)(c2 - c1)`` (both radius b): two candidates; the
        residual of chain 3 is tracked along each branch, its sign changes are refined by
        Newton on the full system and duplicates removed. Roots where the residual only
        touches zero (double roots) can be missed; ``n_phi`` bounds the angular resolution.
        """
        th = np.asarray(angles, dtype=float)
        if th.shape != (3,):
            raise ConfigError(f"angles: expected shape (3,), got {th.shape}")
        a, b = self.geometry.crank, self.geometry.rod
        B = self._A + a * np.stack([np.cos(th), np.sin(th)], axis=-1)
        phis = np.linspace(-np.pi, np.pi, n_phi, endpoint=False)
        c, s = np.cos(phis), np.sin(phis)

        def rot(v: np.ndarray) -> np.ndarray:
            return np.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]], axis=-1)

        d21 = rot(self._c[1] - self._c[0])  # (n, 2)
        d31 = rot(self._c[2] - self._c[0])
        O2 = B[1] - d21  # C1 must be at distance b from O2
        D = O2 - B[0]
        dist = np.hypot(D[:, 0], D[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            along = dist / 2  # equal radii: the chord's midpoint
            half = np.sqrt(b * b - along**2)
            ux, uy = D[:, 0] / dist, D[:, 1] / dist
        found = []
        for sign in (1.0, -1.0):
            C1 = np.stack(
                [B[0, 0] + along * ux - sign * half * uy, B[0, 1] + along * uy + sign * half * ux],
                axis=-1,
            )
            C3 = C1 + d31
            g = np.sum((C3 - B[2]) ** 2, axis=-1) - b * b
            P = C1 - rot(self._c[0])
            nxt = np.roll(np.arange(n_phi), -1)
            change = np.isfinite(g) & np.isfinite(g[nxt]) & (np.sign(g) != np.sign(g[nxt]))
            for k in np.flatnonzero(change):
                guess = np.array([P[k, 0], P[k, 1], phis[k]])
                sol = self.forward(th, guess=guess)
                if np.all(np.isfinite(sol)):
                    found.append(sol)
        uniq: list[np.ndarray] = []
        for sol in found:
            if not any(
                np.hypot(*(sol[:2] - u[:2])) < 1e-9
                and abs((sol[2] - u[2] + np.pi) % (2 * np.pi) - np.pi) < 1e-9
                for u in uniq
            ):
                uniq.append(sol)
        return np.array(uniq).reshape(-1, 3)

    # -- workspace ----------------------------------------------------------------------------
    def workspace(
        self,
        nx: int = 100,
        ny: int = 100,
        nphi: int = 73,
        *,
        x_range: tuple[float, float] | None = None,
        y_range: tuple[float, float] | None = None,
        phi_range: tuple[float, float] = (-math.pi, math.pi),
    ) -> _ws.PlanarWorkspace:
        """The thesis's triple sweep over x, y and phi (chapter 7), compiled.

        See :func:`motionbase.platform.rrr3_workspace.workspace_sweep` for the parameters.
        """
        return _ws.workspace_sweep(
            self.geometry, nx, ny, nphi, x_range=x_range, y_range=y_range, phi_range=phi_range
        )

    def inscribed_rectangle(
        self, phi: float = 0.0, *, n: int = 241
    ) -> tuple[float, float, float, float]:
        """Largest axis-aligned rectangle of valid positions at orientation ``phi`` (rad).

        ``(x_min, x_max, y_min, y_max)`` in m; see
        :func:`motionbase.platform.rrr3_workspace.inscribed_rectangle`.
        """
        return _ws.inscribed_rectangle(self.geometry, phi, n=n)


# --------------------------------------------------------------------------------------------
# The robot plug-in
# --------------------------------------------------------------------------------------------

_TWO_PI = 2.0 * math.pi


@numba.njit(
    "boolean(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1])",
    cache=True,
)
def solve(params, target, cue_out, pose_out, q_out):  # pragma: no cover - compiled
    """Robot kernel (:data:`~motionbase.platform.robot.SOLVE_SIGNATURE`): map the cue pose
    to ``[x, y, phi]``, clamp toward home, solve the joint angles.

    ``params``: the geometry's packed kernel parameters (``Rrr3Geometry.packed``), then
    home (3), the mapping's signed scales (x, y, phi) (3) and the servo intervals' lower ends (3).
    """
    k = params.shape[0] - 9
    p = params[:k]
    hx, hy, hphi = params[k], params[k + 1], params[k + 2]
    sx, sy, sphi = params[k + 3], params[k + 4], params[k + 5]
    theta = np.empty(3)
    servo = np.empty(3, dtype=np.int64)
    cx, cy, cp, clamped, _ = _k.clamp_one(
        hx + sx * target[0],
        hy + sy * target[1],
        hphi + sphi * target[5],
        hx,
        hy,
        hphi,
        p,
        32,
        20,
        theta,
        servo,
    )
    pose_out[0] = cx
    pose_out[1] = cy
    pose_out[2] = cp
    for i in range(3):
        lo = params[k + 6 + i]
        q_out[i] = lo + np.mod(theta[i] - lo, _TWO_PI)  # inside the servo's interval
    for i in range(6):
        cue_out[i] = target[i]
    cue_out[0] = (cx - hx) / sx
    cue_out[1] = (cy - hy) / sy
    cue_out[5] = (cp - hphi) / sphi
    return clamped


class Rrr3Robot(Robot):
    """The 3-RRR robot in planar mode.

    Parameters
    ----------
    geometry : Rrr3Geometry
    scale_m : float
        Metres of robot x and -y per metre of cue surge and sway (sway is to the right,
        -y in the thesis's z-up plane).
    yaw_scale : float
        Robot -phi per radian of cue yaw (a right yaw turns the platform clockwise seen
        from above).
    """

    name = "rrr3"
    actuator_unit = "rad"
    solve_kernel = staticmethod(solve)
    coordinated = True

    def __init__(
        self, geometry: Rrr3Geometry, scale_m: float = 0.1, yaw_scale: float = 0.5
    ) -> None:
        self.kin = Rrr3(geometry)
        self.geometry = geometry
        self.n = 3
        lo, hi = np.asarray(self.kin.angle_limits, dtype=float).T
        self.limits = ActuatorLimits.broadcast(3, lo, hi, geometry.max_speed, geometry.max_accel)
        if scale_m == 0 or yaw_scale == 0:
            raise ConfigError("planar mapping: planar_scale_m and planar_yaw_scale must not be 0")
        # the cue's base axes are FRD (z down), the thesis's plane z up (seen from above, y
        # left of x and phi counter-clockwise): y and phi change sign (a half turn about x,
        # as /tf's world -> base), or the robot moves as the aircraft's mirror image
        self.scale = np.array([scale_m, -scale_m, -yaw_scale], dtype=float)
        self.neutral_pose = np.asarray(self.kin.home, dtype=float)
        self.park_pose = self.neutral_pose
        self.park_cue = np.zeros(6)
        self.park_angles = self.inverse(self.park_pose)
        self.kernel_params = np.concatenate(
            [geometry.packed(), self.neutral_pose, self.scale, self.limits.lower]
        )
        if not np.isfinite(self.park_angles).all():
            raise ConfigError(
                "planar geometry: the home pose is not reachable (check the geometry)"
            )
        self._finish()

    def pose_from_cue(self, cue: np.ndarray) -> np.ndarray:
        cue = np.asarray(cue, dtype=float)
        return self.neutral_pose + self.scale * cue[..., [0, 1, 5]]

    def cue_from_pose(self, pose: np.ndarray, cue: np.ndarray) -> np.ndarray:
        out = np.array(cue, dtype=float)
        out[..., [0, 1, 5]] = (np.asarray(pose) - self.neutral_pose) / self.scale
        return out

    def inverse(self, pose: Any) -> np.ndarray:
        # the same angle modulo 2 pi, written inside the servo's interval when it is in it
        angles = np.asarray(self.kin.inverse(pose), dtype=float)
        lo = self.limits.lower
        return lo + np.mod(angles - lo, _TWO_PI)

    def servo(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(self.kin.to_servo(q))

    def default_output(self) -> Any:
        """Servo degrees, as :meth:`servo` commands them: ``direction * (theta - zero_deg)``
        per servo (the ``[servo]`` table; no wrap is needed within the servo's range), not the
        joint angles in the base frame (92, 212, 332 deg at home for servos that all stand at
        90 there). Fractional: the frame format rounds them."""
        from motionbase.platform.output_map import OutputMapping

        g = self.geometry
        direction = np.asarray(g.servo_direction, dtype=float)
        table = {
            "unit": "deg",
            "sign": direction.tolist(),
            "zero_offset_deg": (-direction * np.asarray(g.servo_zero_deg, dtype=float)).tolist(),
        }
        return OutputMapping.from_dict(
            table, angle_min=self.limits.lower, angle_max=self.limits.upper, source="[servo]"
        )
