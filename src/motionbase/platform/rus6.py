"""Kinematics of the 6-RUS rotary platform: inverse, forward, joint points, Jacobian, clamp.

Conventions (DESIGN.md): a pose is ``[x, y, z, roll, pitch, yaw]``, the displacement of the
platform frame (origin at the centroid of the platform joints) from its neutral pose, in FRD
base axes (heave up is negative z), with Z-Y-X Euler angles: ``R = Rz(yaw) Ry(pitch) Rx(roll)``
maps platform-frame vectors to base axes. Crank angles are 0 with the crank horizontal and grow
as the crank tip rises toward the platform. Units: m and rad.

Every method accepts one pose (shape (6,)) or a batch (shape (..., 6)) and returns matching
leading dimensions. The heavy lifting is in compiled numba kernels (``_rus6_kernels``), compiled
on first use and cached on disk; :meth:`Rus6.warm_up` compiles them ahead of time.

Example
-------
>>> from motionbase.platform import Rus6, Rus6Geometry
>>> rus6 = Rus6(Rus6Geometry.preset("ceart"))
>>> angles = rus6.inverse([0.0, 0.0, -0.05, 0.0, 0.05, 0.0])   # 5 cm up, nose up 0.05 rad
>>> safe, clamped = rus6.clamp([1000.0, 0, 0, 0, 0, 0])          # always reachable
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from motionbase.errors import ConfigError
from motionbase.platform import _rus6_kernels as _k
from motionbase.platform._pose_kernels import (
    as_poses,
    run_clamp,
    run_forward,
    run_inverse,
    run_reachable,
)
from motionbase.platform.robot import Robot
from motionbase.platform.rus6_geometry import Rus6Geometry
from motionbase.safety import ActuatorLimits

__all__ = ["Rus6", "Rus6Robot", "JointPoints", "JacobianResult"]


class JointPoints(NamedTuple):
    """Joint positions in base axes (m), each shape (..., 6, 3).

    Attributes
    ----------
    pivots : crank pivots (fixed to the base).
    crank_tips : crank tips (the U joints).
    platform_joints : platform joints (the S joints).
    """

    pivots: np.ndarray
    crank_tips: np.ndarray
    platform_joints: np.ndarray


class JacobianResult(NamedTuple):
    """Velocity relation between pose rates and crank rates, and singularity measures.

    Attributes
    ----------
    matrix : ndarray, shape (..., 6, 6)
        ``J`` with ``theta_dot = J @ pose_rate`` (rad/s); ``J[..., i, j]`` = d(theta_i)/d(rate_j).
        ``pose_rate = [xdot, ydot, zdot, a, b, c]`` in m/s (base axes) and rad/s, where
        ``(a, b, c)`` are the Euler-angle rates (roll, pitch, yaw rates: the time derivative of
        the pose vector) by default, or the angular velocity in base axes with
        ``angular="omega"``. NaN where the pose cannot be closed, inf at an exact leg
        singularity.
    margin : ndarray, shape (...)
        The singularity measure for clamps and logs: ``min(transmission, conditioning)``, in
        [0, 1], 0 at a singularity of either kind. NaN where the pose cannot be closed.
    transmission : ndarray, shape (...)
        Worst leg's transmission index ``|cos|`` of the angle between the rod and the crank
        tip's velocity, in [0, 1]. 0 when a rod is perpendicular to its crank tip's path (crank
        and rod aligned as seen in the crank's plane: the workspace boundary where that leg
        stops closing, and the crank rate for a platform motion blows up).
    conditioning : ndarray, shape (...)
        ``1 / cond_2`` of the rods' unit lines ``[u_i, (R p_i) x u_i / rp]`` (u_i the unit rod
        direction, rotation scaled by the platform radius ``rp``), in [0, 1]. 0 when the rods
        cannot resist some platform motion (a direct, "type 2" singularity; the platform gains
        freedom). Independent of the Euler parametrisation.
    """

    matrix: np.ndarray
    margin: np.ndarray
    transmission: np.ndarray
    conditioning: np.ndarray


class Rus6:
    """Kinematics of one 6-RUS platform.

    Parameters
    ----------
    geometry : Rus6Geometry
        Dimensions and limits (SI units), e.g. ``Rus6Geometry.preset("ceart")``.
    """

    def __init__(self, geometry: Rus6Geometry) -> None:
        if not isinstance(geometry, Rus6Geometry):
            raise ConfigError(f"Rus6: expected a Rus6Geometry, got {type(geometry).__name__}")
        self.geometry = geometry
        self._pivots = geometry.pivots
        self._cdir = geometry.crank_directions
        self._local = geometry.platform_joints_local
        self._origin = geometry.platform_origin
        self._crank = np.array(geometry.crank)
        self._rod = np.array(geometry.rod)
        self._rod_crank = self._rod * self._crank
        lo, hi = np.array(geometry.angle_min), np.array(geometry.angle_max)
        lo.flags.writeable = False
        hi.flags.writeable = False
        self._limits = (lo, hi)
        self._G = _k.pack_geometry(
            self._pivots,
            self._cdir,
            self._local,
            self._origin,
            geometry.crank,
            geometry.rod,
            lo,
            hi,
        )
        self._park_pose: np.ndarray | None = None

    def __repr__(self) -> str:
        return f"Rus6(geometry={self.geometry.name!r})"

    # ------------------------------------------------------------------ properties
    @property
    def angle_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)`` crank angle limits, rad, each shape (6,) (read-only arrays)."""
        return self._limits

    @property
    def neutral_angle(self) -> np.ndarray:
        """Crank angles at the neutral pose, rad, shape (6,)."""
        return self.geometry.neutral_angle

    @property
    def park_angle(self) -> np.ndarray:
        """Crank angles of the parked platform, rad, shape (6,)."""
        return np.full(6, self.geometry.park_angle)

    @property
    def park_pose(self) -> np.ndarray:
        """The parked pose (pure heave down, FRD z > 0), shape (6,)."""
        if self._park_pose is None:
            z = float(np.mean(self.geometry.heave_for_angles(self.park_angle)))
            self._park_pose = np.array([0.0, 0.0, z, 0.0, 0.0, 0.0])
        return self._park_pose.copy()

    @property
    def max_speed(self) -> np.ndarray:
        """Crank speed limits, rad/s, shape (6,)."""
        return np.array(self.geometry.max_speed)

    @property
    def max_accel(self) -> np.ndarray:
        """Crank acceleration limits, rad/s^2, shape (6,)."""
        return np.array(self.geometry.max_accel)

    # ------------------------------------------------------------------ kinematics
    def inverse(self, pose: ArrayLike) -> np.ndarray:
        """Crank angles of a pose by the thesis's closed form (eq. 8.57 with atan2).

        Parameters
        ----------
        pose : array_like, shape (6,) or (..., 6)
            ``[x, y, z, roll, pitch, yaw]`` in m and rad (FRD base axes, Z-Y-X Euler).

        Returns
        -------
        ndarray, shape (..., 6)
            Crank angles, rad, in (-pi, pi]. A pose whose legs cannot all close gives a row of
            NaN (no warning, no exception). Angles are *not* limited here: use
            :meth:`reachable` or :meth:`clamp` before commanding an actuator.
        """
        return run_inverse(_k.inverse_batch, self._G, pose)

    def reachable(self, pose: ArrayLike) -> np.ndarray | bool:
        """Whether each pose closes every leg with every crank within its limits.

        Returns a bool for one pose, a bool array of shape (...) for a batch. NaN/inf poses are
        not reachable.
        """
        return run_reachable(_k.reachable_batch, self._G, pose)

    def forward(
        self,
        angles: ArrayLike,
        guess: ArrayLike | None = None,
        *,
        tol: float = 1e-10,
        max_iter: int = 50,
    ) -> np.ndarray:
        """Pose from crank angles by damped Newton iteration on the leg closures.

        Parameters
        ----------
        angles : array_like, shape (6,) or (..., 6)
            Crank angles, rad.
        guess : array_like, shape (6,) or (..., 6), optional
            Starting pose(s) (broadcast against ``angles``); the neutral pose by default. Pass
            the previous pose when tracking a moving platform.
        tol : float
            Convergence tolerance: Newton step below ``tol`` (m, rad) and every rod length
            error below ``tol`` (m).
        max_iter : int
            Iteration limit.

        Returns
        -------
        ndarray, shape (..., 6)
            Poses; a row of NaN where the iteration did not converge (or the input is not
            finite).
        """
        return run_forward(_k.forward_batch, self._G, angles, guess, tol, max_iter, "angles")

    def joint_points(self, pose: ArrayLike) -> JointPoints:
        """Crank pivots, crank tips and platform joints of a pose, in base axes.

        Returns
        -------
        JointPoints
            ``(pivots, crank_tips, platform_joints)``, each shape (..., 6, 3), m. NaN crank
            tips where the pose cannot be closed (the platform joints are still the commanded
            rigid-body positions).
        """
        flat, lead = as_poses(pose)
        out = np.empty((3, len(flat), 6, 3))
        _k.joint_points_batch(flat, self._G, out[0], out[1], out[2])
        shape = lead + (6, 3)
        return JointPoints(*(a.reshape(shape) for a in out))

    def jacobian(self, pose: ArrayLike, *, angular: str = "euler") -> JacobianResult:
        """Crank-rate Jacobian ``theta_dot = J @ pose_rate`` and a singularity measure.

        Parameters
        ----------
        pose : array_like, shape (6,) or (..., 6)
        angular : {"euler", "omega"}
            Rotational part of ``pose_rate``: the Euler-angle rates (roll, pitch, yaw rates;
            default, the time derivative of the pose vector) or the angular velocity in base
            axes (rad/s).

        Returns
        -------
        JacobianResult
            ``matrix`` (..., 6, 6) and the singularity measures ``margin``, ``transmission``,
            ``conditioning`` (...); see :class:`JacobianResult`.
        """
        if angular not in ("euler", "omega"):
            raise ConfigError(f"jacobian: angular must be 'euler' or 'omega', got {angular!r}")
        flat, lead = as_poses(pose)
        n = flat.shape[0]
        J = np.empty((n, 6, 6))
        lines = np.empty((n, 6, 6))
        jq = np.empty((n, 6))
        _k.jacobian_batch(flat, self._G, angular == "omega", J, lines, jq)
        closable = ~np.isnan(jq).any(axis=1)
        trans = np.full(n, np.nan)
        cond = np.full(n, np.nan)
        if closable.any():
            # |jq| = 2 |rod . dtip/dtheta| and |rod| = R, |dtip/dtheta| = r
            trans[closable] = np.min(np.abs(jq[closable]) / (2.0 * self._rod_crank), axis=1)
            unit = lines[closable] / (2.0 * self._rod)[:, None]
            unit[:, :, 3:] /= self.geometry.rp
            s = np.linalg.svd(unit, compute_uv=False)
            cond[closable] = np.where(s[:, 0] > 0, s[:, -1] / np.maximum(s[:, 0], 1e-300), 0.0)
        margin = np.minimum(trans, cond)
        return JacobianResult(
            J.reshape(lead + (6, 6)),
            margin.reshape(lead),
            trans.reshape(lead),
            cond.reshape(lead),
        )

    def clamp(self, pose: ArrayLike) -> tuple[np.ndarray, np.ndarray | bool]:
        """The nearest safe pose on the way to neutral, rotation kept first.

        A reachable pose is returned unchanged. Otherwise (priority-aware, never per leg):
        Euler angles are wrapped to [-pi, pi) (the same rotation); the rotation is kept and
        the translation scaled toward zero as little as needed (a scan, then bisection to
        machine precision); if no scale of the translation makes the rotation reachable, the
        translation is dropped and the rotation scaled toward zero. Non-finite input gives
        the neutral pose.

        Returns
        -------
        pose : ndarray, shape (..., 6)
            Always reachable (legs close, cranks within limits), never NaN.
        clamped : bool or ndarray of bool, shape (...)
            True where the returned pose differs from the input.
        """
        return run_clamp(_k.clamp_batch, self._G, pose)

    def clamp_inverse(self, pose: ArrayLike) -> tuple[np.ndarray, bool, np.ndarray]:
        """:meth:`clamp` then :meth:`inverse` of one pose in a single compiled call.

        The real-time path of the pipeline: the same numbers as the two calls.

        Parameters
        ----------
        pose : array_like, shape (6,)
            ``[x, y, z, roll, pitch, yaw]``, m and rad.

        Returns
        -------
        pose : ndarray, shape (6,)
            The clamped (reachable) pose.
        clamped : bool
        angles : ndarray, shape (6,)
            Its crank angles, rad, within the limits.
        """
        p = np.asarray(pose, dtype=np.float64).reshape(6)
        out = np.empty(6)
        angles = np.empty(6)
        clamped = _k.clamp_inverse_one(p, self._G, out, angles)
        return out, bool(clamped), angles

    def warm_up(self) -> None:
        """Compile (or load from the on-disk cache) every kernel now rather than on first use."""
        p = np.zeros((1, 6))
        self.inverse(p)
        self.reachable(p)
        self.clamp(p)
        self.jacobian(p)
        self.forward(self.inverse(p))


class Rus6Robot(Robot):
    """The 6-RUS platform as a pipeline robot (:class:`~motionbase.platform.robot.Robot`):
    the cue pose is the platform pose; actuators are cranks (rad); park is every crank at
    the geometry's ``park_angle``.

    Parameters
    ----------
    geometry : Rus6Geometry
    """

    name = "rus6"
    actuator_unit = "rad"
    solve_kernel = staticmethod(_k.solve)

    def __init__(self, geometry: Rus6Geometry) -> None:
        self.kin = Rus6(geometry)
        self.geometry = geometry
        self.n = 6
        lo, hi = self.kin.angle_limits
        self.limits = ActuatorLimits.broadcast(6, lo, hi, geometry.max_speed, geometry.max_accel)
        self.park_angles = np.full(6, float(geometry.park_angle))
        self.neutral_pose = np.zeros(6)
        self.park_pose = self.kin.forward(self.park_angles, guess=self.neutral_pose)
        self.park_cue = self.park_pose
        self.kernel_params = self.kin._G.ravel()
        if not np.isfinite(self.park_pose).all():
            raise ConfigError("geometry: park_angle gives no assembled platform (choose another)")
        self._finish()
