"""Workspace of a platform: reachability grids, slices and the single-axis envelope.

The thesis (ch. 8.3, fig. 25) sweeps positions at a fixed orientation and solves the inverse
kinematics at each; :func:`reachability_grid` does that for any grid, :func:`workspace_slices`
gives the three planes through neutral for a plot, and :func:`single_axis_envelope` finds how
far each axis reaches alone (both directions). Any robot with a batch ``reachable(poses)``
method works: the 6-RUS (every leg closes and every crank is within its limits,
:meth:`Rus6.reachable`) and the Stewart platform (:meth:`Stewart6.reachable`); a robot
plug-in is swept by cue poses (:meth:`~motionbase.platform.robot.Robot.cue_reachable`: an
axis it lacks reaches 0 both ways). Pure math:
plotting lives in :mod:`motionbase.io.workspace_plots`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "AXES",
    "Reachable",
    "AxisReach",
    "WorkspaceSlices",
    "format_envelope",
    "lacking_axes",
    "reachability_grid",
    "single_axis_envelope",
    "workspace_slices",
]

#: Pose axis names, in pose order.
AXES = ("surge", "sway", "heave", "roll", "pitch", "yaw")


class Reachable(Protocol):
    """A robot whose workspace these functions sweep (e.g. :class:`Rus6`, :class:`Stewart6`)."""

    def reachable(self, pose: ArrayLike) -> np.ndarray | bool:
        """Bool per pose of shape (..., 6) (one bool for a single pose of shape (6,))."""
        ...


@dataclass(frozen=True)
class AxisReach:
    """How far one pose axis reaches alone from neutral.

    Attributes
    ----------
    axis : str
        One of :data:`AXES`.
    negative, positive : float
        Largest reachable magnitude toward the negative / positive direction of the pose
        coordinate (m for surge, sway, heave; rad for roll, pitch, yaw). Heave negative is up
        (FRD). Both are >= 0.
    """

    axis: str
    negative: float
    positive: float

    @property
    def is_rotation(self) -> bool:
        return self.axis in ("roll", "pitch", "yaw")


def reachability_grid(
    robot: Reachable,
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    orientation: ArrayLike = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """Reachability over a grid of positions at a fixed orientation (thesis fig. 25).

    Parameters
    ----------
    robot : Reachable
        Anything with ``reachable(poses)``: :class:`Rus6`, :class:`Stewart6`.
    x, y, z : array_like, 1-D
        Grid coordinates, m, base axes FRD (z down).
    orientation : array_like, shape (3,)
        ``(roll, pitch, yaw)``, rad.

    Returns
    -------
    ndarray of bool, shape (len(x), len(y), len(z))
    """
    xs, ys, zs = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (x, y, z))
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    poses = np.empty(X.shape + (6,))
    poses[..., 0], poses[..., 1], poses[..., 2] = X, Y, Z
    poses[..., 3:] = np.asarray(orientation, dtype=float)
    return np.asarray(_reachable(robot, poses))


def _reachable(robot: Reachable, poses: np.ndarray) -> Any:
    """``robot.reachable`` of cue poses ``(..., 6)``: a robot plug-in's
    :meth:`~motionbase.platform.robot.Robot.cue_reachable` (its own poses may have other
    axes), a kinematics class's ``reachable``."""
    return getattr(robot, "cue_reachable", robot.reachable)(poses)


def _reach_along(robot: Reachable, axis: int, sign: float, limit: float, tol: float) -> float:
    """Largest t in [0, limit] such that every pose sign * s * e_axis, s <= t, is reachable."""
    n = 2001
    t = np.linspace(0.0, limit, n)
    poses = np.zeros((n, 6))
    poses[:, axis] = sign * t
    ok = np.asarray(_reachable(robot, poses))
    if not ok[0]:
        return 0.0
    bad = np.flatnonzero(~ok)
    if bad.size == 0:
        return float(limit)
    lo, hi = t[bad[0] - 1], t[bad[0]]
    pose = np.zeros(6)
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        pose[axis] = sign * mid
        if _reachable(robot, pose):
            lo = mid
        else:
            hi = mid
    return float(lo)


def single_axis_envelope(
    robot: Reachable,
    *,
    max_translation: float = 2.0,
    max_rotation: float = math.pi,
    tol: float = 1e-9,
) -> list[AxisReach]:
    """How far each of surge, sway, heave, roll, pitch, yaw reaches alone, both ways.

    A fine scan from neutral finds the first unreachable value, then bisection refines it to
    ``tol`` (m or rad). A translation scan that is reachable all the way to
    ``max_translation`` (m) is repeated twice as far, and so on up to
    ``MAX_TRANSLATION_GROWTH`` times it: a large platform's reach is its own, not the
    scan's. Rotations are capped at ``max_rotation`` (rad).

    Returns
    -------
    list of AxisReach, in :data:`AXES` order.
    """

    def reach(j: int, sign: float) -> float:
        limit = max_translation if j < 3 else max_rotation
        found = _reach_along(robot, j, sign, limit, tol)
        while j < 3 and found >= limit and limit < MAX_TRANSLATION_GROWTH * max_translation:
            limit *= 2.0
            found = _reach_along(robot, j, sign, limit, tol)
        return found

    return [AxisReach(name, reach(j, -1.0), reach(j, +1.0)) for j, name in enumerate(AXES)]


