"""JSON Schemas (draft 2020-12) of every topic motionbase writes to MCAP.

Each topic's messages are JSON objects that carry ``t``, the time of the sample
in seconds of the source's clock (simulation time for JSBSim and replays); the
MCAP ``log_time`` and ``publish_time`` of a message are ``round(t * 1e9)`` ns.
Every schema lists the core fields and allows extra ones.

Non-finite numbers
    JSON has no NaN or infinity. Where a topic may carry them (the raw aircraft
    state as the source gave it, before the pipeline rejects it) they are
    written as the strings ``"NaN"``, ``"Infinity"`` and ``"-Infinity"``, the
    convention of the protobuf JSON mapping, and read back as floats (``null``
    is accepted there too and reads back as NaN). Every
    topic downstream of the safety stage must hold finite numbers only, and
    its schema says so.

``/tf`` carries ``foxglove.FrameTransform`` messages with Foxglove's own schema,
so Foxglove's 3D panel can show the platform move (see
:meth:`motionbase.io.mcap_log.McapLogger.add_transform`); ``/platform/scene`` carries
``foxglove.SceneUpdate`` messages drawing the legs (:mod:`motionbase.io.scene`).
"""

from __future__ import annotations

from typing import Any

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"

#: Strings that stand for non-finite floats in JSON messages.
NONFINITE_STRINGS: dict[str, float] = {
    "NaN": float("nan"),
    "Infinity": float("inf"),
    "-Infinity": float("-inf"),
}

_T = {"type": "number", "description": "time of the sample, s, source clock"}
_NUMBER = {"type": "number"}
_NUMBER_OR_NONFINITE = {
    "anyOf": [{"type": "number"}, {"enum": [*NONFINITE_STRINGS, None]}],
}


def _vector(n: int, description: str, item: dict[str, Any] | None = None) -> dict[str, Any]:
    return {
        "type": "array",
        "items": dict(item or _NUMBER),
        "minItems": n,
        "maxItems": n,
        "description": description,
    }


def _topic(
    title: str, description: str, properties: dict[str, Any], required: list[str]
) -> dict[str, Any]:
    return {
        "$schema": SCHEMA_DIALECT,
        "title": title,
        "description": description,
        "type": "object",
        "properties": {"t": dict(_T), **properties},
        "required": ["t", *required],
        "additionalProperties": True,
    }


AIRCRAFT_STATE = _topic(
    "motionbase.AircraftState",
    "Aircraft motion at the pilot as the source gave it (SI units, body axes FRD). "
    "Non-finite values are written as the strings NaN, Infinity, -Infinity "
    "(null is also accepted and reads back as NaN).",
    {
        "specific_force": _vector(
            3, "specific force f = a - g at the pilot, m/s^2, body FRD", _NUMBER_OR_NONFINITE
        ),
        "angular_velocity": _vector(
            3, "body rates (p, q, r), rad/s, body FRD", _NUMBER_OR_NONFINITE
        ),
        "attitude": _vector(3, "Euler angles (roll, pitch, yaw), rad, Z-Y-X", _NUMBER_OR_NONFINITE),
        "angular_acceleration": _vector(
            3, "body angular accelerations, rad/s^2, body FRD (optional)", _NUMBER_OR_NONFINITE
        ),
        "on_ground": {
            "type": "boolean",
            "description": "flight phase: true on the ground (weight on wheels), false in "
            "the air (optional: absent when the source does not say)",
        },
    },
    ["specific_force", "angular_velocity", "attitude"],
)

WASHOUT_POSE = _topic(
    "motionbase.WashoutPose",
    "Platform pose the washout asks for, before clamping: [x, y, z] m and "
    "[roll, pitch, yaw] rad (Z-Y-X), base axes FRD.",
    {
        "pose": _vector(6, "[x, y, z, roll, pitch, yaw], m and rad"),
        "profile": {
            "type": "string",
            "description": "flight-phase profile the cueing runs or blends toward: base, "
            "ground or air (optional: parameters with profiles only)",
        },
        "profile_weights": {
            "type": "object",
            "additionalProperties": {"type": "number", "minimum": 0, "maximum": 1},
            "description": "each profile's share of the pose (sum 1; optional)",
        },
    },
    ["pose"],
)


