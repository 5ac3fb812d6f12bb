"""The ``foxglove.SceneUpdate`` message of a robot drawn from its joint points (plain dicts).

Standard library only, so that the log's writer process (:mod:`motionbase.io.log_writer`)
builds the ``/platform/scene`` messages itself from the numbers a tick sends it;
:class:`motionbase.io.scene.SceneBuilder` computes those numbers (the robot's compiled
``joint_points``) and says what is drawn and how it is coloured.
"""

from __future__ import annotations

from typing import Any

_SEC = 1_000_000_000
_Q = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
_IDENTITY = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": _Q}
_ZERO_DURATION = {"sec": 0, "nsec": 0}
_LINE_STRIP, _LINE_LOOP = 0, 1


def timestamp(ns: int) -> dict[str, int]:
    """A Foxglove ``Timestamp`` (``sec``, ``nsec``) of a log time in ns."""
    return {"sec": ns // _SEC, "nsec": ns % _SEC}


def _color(r: float, g: float, b: float, a: float = 1.0) -> dict[str, float]:
    return {"r": r, "g": g, "b": b, "a": a}


CRANK = _color(0.20, 0.45, 0.90)
ROD = _color(0.75, 0.75, 0.75)
NEAR = _color(0.90, 0.10, 0.10)
JOINT = _color(0.15, 0.15, 0.15)
BASE = _color(0.35, 0.35, 0.35)
PLATE = _color(0.30, 0.70, 0.40, 0.6)
PLATE_CLAMPED = _color(1.00, 0.60, 0.00, 0.6)


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


def scene_message(
    t: float,
    frame: str,
    sizes: list[float],
    chains: list[list[list[float]]],
    centre: list[float],
    near: list[bool],
    clamped: bool,
) -> dict[str, Any]:
    """The scene: one ``leg<i>`` entity per chain, ``base`` and ``platform`` (with ``t``).

    Parameters
    ----------
    t : float
        Time, s, source clock (the entities' timestamp).
    frame : str
        The frame the points are in (``base`` or ``world``).
    sizes : list of 3 floats
        Joint sphere size, crank and rod line thickness, m.
    chains : list of k lists of n points [x, y, z]
        ``chains[j][i]`` is point ``j`` of leg ``i`` (pivot, crank tip, ..., platform
        joint), m; the first chain is drawn as the base, the last as the top plate.
    centre : list of 3 floats
        The centroid of the platform joints, m (the top plate's triangle fan).
    near : list of n bools
        Leg ``i`` is near a limit of its actuator (drawn red).
    clamped : bool
        The workspace clamp moved the pose this tick (the top plate turns orange).
    """
    ns = round(t * 1e9)
    ts = timestamp(ns)
    joint_size, crank_thickness, rod_thickness = sizes
    base = _line(chains[0], 0.5 * rod_thickness, BASE, _LINE_LOOP)
    entities = [_entity(ts, frame, "base", lines=[base])]
    for i, hot in enumerate(near):
        leg = [points[i] for points in chains]
        lines = [_line(leg[:2], crank_thickness, NEAR if hot else CRANK)]
        rods = range(1, len(leg) - 1)
        lines += [_line(leg[j : j + 2], rod_thickness, NEAR if hot else ROD) for j in rods]
        spheres = [_sphere(p, joint_size, JOINT) for p in leg]
        entities.append(_entity(ts, frame, f"leg{i + 1}", lines=lines, spheres=spheres))
    joints = chains[-1]
    n = len(joints)
    fan = []
    for i in range(n):
        fan += [centre, joints[i], joints[(i + 1) % n]]
    plate = PLATE_CLAMPED if clamped else PLATE
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