def lacking_axes(robot: Reachable, step: float = 1e-3) -> list[str]:
    """The pose axes (:data:`AXES`) a robot does not render: not even ``step`` (m or rad: 1 mm,
    1 mrad) of it either way from neutral (the 3-actuator plug-in's surge, sway and yaw; the
    planar robot's heave, roll and pitch)."""
    moves = np.asarray(_reachable(robot, np.concatenate([np.eye(6), -np.eye(6)]) * step))
    return [axis for axis, ok in zip(AXES, moves[:6] | moves[6:], strict=True) if not ok]


#: How far a translation scan of :func:`single_axis_envelope` goes at most, in units of its
#: ``max_translation`` (2 m by default: 128 m).
MAX_TRANSLATION_GROWTH = 64.0


def format_envelope(envelope: list[AxisReach]) -> str:
    """The envelope as a plain-text table (translations in m, rotations in degrees)."""
    lines = [
        f"{'axis':<7} {'negative':>10} {'positive':>10}  unit  note",
        f"{'-' * 7} {'-' * 10} {'-' * 10}  ----  ----",
    ]
    notes = {
        "surge": "-: back, +: forward",
        "sway": "-: left, +: right",
        "heave": "-: up, +: down (FRD)",
        "roll": "+: right side down",
        "pitch": "+: nose up",
        "yaw": "+: nose right",
    }
    for a in envelope:
        if a.is_rotation:
            neg, pos, unit = math.degrees(a.negative), math.degrees(a.positive), "deg"
            lines.append(f"{a.axis:<7} {neg:>10.1f} {pos:>10.1f}  {unit:<4}  {notes[a.axis]}")
        else:
            lines.append(
                f"{a.axis:<7} {a.negative:>10.3f} {a.positive:>10.3f}  {'m':<4}  {notes[a.axis]}"
            )
    return "\n".join(lines)


@dataclass(frozen=True)
class WorkspaceSlices:
    """Reachability on three planes through the neutral pose at a fixed orientation.

    Attributes
    ----------
    x, y, z : ndarray, 1-D
        Grid coordinates, m (base axes, FRD).
    xy : ndarray of bool, shape (len(x), len(y))
        Plane z = 0.
    xz : ndarray of bool, shape (len(x), len(z))
        Plane y = 0.
    yz : ndarray of bool, shape (len(y), len(z))
        Plane x = 0.
    orientation : tuple of float
        ``(roll, pitch, yaw)``, rad.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    xy: np.ndarray
    xz: np.ndarray
    yz: np.ndarray
    orientation: tuple[float, float, float]


def workspace_slices(
    robot: Reachable,
    orientation: ArrayLike = (0.0, 0.0, 0.0),
    *,
    n: int = 121,
    extent: float | None = None,
) -> WorkspaceSlices:
    """Reachability on the planes z = 0, y = 0 and x = 0 (through neutral).

    Parameters
    ----------
    robot : Reachable
        Anything with ``reachable(poses)``: :class:`Rus6`, :class:`Stewart6`.
    orientation : array_like, shape (3,)
        ``(roll, pitch, yaw)``, rad.
    n : int
        Grid points per axis.
    extent : float, optional
        Half-width of the square grids, m; by default 1.25 x the largest single-axis
        translation reach, widened (by 1.25 at a time) until no slice touches the grid's
        edge: axes combined reach further than single ones (a 6-RUS with 1.2 m rods and
        0.1 m cranks reaches 0.58 m of surge 0.13 m below neutral, where surge alone
        reaches 0.36 m), and a slice cut off at the edge would draw less than the robot
        reaches.
    """
    auto = extent is None
    if extent is None:
        env = single_axis_envelope(robot, tol=1e-4)
        extent = 1.25 * max(max(a.negative, a.positive) for a in env if not a.is_rotation)
    o = tuple(float(v) for v in np.asarray(orientation, dtype=float))
    zero = np.array([0.0])
    for _ in range(8):  # (a bound on the widening: 1.25^8 = 6 x the first extent)
        g = np.linspace(-extent, extent, int(n))
        xy = reachability_grid(robot, g, g, zero, o)[:, :, 0]
        xz = reachability_grid(robot, g, zero, g, o)[:, 0, :]
        yz = reachability_grid(robot, zero, g, g, o)[0, :, :]
        if not auto or not any(_touches_edge(grid) for grid in (xy, xz, yz)):
            break
        extent *= 1.25
    return WorkspaceSlices(g, g.copy(), g.copy(), xy, xz, yz, o)  # type: ignore[arg-type]


def _touches_edge(grid: np.ndarray) -> bool:
    """Whether a reachability grid has a reachable cell on its border."""
    return bool(grid[0].any() or grid[-1].any() or grid[:, 0].any() or grid[:, -1].any())