def platform_topics(axes: int = 6, actuators: int = 6) -> dict[str, tuple[str, dict[str, Any]]]:
    """``/platform/pose`` and ``/platform/actuators`` (topic -> (schema name, JSON Schema))
    for a robot of ``axes`` pose axes and ``actuators`` actuators: the 6-DOF platforms' 6
    and 6 in :data:`TOPIC_SCHEMAS`, a robot plug-in of fewer its own (its log's, through
    :class:`~motionbase.io.mcap_log.McapLogger`'s ``topics``), each exactly that long."""
    own = axes != 6 or actuators != 6
    pose = _topic(
        "motionbase.PlatformPose",
        "Platform pose after clamping (reachable): [x, y, z] m and [roll, pitch, yaw] rad "
        "(Z-Y-X), base axes FRD"
        + (
            "; here a robot plug-in's own pose (the metadata's pipeline_config.robot)."
            if own
            else "."
        ),
        {
            "pose": _vector(
                axes,
                f"the robot's own pose, {axes} values"
                if own
                else "[x, y, z, roll, pitch, yaw], m and rad",
            ),
            "clamped": {"type": "boolean", "description": "true when the pose was scaled back"},
        },
        ["pose", "clamped"],
    )
    angles = _topic(
        "motionbase.PlatformActuators",
        "Actuator positions sent to the 6-DOF platform: 6-RUS crank angles, rad (0 = crank "
        "horizontal); 6-UPS Stewart actuator lengths joint centre to joint centre, m (the "
        "metadata's pipeline_config.robot says which"
        + ("; here a robot plug-in's, in its actuator unit)." if own else ")."),
        {
            "angles": _vector(
                actuators,
                f"the plug-in's {actuators} actuator positions"
                if own
                else "crank angles, rad (6-RUS), or actuator lengths, m (6-UPS)",
            )
        },
        ["angles"],
    )
    return {
        "/platform/pose": ("motionbase.PlatformPose", pose),
        "/platform/actuators": ("motionbase.PlatformActuators", angles),
    }


PLATFORM_POSE = platform_topics()["/platform/pose"][1]
PLATFORM_ACTUATORS = platform_topics()["/platform/actuators"][1]

PLANAR_POSE = _topic(
    "motionbase.PlanarPose",
    "3-RRR platform pose [x, y, phi] in the thesis's base frame, m and rad.",
    {"pose": _vector(3, "[x, y, phi], m and rad")},
    ["pose"],
)

PLANAR_ACTUATORS = _topic(
    "motionbase.PlanarActuators",
    "3-RRR joint angles, rad, and the servo commands, integer degrees 0..180.",
    {
        "angles": _vector(3, "joint angles, rad"),
        "servo_deg": _vector(
            3, "servo commands, integer degrees", {"type": "integer", "minimum": 0, "maximum": 180}
        ),
    },
    ["angles", "servo_deg"],
)

_COUNT = {"type": "integer", "minimum": 0}

HEALTH = _topic(
    "motionbase.Health",
    "Running counts of the safety stage's interventions and the worst loop overrun.",
    {
        "rejected_inputs": dict(_COUNT, description="input samples rejected and held"),
        "clamps": dict(_COUNT, description="poses scaled back into the workspace"),
        "rate_limited": dict(_COUNT, description="commands limited in speed or acceleration"),
        "watchdog_fades": dict(_COUNT, description="fades to neutral on stale input"),
        "estops": dict(_COUNT, description="emergency stops"),
        "overruns": dict(_COUNT, description="real-time ticks processed later than one period"),
        "overruns_off_cpu": dict(
            _COUNT,
            description="overruns in which the loop thread ran for less than one period "
            "(it waited for the CPU, the interpreter lock or I/O)",
        ),
        "worst_overrun_s": {
            "type": "number",
            "minimum": 0,
            "description": "largest lateness of a loop tick behind its deadline, s",
        },
        "late_commands": dict(
            _COUNT,
            description="commands that reached the sinks more than one period after their "
            "sample was due",
        ),
        "worst_late_s": {
            "type": "number",
            "minimum": 0,
            "description": "largest lateness of a command beyond one period after its due time, s",
        },
    },
    ["rejected_inputs", "clamps", "rate_limited", "watchdog_fades", "estops", "worst_overrun_s"],
)

