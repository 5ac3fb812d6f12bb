"""Kinematics of the 6-UPS Stewart platform (linear actuators): inverse, forward, clamp, park.

Conventions (DESIGN.md): a pose is ``[x, y, z, roll, pitch, yaw]``, the displacement of the
platform frame (origin at the centroid of the platform joints) from its neutral pose, in FRD
base axes (heave up is negative z), with Z-Y-X Euler angles: ``R = Rz(yaw) Ry(pitch) Rx(roll)``
maps platform-frame vectors to base axes. An actuator value is the length between the leg's
two joint centres, m; speeds m/s, accelerations m/s^2.

The class offers the robot interface of issue 14: :meth:`~Stewart6.inverse`,
:meth:`~Stewart6.reachable`, :meth:`~Stewart6.clamp`, :meth:`~Stewart6.forward`,
:meth:`~Stewart6.joint_points`, :attr:`~Stewart6.limits`, :attr:`~Stewart6.park` and
:attr:`~Stewart6.neutral`. Every method accepts one pose (shape (6,)) or a batch (shape
(..., 6)). The work is done by compiled numba kernels (``_stewart6_kernels``), compiled on
first use and cached on disk; :meth:`Stewart6.warm_up` compiles them ahead of time.

Example
-------
>>> from motionbase.platform import Stewart6, Stewart6Geometry
>>> hexapod = Stewart6(Stewart6Geometry.preset("seat"))
>>> lengths = hexapod.inverse([0.0, 0.0, -0.05, 0.0, 0.05, 0.0])  # 5 cm up, nose up 0.05 rad
>>> safe, clamped = hexapod.clamp([1000.0, 0, 0, 0, 0, 0])          # always reachable
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from motionbase.errors import ConfigError
from motionbase.platform import _stewart6_kernels as _k
from motionbase.platform._pose_kernels import (
    as_poses,
    run_clamp,
    run_forward,
    run_inverse,
    run_reachable,
)
from motionbase.platform.conditioning import MIN_LINE_CONDITIONING, line_conditioning
from motionbase.platform.robot import Robot
from motionbase.platform.stewart6_geometry import Stewart6Geometry
from motionbase.safety import ActuatorLimits

__all__ = ["Park", "Stewart6", "Stewart6Joints", "Stewart6Robot"]


class Park(NamedTuple):
    """The parked platform: actuators retracted to ``length_min + park_margin``.

    Attributes
    ----------
    lengths : ndarray, shape (6,)
        Actuator lengths, m.
    pose : ndarray, shape (6,)
        The pose those lengths hold, by forward kinematics (heave down: z > 0).
    """

    lengths: np.ndarray
    pose: np.ndarray


class Stewart6Joints(NamedTuple):
    """Joint centres in base axes, m.

    Attributes
    ----------
    base_joints : ndarray, shape (..., 6, 3)
        Fixed to the base.
    platform_joints : ndarray, shape (..., 6, 3)
        ``O + p + R q_i`` for the pose.
    """

    base_joints: np.ndarray
    platform_joints: np.ndarray


def _read_only(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


class Stewart6:
    """Kinematics of one 6-UPS Stewart platform with linear actuators.

    Parameters
    ----------
    geometry : Stewart6Geometry
        Dimensions and limits (SI units), e.g. ``Stewart6Geometry.preset("seat")``.

    Raises
    ------
    ConfigError
        If the neutral pose is not reachable or the park pose cannot be found (a geometry
        whose numbers pass the field checks but do not make a working platform).
    """

    def __init__(self, geometry: Stewart6Geometry) -> None:
        if not isinstance(geometry, Stewart6Geometry):
            raise ConfigError(
                f"Stewart6: expected a Stewart6Geometry, got {type(geometry).__name__}"
            )
        self.geometry = geometry
        self._base = _read_only(geometry.base_joints)
        self._G = _k.pack_geometry(
            geometry.base_joints,
            geometry.platform_joints_local,
            geometry.platform_origin,
            geometry.length_min,
            geometry.length_max,
            geometry.line_scale,
        )
        self._limits = ActuatorLimits.broadcast(
            6, geometry.length_min, geometry.length_max, geometry.max_speed, geometry.max_accel
        )
        src = f"stewart6 geometry {geometry.name!r}"
        zero = np.zeros(6)
        if not self.reachable(zero):
            raise ConfigError(
                f"{src}: the neutral pose is not reachable (fix neutral_height or the length "
                "limits)"
            )
        self._neutral = _read_only(self.inverse(zero))
        park_lengths = geometry.park_lengths
        # the parked platform sinks straight down on this symmetric layout; start from neutral
        park_pose = self.forward(park_lengths)
        margin = f"length_min + {geometry.park_margin:g} m"
        if not np.isfinite(park_pose).all():
            raise ConfigError(
                f"{src}: field 'park_margin': no pose holds the actuators at {margin} "
                "(choose another margin)"
            )
        if not self.reachable(park_pose):
            joints = self.joint_points(park_pose).platform_joints
            held = line_conditioning(
                joints - (geometry.platform_origin + park_pose[:3]),
                joints - geometry.base_joints,
                geometry.line_scale,
            )
            why = (
                f"the legs barely hold the platform there (line conditioning {held:.2g} < "
                f"{MIN_LINE_CONDITIONING:g}: near a singularity)"
                if held < MIN_LINE_CONDITIONING
                else "it is not reachable"
            )
            raise ConfigError(
                f"{src}: field 'park_margin': the parked pose, the actuators at {margin} "
                f"({park_pose[2]:.3g} m below neutral), is no place to park: {why} (choose a "
                "larger margin)"
            )
        self._park = Park(_read_only(park_lengths), _read_only(park_pose))

    def __repr__(self) -> str:
        return f"Stewart6(geometry={self.geometry.name!r})"

    # ------------------------------------------------------------------ properties
    @property
    def limits(self) -> ActuatorLimits:
        """Actuator length (m), speed (m/s) and acceleration (m/s^2) limits, each (6,)."""
        return self._limits

    @property
    def neutral(self) -> np.ndarray:
        """Actuator lengths at the neutral pose, m, shape (6,) (read-only)."""
        return self._neutral

    @property
    def park(self) -> Park:
        """Parked actuator lengths (``length_min + park_margin``, m) and their pose."""
        return self._park

    # ------------------------------------------------------------------ kinematics
    def inverse(self, pose: ArrayLike) -> np.ndarray:
        """Actuator lengths of a pose: ``L_i = |O + p + R q_i - B_i|``.

        Parameters
        ----------
        pose : array_like, shape (6,) or (..., 6)
            ``[x, y, z, roll, pitch, yaw]`` in m and rad (FRD base axes, Z-Y-X Euler).

        Returns
        -------
        ndarray, shape (..., 6)
            Lengths, m, joint centre to joint centre. Every finite pose has lengths; they are
            *not* limited here: use :meth:`reachable` or :meth:`clamp` before commanding an
            actuator. A non-finite pose gives NaN.
        """
        return run_inverse(_k.inverse_batch, self._G, pose)

    def reachable(self, pose: ArrayLike) -> np.ndarray | bool:
        """Whether each pose keeps every actuator within its length limits.

        Also required: every platform joint above its base joint and the platform upright
        (tilted less than 90 deg), which rules out the mirror solutions of the length
        equations (platform below the base or upside down), and legs that hold the platform:
        their line conditioning (:mod:`motionbase.platform.conditioning`) at least
        ``MIN_LINE_CONDITIONING``, the bound a geometry must meet at neutral, which keeps
        the platform away from its singularities (yawed 90 deg, say, where the legs cannot
        resist some motion and the forward kinematics has no unique answer). A bool for one
        pose, a bool array of shape (...) for a batch. NaN/inf poses are not reachable.
        """
        return run_reachable(_k.reachable_batch, self._G, pose)

    def clamp(self, pose: ArrayLike) -> tuple[np.ndarray, np.ndarray | bool]:
        """The whole pose scaled toward neutral until it is reachable (never one leg alone).

        A reachable pose is returned unchanged. Otherwise its Euler angles are wrapped to
        [-pi, pi) (the same rotation); if that is still unreachable, the result is ``s`` times
        the wrapped pose for the scale ``s`` in [0, 1) where the line from neutral first leaves
        the workspace (an upward scan in 1/32 steps, then bisection to adjacent floats).
        Non-finite input gives the neutral pose.

        Returns
        -------
        pose : ndarray, shape (..., 6)
            Always reachable (:meth:`reachable` is True for it), never NaN.
        clamped : bool or ndarray of bool, shape (...)
            True where the returned pose differs from the input.
        """
        return run_clamp(_k.clamp_batch, self._G, pose)

    def clamp_inverse(self, pose: ArrayLike) -> tuple[np.ndarray, bool, np.ndarray]:
        """:meth:`clamp` then :meth:`inverse` of one pose in one compiled call (real-time path).

        Returns
        -------
        pose : ndarray, shape (6,)
            The clamped (reachable) pose.
        clamped : bool
        lengths : ndarray, shape (6,)
            Its actuator lengths, m, within the limits.
        """
        p = np.asarray(pose, dtype=np.float64).reshape(6)
        out = np.empty(6)
        lengths = np.empty(6)
        clamped = _k.clamp_inverse_one(p, self._G, out, lengths)
        return out, bool(clamped), lengths

    def forward(
        self,
        lengths: ArrayLike,
        guess: ArrayLike | None = None,
        *,
        tol: float = 1e-10,
        max_iter: int = 50,
    ) -> np.ndarray:
        """Pose from actuator lengths by damped Newton iteration with the analytic Jacobian.

        Parameters
        ----------
        lengths : array_like, shape (6,) or (..., 6)
            Actuator lengths, m.
        guess : array_like, shape (6,) or (..., 6), optional
            Starting pose(s) (broadcast against ``lengths``); the neutral pose by default.
            Pass the previous pose when tracking a moving platform: a hexapod has several
            poses for the same lengths, and Newton finds the one its start leads to.
        tol : float
            Convergence tolerance: Newton step below ``tol`` (m, rad) and every length error
            below ``tol`` (m).
        max_iter : int
            Iteration limit.

        Returns
        -------
        ndarray, shape (..., 6)
            Poses; a row of NaN where the iteration did not converge (or the input is not
            finite, or a length is not positive).
        """
        return run_forward(_k.forward_batch, self._G, lengths, guess, tol, max_iter, "lengths")

    def joint_points(self, pose: ArrayLike) -> Stewart6Joints:
        """Base joints and platform joints of a pose, in base axes, m.

        Returns
        -------
        Stewart6Joints
            ``(base_joints, platform_joints)``, each shape (..., 6, 3). The platform joints
            are the commanded rigid-body positions, whether or not the pose is reachable.
        """
        flat, lead = as_poses(pose)
        joints = np.empty((flat.shape[0], 6, 3))
        _k.joints_batch(flat, self._G, joints)
        base = np.broadcast_to(self._base, joints.shape).copy()
        shape = lead + (6, 3)
        return Stewart6Joints(base.reshape(shape), joints.reshape(shape))

    def warm_up(self) -> None:
        """Compile (or load from the on-disk cache) every kernel now rather than on first use."""
        p = np.zeros((1, 6))
        self.inverse(p)
        self.inverse(p[0])
        self.reachable(p)
        self.clamp(p)
        self.clamp_inverse(p[0])
        self.joint_points(p)
        self.forward(self.inverse(p))


class Stewart6Robot(Robot):
    """The 6-UPS Stewart platform as a pipeline robot
    (:class:`~motionbase.platform.robot.Robot`): the cue pose is the platform pose;
    actuators are linear (lengths joint centre to joint centre, m; speeds m/s,
    accelerations m/s^2); park is every actuator at ``length_min + park_margin``.

    Parameters
    ----------
    geometry : Stewart6Geometry
    """

    name = "stewart6"
    actuator_unit = "m"
    solve_kernel = staticmethod(_k.solve)

    def __init__(self, geometry: Stewart6Geometry) -> None:
        self.kin = Stewart6(geometry)
        self.geometry = geometry
        self.n = 6
        self.limits = self.kin.limits
        self.park_angles = self.kin.park.lengths
        self.neutral_pose = np.zeros(6)
        self.park_pose = self.kin.park.pose
        self.park_cue = self.park_pose
        self.kernel_params = self.kin._G.ravel()
        self._finish()
