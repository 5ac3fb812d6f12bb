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

import contextlib
import math
import re
from operator import itemgetter
from typing import Any

import numpy as np
import orjson

__all__ = ["NEAR_LIMIT_DEG", "NEAR_LIMIT_M", "SCENE_RATE_HZ", "SceneBuilder", "near_limit"]

#: A leg is drawn red when its angle is this close to an end of its range, deg.
NEAR_LIMIT_DEG = 5.0
#: A linear actuator within this of an end of its stroke is drawn in the warning colour, m.
NEAR_LIMIT_M = 0.02
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


def _scene(
    ts: Any,
    frame: str,
    chains: list[list],
    centre: Any,
    crank_colors: list,
    rod_colors: list,
    plate: Any,
    sizes: tuple[float, float, float],
    t: Any,
) -> dict[str, Any]:
    """The scene message: one ``leg<i>`` entity per chain, ``base``, ``platform``.

    ``chains[j][i]`` is point ``j`` (pivot, crank tip, ..., platform joint) of leg ``i``.
    The values may be numbers or placeholders (:class:`SceneBuilder` makes its template
    from the very same call).
    """
    joint_size, crank_thickness, rod_thickness = sizes
    base = _line(chains[0], 0.5 * rod_thickness, BASE, _LINE_LOOP)
    entities = [_entity(ts, frame, "base", lines=[base])]
    for i in range(len(chains[0])):
        leg = [points[i] for points in chains]
        lines = [_line(leg[:2], crank_thickness, crank_colors[i])]
        rods = range(1, len(leg) - 1)
        lines += [_line(leg[j : j + 2], rod_thickness, rod_colors[i]) for j in rods]
        spheres = [_sphere(p, joint_size, JOINT) for p in leg]
        entities.append(_entity(ts, frame, f"leg{i + 1}", lines=lines, spheres=spheres))
    joints = chains[-1]
    n = len(joints)
    fan = []
    for i in range(n):
        fan += [centre, joints[i], joints[(i + 1) % n]]
    triangles = {
        "pose": _IDENTITY,
        "points": [_point(p) for p in fan],
        "color": plate,
        "colors": [],
        "indices": [],
    }
    outline = _line(joints, rod_thickness, plate, _LINE_LOOP)
    entities.append(_entity(ts, frame, "platform", triangles=[triangles], lines=[outline]))
    return {"t": t, "deletions": [], "entities": entities}


_HOLE = re.compile(rb'"@([^@"]*)@"')


