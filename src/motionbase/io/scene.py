"""The platform as a 3D scene: ``foxglove.SceneUpdate`` messages (dicts) for ``/platform/scene``.

No I/O here: :class:`SceneBuilder` turns one pipeline output (the achieved pose, the
actuator angles, whether the pose was clamped) into the message, or the numbers it is made
of, that :class:`~motionbase.io.pipeline_log.PipelineLog` logs, and that Foxglove's 3D panel draws
(in the log and live, see the README's "Watching live in Foxglove").

What is drawn
    One entity per leg (``leg1`` ... ``legN``): the crank (pivot -> crank tip) and the rod
    (crank tip -> platform joint) as lines, and a sphere at each of the three joints; an
    entity ``base`` (a line loop through the crank pivots) and an entity ``platform`` (the
    top plate: triangles from the centroid of the platform joints, and its outline). The
    points are the robot's ``joint_points`` of the logged platform pose
    (:meth:`motionbase.platform.robot.Robot.joint_points`).

Frames
    6-RUS: frame ``base`` (x forward, y right, z down), the parent frame of ``/tf``, so the
    scene sits where the platform frame does; pick ``world`` as the display frame (``/tf``
    also holds ``world -> base``). 3-RRR: frame ``world`` with z = 0: the thesis's base frame
    (x from motor 1 to motor 2, y toward motor 3) is z-up, as Foxglove's world is.

Colours (the rule)
    A leg is red (crank and rod) when its actuator angle, as commanded this tick, is within
    :data:`NEAR_LIMIT_DEG` (5 deg) of either end of its range (the geometry's crank limits on
    the 6-RUS, the servo interval on the 3-RRR); otherwise the crank is blue and the rod grey.
    The top plate is green, orange when the workspace clamp moved the pose this tick.
"""

from __future__ import annotations

import contextlib
import math
from typing import Any

import numpy as np

from motionbase.scene_update import scene_message

__all__ = ["NEAR_LIMIT_DEG", "NEAR_LIMIT_M", "SCENE_RATE_HZ", "SceneBuilder", "near_limit"]

#: A leg is drawn red when its angle is this close to an end of its range, deg.
NEAR_LIMIT_DEG = 5.0
#: A linear actuator within this of an end of its stroke is drawn in the warning colour, m.
NEAR_LIMIT_M = 0.02
#: Scenes per second of source time written by the pipeline's log (not every tick).
SCENE_RATE_HZ = 30.0


def near_limit(
    angles: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    margin: float = math.radians(NEAR_LIMIT_DEG),
) -> np.ndarray:
    """Which actuators are within ``margin`` of an end of their range (bool array).

    Parameters
    ----------
    angles, lower, upper : ndarray, shape (n,)
        Actuator positions and their range (rad, angles expressed inside the range; or m).
    margin : float
        Rad (default :data:`NEAR_LIMIT_DEG`), or m for linear actuators.
    """
    a = np.asarray(angles, dtype=float)
    return (a - lower < margin) | (upper - a < margin)


class SceneBuilder:
    """Builds the ``/platform/scene`` message of a robot's pose.

    :meth:`message` gives it as a dict; :meth:`parts` gives the numbers it is made of, which
    the pipeline's log sends to its writer process: the tick computes the robot's points
    (compiled, a few us) and the writer builds and encodes the message
    (:func:`motionbase.scene_update.scene_message`), off the tick.

    Parameters
    ----------
    robot : Robot
        The robot plug-in (:class:`~motionbase.platform.robot.Robot`): its ``joint_points``
        (the first array drawn as the base, the last as the top plate, the first segment of
        each chain as the crank and the others as the rod; a planar robot's drawn at
        z = 0), and its actuator ``limits`` for the near-limit colour (rad, or m for linear
        actuators: :data:`NEAR_LIMIT_M`).
    """

    def __init__(self, robot: Any) -> None:
        from motionbase.platform.robot import robot_spec

        self.robot = robot
        self.lower = np.asarray(robot.limits.lower, dtype=float)
        self.upper = np.asarray(robot.limits.upper, dtype=float)
        linear = robot.actuator_unit == "m"
        self.margin = NEAR_LIMIT_M if linear else math.radians(NEAR_LIMIT_DEG)
        self.planar = robot_spec(robot.name).planar
        self.frame = "world" if self.planar else "base"
        crank = getattr(robot.geometry, "crank", None)
        # m; a robot without cranks: a size from its base (the first points at rest)
        self._size = None if crank is None else float(np.mean(crank))
        # Draw once now, at rest: the first scene loads the robot's compiled joint_points
        # (a few ms, a late first tick at 1 kHz). (A writable copy: numba compiles apart
        # for the robot's read-only arrays, and the ticks' poses are writable.)
        rest = np.array(robot.neutral_pose, dtype=float)
        with contextlib.suppress(Exception):
            self.parts(0.0, rest, robot.inverse(rest))

    def points(self, pose: np.ndarray) -> tuple[np.ndarray, ...]:
        """The chains' points of ``pose`` in the scene's frame, each (n, 3), m."""
        pts = self.robot.joint_points(np.asarray(pose, dtype=float))
        return tuple(np.column_stack([v, np.zeros(len(v))]) if v.shape[-1] == 2 else v for v in pts)

    def _sizes(self, pts: tuple[np.ndarray, ...]) -> tuple[float, float, float]:
        """Joint sphere size, crank and rod line thickness, m."""
        if self._size is None:
            base = pts[0]
            self._size = 0.45 * float(np.mean(np.linalg.norm(base - base.mean(axis=0), axis=1)))
        size = self._size
        return 0.25 * size, 0.12 * size, 0.06 * size

    def parts(
        self, t: float, pose: np.ndarray, angles: np.ndarray, clamped: bool = False
    ) -> list[Any]:
        """The numbers that make the scene of one tick, as plain data: the arguments of
        :func:`motionbase.scene_update.scene_message` (the log's writer process builds the
        message from them; the parameters are :meth:`message`'s)."""
        pts = self.points(pose)
        chains = [v.tolist() for v in pts]
        near = near_limit(angles, self.lower, self.upper, self.margin).tolist()
        centre = np.mean(pts[-1], axis=0).tolist()
        return [float(t), self.frame, list(self._sizes(pts)), chains, centre, near, bool(clamped)]

    def message(
        self, t: float, pose: np.ndarray, angles: np.ndarray, clamped: bool = False
    ) -> dict[str, Any]:
        """The ``foxglove.SceneUpdate`` of one tick (a plain dict, with ``t``).

        Parameters
        ----------
        t : float
            Time, s, source clock (the entities' timestamp).
        pose : ndarray, shape (6,) or (3,)
            The achieved platform pose (6-RUS) or planar pose ``[x, y, phi]``.
        angles : ndarray, shape (6,) or (3,)
            The actuator angles commanded this tick, rad (for the near-limit colour).
        clamped : bool
            The workspace clamp moved the pose (the top plate turns orange).
        """
        return scene_message(*self.parts(t, pose, angles, clamped))
