"""One pipeline tick as bytes, and the log's messages made from them.

The pipeline's log sends each tick to the log's writer process
(:mod:`motionbase.io.log_writer`) as one record: :func:`pack` on the tick's thread
(a few byte copies: the numbers as doubles, the flags as bits), :func:`messages` in the
writer process (the topics' JSON messages, encoded there). The tick then does no
message building and no JSON of its own: that work is on the other core.

Standard library only, as :mod:`motionbase.scene_update`: the writer process imports it.
:func:`pack` takes a :class:`~motionbase.state.PipelineOutput` (its arrays are numpy's),
:func:`messages` gives plain dicts, lists and numbers.

Layout (little-endian): :data:`HEAD` (time, the sample's own time, the fade, the flags,
the phase's name, the lengths of the platform pose and of the actuator command), then doubles:
the sample's specific force, angular velocity and attitude (and angular acceleration)
when there is a sample, the cueing's pose (6), the platform pose, the actuator command,
and the servos' degrees when there are any; then, when :data:`EXTRA` is set, JSON (as
:func:`motionbase.io.mcap_log.encode_message` writes it) of ``[cue status, diagnostics
topic, cueing diagnostics]``, the status or the diagnostics null when there are none.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Callable
from typing import Any

#: time (s), the sample's own time (s), fade, flags, phase (ASCII), platform pose length,
#: command length
HEAD = struct.Struct("<dddH8sBB")
_PLATFORM = ("/platform/pose", "/platform/actuators")
_PLANAR = ("/planar/pose", "/planar/actuators")

# flags
STATE = 1  #: the tick has a sample (not a park tick after the source ended)
FRESH = 2
ACCEPTED = 4
CLAMPED = 8
RATE_LIMITED = 16
HELD = 32
ANGULAR_ACCELERATION = 64  #: the sample has angular accelerations
ON_GROUND_KNOWN = 128  #: the sample gives its flight phase ...
ON_GROUND = 256  #: ... and it is on the ground
SERVO = 512  #: the command has servo degrees (planar mode)
EXTRA = 1024  #: a JSON tail follows: [cue status, diagnostics topic, cueing diagnostics]


def pack(
    out: Any,
    diagnostics: dict[str, Any] | None = None,
    diagnostics_topic: str = "",
    encode: Callable[[Any], bytes] | None = None,
) -> bytes:
    """The record of one :class:`~motionbase.state.PipelineOutput`.

    Parameters
    ----------
    out : PipelineOutput
        The tick.
    diagnostics : dict, optional
        The cueing's diagnostics of the tick, logged on ``diagnostics_topic``.
    diagnostics_topic : str
        Their topic, ``/cueing/<name>``.
    encode : callable
        Encodes the JSON tail (:func:`motionbase.io.mcap_log.encode_message`, which writes
        numpy values and non-finite numbers); needed only when the tick has a cue status
        or diagnostics.
    """
    s = out.state
    flags = (
        out.fresh * FRESH
        | out.accepted * ACCEPTED
        | out.clamped * CLAMPED
        | out.rate_limited * RATE_LIMITED
        | out.held * HELD
    )
    pose, angles = out.platform_pose, out.angles
    parts = [b""]
    if s is not None:
        flags |= STATE
        parts += (_f8(s.specific_force), _f8(s.angular_velocity), _f8(s.attitude))
        if s.angular_acceleration is not None:
            flags |= ANGULAR_ACCELERATION
            parts.append(_f8(s.angular_acceleration))
        if s.on_ground is not None:
            flags |= ON_GROUND_KNOWN | (ON_GROUND if s.on_ground else 0)
    parts += (_f8(out.washout_pose), _f8(pose), _f8(angles))
    if out.servo_deg is not None:
        flags |= SERVO
        parts.append(_f8(out.servo_deg))
    if out.cue_status or diagnostics is not None:
        assert encode is not None, "a cue status or diagnostics need an encoder"
        flags |= EXTRA
        parts.append(encode([out.cue_status or None, diagnostics_topic, diagnostics]))
    parts[0] = HEAD.pack(
        out.t,
        s.t if s is not None else math.nan,
        out.fade,
        flags,
        out.phase.encode(),
        len(pose),
        len(angles),
    )
    return b"".join(parts)


def _f8(a: Any) -> bytes:
    """An array's values as little-endian doubles."""
    return a.astype("<f8", copy=False).tobytes()


def messages(record: bytes) -> tuple[list[tuple[str, dict[str, Any]]], list[float] | None]:
    """The ``(topic, message)`` pairs of one tick's record, in the order they are logged,
    and the platform pose for ``/tf`` (None in planar mode).

    The topics are those of :mod:`motionbase.io.pipeline_log`: ``/aircraft/state`` (a tick
    with a sample), ``/washout/pose``, ``/platform/pose`` and ``/platform/actuators`` (or
    ``/planar/pose`` and ``/planar/actuators`` for a command in servo degrees), and the
    cueing's diagnostics topic. Non-finite numbers are written as the strings ``"NaN"``,
    ``"Infinity"`` and ``"-Infinity"``, as :func:`motionbase.io.mcap_log.json_safe` writes
    them.
    """
    t, source_t, fade, flags, phase, m, n = HEAD.unpack_from(record)
    at = HEAD.size

    def take(k: int) -> list[float]:
        nonlocal at
        values = list(struct.unpack_from(f"<{k}d", record, at))
        at += 8 * k
        return values

    items: list[tuple[str, dict[str, Any]]] = []
    if flags & STATE:
        state = {
            "t": t,
            "source_t": source_t,
            "specific_force": _finite(take(3)),
            "angular_velocity": _finite(take(3)),
            "attitude": _finite(take(3)),
            "fresh": bool(flags & FRESH),
            "accepted": bool(flags & ACCEPTED),
        }
        if flags & ANGULAR_ACCELERATION:
            state["angular_acceleration"] = _finite(take(3))
        if flags & ON_GROUND_KNOWN:
            state["on_ground"] = bool(flags & ON_GROUND)
        items.append(("/aircraft/state", state))
    cue = {"t": t, "pose": _finite(take(6))}
    pose = _finite(take(m))
    actuators: dict[str, Any] = {"t": t, "angles": _finite(take(n))}
    planar = bool(flags & SERVO)
    if planar:
        actuators["servo_deg"] = [int(v) for v in take(n)]
    status = diagnostics = None
    if flags & EXTRA:
        status, diagnostics_topic, diagnostics = json.loads(record[at:])
    if status:
        cue.update(status)
    pose_topic, actuators_topic = _PLANAR if planar else _PLATFORM
    items += (
        ("/washout/pose", cue),
        (
            pose_topic,
            {
                "t": t,
                "pose": pose,
                "clamped": bool(flags & CLAMPED),
                "rate_limited": bool(flags & RATE_LIMITED),
                "held": bool(flags & HELD),
                "phase": phase.rstrip(b"\0").decode(),
                "fade": fade,
            },
        ),
        (actuators_topic, actuators),
    )
    if diagnostics is not None:
        message = diagnostics if "t" in diagnostics else {"t": t, **diagnostics}
        items.append((diagnostics_topic, message))
    return items, None if planar else pose


def _finite(values: list[float]) -> list[Any]:
    """``values``, each non-finite one as the string JSON needs for it."""
    if math.isfinite(sum(values)):
        return values
    return [
        v if math.isfinite(v) else ("NaN" if v != v else ("Infinity" if v > 0 else "-Infinity"))
        for v in values
    ]