class SceneBuilder:
    """Builds the ``/platform/scene`` message of a robot's pose.

    :meth:`message` gives it as a dict; :meth:`encode` gives its JSON bytes (what the log
    writes), the same bytes as ``encode_message(message(...))`` at a fraction of the cost:
    the message's text is a template made once, and a tick only formats its numbers (one
    ``orjson`` call on one array) and joins the pieces.

    Parameters
    ----------
    kinematics : robot
        Any robot whose ``joint_points(pose)`` gives its chains' points, ``k >= 2`` arrays
        of shape ``(n, 3)`` (or ``(n, 2)`` for a planar robot, drawn at z = 0): the first
        is drawn as the base, the last as the top plate, the first segment of each chain as
        the crank and the others as the rod. Its ``angle_limits`` (``(lo, hi)`` arrays, or
        ``(n, 2)`` intervals for the planar 3-RRR), or for linear actuators its ``limits``
        (lengths, m; :data:`NEAR_LIMIT_M`), colour a leg near its limit; a robot without
        them is drawn without that colour.
    """

    def __init__(self, kinematics: Any) -> None:
        self.kin = kinematics
        limits = getattr(kinematics, "angle_limits", None)
        self.lower = self.upper = None
        self.planar = False
        self.margin = math.radians(NEAR_LIMIT_DEG)
        if isinstance(limits, tuple):  # Rus6: (lo, hi)
            self.lower, self.upper = (np.asarray(v, dtype=float) for v in limits)
        elif limits is not None:  # Rrr3: (3, 2) intervals
            self.planar = True
            self.lower, self.upper = np.asarray(limits, dtype=float).T
        elif hasattr(kinematics, "limits"):  # linear actuators (Stewart6): lengths, m
            self.lower = np.asarray(kinematics.limits.lower, dtype=float)
            self.upper = np.asarray(kinematics.limits.upper, dtype=float)
            self.margin = NEAR_LIMIT_M
        self.frame = "world" if self.planar else "base"
        geometry = getattr(kinematics, "geometry", None)
        crank = getattr(geometry, "crank", None)
        # m; a robot without cranks: a size from its base (the first points at rest)
        self._size = None if crank is None else float(np.mean(crank))
        self._templates: dict[tuple[int, int], tuple] = {}
        self._color_json = {
            id(c): orjson.dumps(c) for c in (CRANK, ROD, NEAR, PLATE, PLATE_CLAMPED)
        }
        # Draw once now, at rest: the first scene loads the robot's compiled joint_points
        # and builds the template (4-7 ms, a late first tick at 1 kHz). A robot whose rest
        # pose is neither of these is drawn cold at its first tick instead.
        rest = getattr(kinematics, "home", None)  # the planar robot's; the 6-DOF's is zero
        at_rest = np.zeros(6) if rest is None else np.asarray(rest, dtype=float)
        with contextlib.suppress(Exception):
            self.encode(0.0, at_rest, np.zeros(1 if self.lower is None else len(self.lower)))

    def points(self, pose: np.ndarray) -> tuple[np.ndarray, ...]:
        """The chains' points of ``pose`` in the scene's frame, each (n, 3), m."""
        pts = self.kin.joint_points(np.asarray(pose, dtype=float))
        return tuple(np.column_stack([v, np.zeros(len(v))]) if v.shape[-1] == 2 else v for v in pts)

    def _sizes(self, pts: tuple[np.ndarray, ...]) -> tuple[float, float, float]:
        """Joint sphere size, crank and rod line thickness, m."""
        if self._size is None:
            base = pts[0]
            self._size = 0.45 * float(np.mean(np.linalg.norm(base - base.mean(axis=0), axis=1)))
        size = self._size
        return 0.25 * size, 0.12 * size, 0.06 * size

    def _near(self, angles: np.ndarray, n: int) -> list[bool]:
        if self.lower is None:
            return [False] * n
        return near_limit(angles, self.lower, self.upper, self.margin).tolist()

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
        pts = self.points(pose)
        chains = [v.tolist() for v in pts]
        near = self._near(angles, len(chains[0]))
        centre = np.mean(np.asarray(chains[-1]), axis=0).tolist()
        cranks = [NEAR if hot else CRANK for hot in near]
        rods = [NEAR if hot else ROD for hot in near]
        plate = PLATE_CLAMPED if clamped else PLATE
        return _scene(ts, self.frame, chains, centre, cranks, rods, plate, self._sizes(pts), t)

    def encode(
        self, t: float, pose: np.ndarray, angles: np.ndarray, clamped: bool = False
    ) -> bytes:
        """The JSON bytes of :meth:`message` (the same arguments), as the log writes them.

        Equal to ``encode_message(self.message(...))`` byte for byte (floats in their
        shortest round-trip form); a pose whose points are not finite takes that slow path.
        """
        pts = self.points(pose)
        n, k = len(pts[0]), len(pts)
        template = self._templates.get((n, k))
        if template is None:
            template = self._templates[(n, k)] = self._template(n, k, self._sizes(pts))
        seq, pick = template
        centre = np.mean(np.ascontiguousarray(pts[-1]), axis=0, keepdims=True)
        flat = np.concatenate((*pts, centre)).ravel()
        numbers = orjson.dumps(flat, option=orjson.OPT_SERIALIZE_NUMPY)
        if b"null" in numbers:  # NaN or infinity: written as strings by the general encoder
            from motionbase.io.mcap_log import encode_message

            return encode_message(self.message(t, pose, angles, clamped))
        ns = round(t * 1e9)
        colors = self._color_json
        near = self._near(angles, n)
        values = numbers[1:-1].split(b",")
        values.append(orjson.dumps(float(t)))
        values.append(b'{"sec":%d,"nsec":%d}' % (ns // _SEC, ns % _SEC))
        values.append(colors[id(PLATE_CLAMPED if clamped else PLATE)])
        values += [colors[id(NEAR if hot else CRANK)] for hot in near]
        values += [colors[id(NEAR if hot else ROD)] for hot in near]
        seq = seq.copy()
        seq[1::2] = pick(values)
        return b"".join(seq)

    def _template(self, n: int, k: int, sizes: tuple[float, float, float]) -> tuple:
        """The message's text around its values, and where each value comes from.

        Returns ``(seq, pick)``: ``seq`` the literal pieces with a slot between each two,
        ``pick(values)`` the values in slot order; ``values`` lists the numbers (the points,
        chain by chain, then the plate's centre), ``t``, the timestamp, the plate's colour,
        the crank colours and the rod colours.
        """
        count = 0

        def hole() -> str:
            nonlocal count
            count += 1
            return f"@{count - 1}@"

        chains = [[[hole(), hole(), hole()] for _ in range(n)] for _ in range(k)]
        centre = [hole(), hole(), hole()]
        f = count
        names = {"t": f, "TS": f + 1, "PL": f + 2}
        names.update({f"C{i}": f + 3 + i for i in range(n)})
        names.update({f"R{i}": f + 3 + n + i for i in range(n)})
        msg = _scene("@TS@", self.frame, chains, centre, [f"@C{i}@" for i in range(n)],
                     [f"@R{i}@" for i in range(n)], "@PL@", sizes, "@t@")  # fmt: skip
        pieces = _HOLE.split(orjson.dumps(msg))
        slots = [p.decode() for p in pieces[1::2]]
        order = [int(s) if s.isdigit() else names[s] for s in slots]
        seq: list[bytes] = []
        for literal in pieces[0::2]:
            seq += [literal, b""]
        return seq[:-1], itemgetter(*order)
