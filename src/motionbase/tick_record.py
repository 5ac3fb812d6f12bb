"""One pipeline tick as bytes, and the log's messages made from them.

The pipeline's log sends each tick to the log's writer process
(:mod:`motionbase.io.log_writer`) as one record: :func:`pack` on the tick's thread (a few
byte copies), :func:`messages` in the writer process (the topics' messages, which it
encodes). The tick then builds no message and encodes no JSON: that work is on the
other core.

Standard library only, as :mod:`motionbase.scene_update`: the writer process imports it.
:func:`pack` takes a :class:`~motionbase.state.PipelineOutput` (its arrays are numpy's, of
float64 but for the servo degrees), :func:`messages` gives plain dicts, lists and numbers.

Layout: :data:`HEAD` (little-endian), then doubles in the machine's order (numpy's
``tobytes``; both processes run on one machine): the sample's specific force, angular
velocity and attitude (and angular acceleration) when the tick has a sample, the cueing's
pose (6), the platform pose, the actuator command and the servos' degrees when there are
any; then a JSON tail (as :func:`motionbase.io.mcap_log.encode_message` writes it) when
the cueing has a status or diagnostics: ``[status, diagnostics topic, diagnostics]``.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Callable
from typing import Any

#: time (s), the sample's own time (s), fade, phase (ASCII), lengths of the platform pose
#: and of the command, fresh, accepted, clamped, rate limited, held, on the ground (-1: not
#: given), a sample, its angular acceleration, servo degrees; the JSON tail's length
HEAD = struct.Struct("<ddd8sBB5?b3?I")
_STATE_KEYS = ("specific_force", "angular_velocity", "attitude")


def pack(out: Any, diagnostics: Any, topic: str, encode: Callable[[Any], bytes]) -> bytes:
    """The record of one :class:`~motionbase.state.PipelineOutput`, with the cueing's
    diagnostics of the tick (a dict, or None) for ``topic`` (``/cueing/<name>``);
    ``encode`` writes the JSON tail (:func:`motionbase.io.mcap_log.encode_message`)."""
    s, servo = out.state, out.servo_deg
    arrays = [out.washout_pose, out.platform_pose, out.angles]
    acc = ground = None
    if s is not None:
        acc, ground = s.angular_acceleration, s.on_ground
        first = (s.specific_force, s.angular_velocity, s.attitude, acc)
        arrays[:0] = first[: 3 + (acc is not None)]
    if servo is not None:
        arrays.append(servo.astype(float))
    extra = out.cue_status or diagnostics is not None
    tail = encode([out.cue_status or None, topic, diagnostics]) if extra else b""
    head = HEAD.pack(
        out.t, math.nan if s is None else s.t, out.fade, out.phase.encode(),
        len(out.platform_pose), len(out.angles), out.fresh, out.accepted, out.clamped,
        out.rate_limited, out.held, -1 if ground is None else ground, s is not None,
        acc is not None, servo is not None, len(tail),
    )  # fmt: skip
    return b"".join([head, *[a.tobytes() for a in arrays], tail])


def messages(record: bytes) -> tuple[list[tuple[str, dict[str, Any]]], list[float] | None]:
    """The ``(topic, message)`` pairs of one tick's record, in the order they are logged,
    and the platform pose for ``/tf`` (None in planar mode, and for a robot whose pose is
    not ``[x, y, z, roll, pitch, yaw]``: a plug-in's of fewer axes, drawn by its scene).

    The topics are those of :mod:`motionbase.io.pipeline_log`: ``/aircraft/state`` (a tick
    with a sample), ``/washout/pose``, ``/platform/pose`` and ``/platform/actuators`` (or
    ``/planar/pose`` and ``/planar/actuators`` for a command in servo degrees), and the
    cueing's diagnostics topic. Non-finite numbers are written as the strings ``"NaN"``,
    ``"Infinity"`` and ``"-Infinity"`` (:func:`json_float`), as
    :func:`motionbase.io.mcap_log.json_safe` does.
    """
    (t, source_t, fade, phase, m, n, fresh, accepted, clamped, rate_limited, held, ground,
     has_state, has_acc, servo, tail) = HEAD.unpack_from(record)  # fmt: skip
    k = (9 + 3 * has_acc) * has_state + 6 + m + n + n * servo
    if HEAD.size + 8 * k + tail != len(record):  # e.g. an array of another type than float64
        raise ValueError(f"a tick record of {len(record)} bytes, not {HEAD.size + 8 * k + tail}")
    values = struct.unpack_from(f"={k}d", record, HEAD.size)
    at = 0

    def take(count: int) -> list[Any]:
        nonlocal at
        at += count
        chunk = values[at - count : at]  # (non-finite numbers as JSON's strings for them)
        return list(chunk) if math.isfinite(sum(chunk)) else [json_float(v) for v in chunk]

    items: list[tuple[str, dict[str, Any]]] = []
    if has_state:
        state = {"t": t, "source_t": json_float(source_t)}
        state.update((key, take(3)) for key in _STATE_KEYS)
        state.update(fresh=fresh, accepted=accepted)
        if has_acc:
            state["angular_acceleration"] = take(3)
        if ground >= 0:
            state["on_ground"] = bool(ground)
        items.append(("/aircraft/state", state))
    cue = {"t": t, "pose": take(6)}
    pose = take(m)
    actuators = {"t": t, "angles": take(n)}
    if servo:
        actuators["servo_deg"] = [int(v) for v in take(n)]
    status = diagnostics = None
    if tail:
        status, topic, diagnostics = json.loads(record[len(record) - tail :])
    cue.update(status or {})
    prefix = "/planar" if servo else "/platform"
    items += (
        ("/washout/pose", cue),
        (f"{prefix}/pose", {"t": t, "pose": pose, "clamped": clamped, "rate_limited":
         rate_limited, "held": held, "phase": phase.rstrip(b"\0").decode(), "fade": fade}),
        (f"{prefix}/actuators", actuators),
    )  # fmt: skip
    if diagnostics is not None:
        items.append((topic, diagnostics if "t" in diagnostics else {"t": t, **diagnostics}))
    return items, None if servo or m != 6 else pose


def json_float(v: float) -> float | str:
    """``v``, or when it is not finite the string the log writes for it in JSON (which has
    no NaN or infinity): ``"NaN"``, ``"Infinity"`` or ``"-Infinity"``."""
    return v if math.isfinite(v) else ("NaN" if v != v else ("Infinity" if v > 0 else "-Infinity"))
