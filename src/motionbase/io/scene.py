"""The platform as a 3D scene: ``foxglove.SceneUpdate`` messages (dicts) for ``/platform/scene``.

No I/O here: :class:`SceneBuilder` turns one pipeline output (the achieved pose, the
actuator angles, whether the pose was clamped) into the JSON message that
:class:`~motionbase.io.pipeline_log.PipelineLog` logs, and that Foxglove's 3D panel draws
(in the log and live, see the README's "Watching live in Foxglove").

What is drawn
    One entity per leg (``leg1`` ... ``legN``): the crank (pivot -> crank tip) and the rod
    (crank tip -> platform joint) as lines, and a sphere at each of the three joints; an
    entity ``base`` (a line loop through the crank pivots) and an entity ``platform`` (the
    top plate: triangles from the centroid of the platform joints, and its outline). The
    points are the robot's ``joint_points`` of the logged platform pose
    (:meth:`motionbase.platform.Rus6.joint_points`, :meth:`motionbase.platform.Rrr3.joint_points`).

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

import math
from typing import Any

import numpy as np

__all__ = ["NEAR_LIMIT_DEG", "SCENE_RATE_HZ", "SceneBuilder", "near_limit"]

#: A leg is drawn red when its angle is this close to an end of its range, deg.
NEAR_LIMIT_DEG = 5.0
#: Scenes per second of source time written by the pipeline's log (not every tick).
SCENE_RATE_HZ = 30.0

_SEC = 1_000_000_000
_Q = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
_IDENTITY = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": _Q}
_ZERO_DURATION = {"sec": 0, "nsec": 0}
_LINE_STRIP, _LINE_LOOP = 0, 1


def _color(r: float, g: float, b: float, a: float = 1.0) -> dict[str, float]:
    return {"r": r, "g": g, "b": b, "a": a}


CRANK = _color(0.20, 0.45, 0.90)
ROD = _color(0.75, 0.75, 0.75)
NEAR = _color(0.90, 0.10, 0.10)
JOINT = _color(0.15, 0.15, 0.15)
BASE = _color(0.35, 0.35, 0.35)
PLATE = _color(0.30, 0.70, 0.40, 0.6)
PLATE_CLAMPED = _color(1.00, 0.60, 0.00, 0.6)


def near_limit(angles: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Which actuators are within :data:`NEAR_LIMIT_DEG` of an end of their range (bool array).

    Parameters
    ----------
    angles, lower, upper : ndarray, shape (n,)
        Actuator angles and their range, rad (angles expressed inside the range).
    """
    margin = math.radians(NEAR_LIMIT_DEG)
    a = np.asarray(angles, dtype=float)
    return (a - lower < margin) | (upper - a < margin)


def _point(p: Any) -> dict[str, float]:
    return {"x": p[0], "y": p[1], "z": p[2]}


def _line(points: list, thickness: float, color: dict, kind: int = _LINE_STRIP) -> dict:
    return {
        "type": kind,
        "pose": _IDENTITY,
        "thickness": thickness,
        "scale_invariant": False,
        "points": [_point(p) for p in points],
        "color": color,
        "colors": [],
        "indices": [],
    }


def _sphere(p: Any, size: float, color: dict) -> dict:
    return {
        "pose": {"position": _point(p), "orientation": _Q},
        "size": {"x": size, "y": size, "z": size},
        "color": color,
    }


def _entity(ts: dict, frame: str, name: str, **primitives: list) -> dict:
    entity = {
        "timestamp": ts,
        "frame_id": frame,
        "id": name,
        "lifetime": _ZERO_DURATION,
        "frame_locked": False,
        "metadata": [],
        "arrows": [],
        "cubes": [],
        "spheres": [],
        "cylinders": [],
        "lines": [],
        "triangles": [],
        "texts": [],
        "models": [],
    }
    entity.update(primitives)
    return entity


class SceneBuilder:
    """Builds the ``/platform/scene`` message of a robot's pose.

    Parameters
    ----------
    kinematics : Rus6 or Rrr3
        The robot (its ``joint_points`` and ``angle_limits``).
    """

    def __init__(self, kinematics: Any) -> None:
        self.kin = kinematics
        limits = kinematics.angle_limits
        if isinstance(limits, tuple):  # Rus6: (lo, hi)
            self.planar = False
            self.lower, self.upper = (np.asarray(v, dtype=float) for v in limits)
        else:  # Rrr3: (3, 2) intervals
            self.planar = True
            self.lower, self.upper = np.asarray(limits, dtype=float).T
        self.frame = "world" if self.planar else "base"
        size = float(np.mean(kinematics.geometry.crank))  # m (per leg on the 6-RUS)
        self._joint_size = 0.25 * size
        self._crank_thickness = 0.12 * size
        self._rod_thickness = 0.06 * size

    def points(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pivots, crank tips and platform joints of ``pose`` in the scene's frame, (n, 3), m."""
        a, b, c = self.kin.joint_points(np.asarray(pose, dtype=float))
        if self.planar:  # (3, 2) in the thesis's base frame, z = 0
            a, b, c = (np.column_stack([v, np.zeros(len(v))]) for v in (a, b, c))
        return a, b, c

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
        ns = round(t * 1e9)
        ts = {"sec": ns // _SEC, "nsec": ns % _SEC}
        pivots, tips, joints = (v.tolist() for v in self.points(pose))
        near = near_limit(angles, self.lower, self.upper).tolist()
        frame = self.frame
        entities = [_entity(ts, frame, "base", lines=[_line(pivots, 0.5 * self._rod_thickness,
                                                             BASE, _LINE_LOOP)])]  # fmt: skip
        js = self._joint_size
        for i, (p, q, r) in enumerate(zip(pivots, tips, joints, strict=True)):
            hot = near[i]
            entities.append(
                _entity(
                    ts,
                    frame,
                    f"leg{i + 1}",
                    lines=[
                        _line([p, q], self._crank_thickness, NEAR if hot else CRANK),
                        _line([q, r], self._rod_thickness, NEAR if hot else ROD),
                    ],
                    spheres=[_sphere(p, js, JOINT), _sphere(q, js, JOINT), _sphere(r, js, JOINT)],
                )
            )
        centre = np.mean(np.asarray(joints), axis=0).tolist()
        fan = []
        n = len(joints)
        for i in range(n):
            fan += [centre, joints[i], joints[(i + 1) % n]]
        plate = PLATE_CLAMPED if clamped else PLATE
        entities.append(
            _entity(
                ts,
                frame,
                "platform",
                triangles=[
                    {
                        "pose": _IDENTITY,
                        "points": [_point(p) for p in fan],
                        "color": plate,
                        "colors": [],
                        "indices": [],
                    }
                ],
                lines=[_line(joints, self._rod_thickness, plate, _LINE_LOOP)],
            )
        )
        return {"t": t, "deletions": [], "entities": entities}