CURSOR = _topic(
    "motionbase.Cursor",
    "Teleoperation cursor: screen pixel and the calibrated target in the workspace.",
    {
        "pixel": _vector(2, "cursor position on screen, pixels"),
        "target": _vector(2, "calibrated target position [x, y], m"),
    },
    ["pixel", "target"],
)

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
    "description": "Timestamp of transform",
}


def _xyz(title: str, names: str, description: str) -> dict[str, Any]:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": {n: {"type": "number", "description": f"{n} value"} for n in names},
        "required": list(names),
    }


#: Foxglove's ``foxglove.FrameTransform`` JSON Schema (foxglove-sdk schemas/jsonschema).
FRAME_TRANSFORM = {
    "title": "foxglove.FrameTransform",
    "description": "A transform between two reference frames in 3D space. The transform "
    "defines the position and orientation of a child frame within a parent frame. Foxglove "
    "applies the translation first and then the rotation.",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
        "child_frame_id": {"type": "string", "description": "Name of the child frame"},
        "translation": _xyz(
            "foxglove.Vector3",
            "xyz",
            "Translation component of the transform, representing the position of the child "
            "frame's origin in the parent frame.",
        ),
        "rotation": _xyz(
            "foxglove.Quaternion",
            "xyzw",
            "Rotation component of the transform, representing the orientation of the child "
            "frame in the parent frame",
        ),
    },
    "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
}


def _object(title: str, properties: dict[str, Any], description: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {"title": title, "type": "object", "properties": properties}
    if description:
        out["description"] = description
    out["required"] = list(properties)
    return out


def _array(item: dict[str, Any], description: str) -> dict[str, Any]:
    return {"type": "array", "items": item, "description": description}


_VEC3 = _xyz("foxglove.Vector3", "xyz", "Vector in 3D space")
_POINT3 = _xyz("foxglove.Point3", "xyz", "Point in 3D space")
_QUAT = _xyz("foxglove.Quaternion", "xyzw", "Quaternion denoting orientation in 3D space")
_POSE = _object("foxglove.Pose", {"position": _VEC3, "orientation": _QUAT})
_COLOR = _object(
    "foxglove.Color",
    {c: {"type": "number", "description": f"{c} value between 0 and 1"} for c in "rgba"},
)
_DURATION = {
    "type": "object",
    "title": "duration",
    "properties": {"sec": {"type": "integer"}, "nsec": dict(_TIME["properties"]["nsec"])},
}
_LINE = _object(
    "foxglove.LinePrimitive",
    {
        "type": {
            "title": "foxglove.LinePrimitiveLineType",
            "description": "0: LINE_STRIP, 1: LINE_LOOP, 2: LINE_LIST",
            "enum": [0, 1, 2],
        },
        "pose": _POSE,
        "thickness": {"type": "number", "minimum": 0},
        "scale_invariant": {"type": "boolean"},
        "points": _array(_POINT3, "Points along the line"),
        "color": _COLOR,
        "colors": _array(_COLOR, "Per-point colors (empty: color)"),
        "indices": _array({"type": "integer", "minimum": 0}, "Indices into points"),
    },
    "A primitive representing a series of points connected by lines",
)
_SPHERE = _object(
    "foxglove.SpherePrimitive",
    {"pose": _POSE, "size": _VEC3, "color": _COLOR},
    "A primitive representing a sphere or ellipsoid",
)
_TRIANGLES = _object(
    "foxglove.TriangleListPrimitive",
    {
        "pose": _POSE,
        "points": _array(_POINT3, "Vertices, three per triangle"),
        "color": _COLOR,
        "colors": _array(_COLOR, "Per-vertex colors (empty: color)"),
        "indices": _array({"type": "integer", "minimum": 0}, "Indices into points"),
    },
    "A primitive representing a set of triangles or a surface tiled by triangles",
)
_ANY_PRIMITIVE = {"type": "object"}  # arrows, cubes, ... : never written, always empty
_ENTITY = _object(
    "foxglove.SceneEntity",
    {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "id": {"type": "string"},
        "lifetime": _DURATION,
        "frame_locked": {"type": "boolean"},
        "metadata": _array({"type": "object"}, "Key-value pairs"),
        "arrows": _array(_ANY_PRIMITIVE, "Arrow primitives"),
        "cubes": _array(_ANY_PRIMITIVE, "Cube primitives"),
        "spheres": _array(_SPHERE, "Sphere primitives"),
        "cylinders": _array(_ANY_PRIMITIVE, "Cylinder primitives"),
        "lines": _array(_LINE, "Line primitives"),
        "triangles": _array(_TRIANGLES, "Triangle list primitives"),
        "texts": _array(_ANY_PRIMITIVE, "Text primitives"),
        "models": _array(_ANY_PRIMITIVE, "Model primitives"),
    },
    "A visual element in a 3D scene",
)

#: Foxglove's ``foxglove.SceneUpdate`` JSON Schema, the part motionbase writes (lines,
#: spheres, triangles; the other primitive arrays are always empty), plus ``t``.
SCENE_UPDATE = {
    "title": "foxglove.SceneUpdate",
    "description": "An update to the entities displayed in a 3D scene (motionbase: the "
    "platform's legs and plates, see motionbase.io.scene)",
    "type": "object",
    "properties": {
        "t": dict(_T),
        "deletions": _array({"type": "object"}, "Scene entities to delete (none written)"),
        "entities": _array(_ENTITY, "Scene entities to add or replace"),
    },
    "required": ["deletions", "entities"],
}

MPC_DIAGNOSTICS = _topic(
    "motionbase.MpcDiagnostics",
    "The model-predictive cueing's solver, per tick (motionbase.washout.mpc.MpcInfo)",
    {
        "status": {"type": "string", "description": "OSQP's status of this tick's solve"},
        "iterations": {"type": "integer", "minimum": 0, "description": "OSQP iterations"},
        "solve_time_s": {"type": "number", "description": "update + solve wall time, s"},
        "fallback": {
            "type": "boolean",
            "description": "the solution was not used: the last plan, blending to the fallback",
        },
        "weight": {
            "type": "number",
            "description": "share of the MPC's pose in the pose sent (1: all MPC)",
        },
        "preview": {"type": "boolean", "description": "the recorded future of the reference"},
        "violation": {
            "type": "number",
            "description": "largest slack of the soft actuator constraints, rad or m",
        },
    },
    ["status", "iterations", "solve_time_s", "fallback", "weight"],
)

#: Cueings with per-tick diagnostics (:meth:`motionbase.washout.cueing.Cueing.diagnostics`),
#: logged on ``/cueing/<name>``: name -> (schema name, JSON Schema).
CUEING_DIAGNOSTICS: dict[str, tuple[str, dict[str, Any]]] = {
    "mpc": ("motionbase.MpcDiagnostics", MPC_DIAGNOSTICS),
}

#: topic -> (schema name, JSON Schema). The MCAP logger accepts exactly these topics.
TOPIC_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    "/aircraft/state": ("motionbase.AircraftState", AIRCRAFT_STATE),
    "/washout/pose": ("motionbase.WashoutPose", WASHOUT_POSE),
    "/platform/pose": ("motionbase.PlatformPose", PLATFORM_POSE),
    "/platform/actuators": ("motionbase.PlatformActuators", PLATFORM_ACTUATORS),
    "/planar/pose": ("motionbase.PlanarPose", PLANAR_POSE),
    "/planar/actuators": ("motionbase.PlanarActuators", PLANAR_ACTUATORS),
    "/health": ("motionbase.Health", HEALTH),
    "/cursor": ("motionbase.Cursor", CURSOR),
    "/tf": ("foxglove.FrameTransform", FRAME_TRANSFORM),
    "/platform/scene": ("foxglove.SceneUpdate", SCENE_UPDATE),
    **{f"/cueing/{name}": entry for name, entry in CUEING_DIAGNOSTICS.items()},
}

__all__ = [
    "CUEING_DIAGNOSTICS",
    "FRAME_TRANSFORM",
    "NONFINITE_STRINGS",
    "SCENE_UPDATE",
    "SCHEMA_DIALECT",
    "TOPIC_SCHEMAS",
    "platform_topics",
]
