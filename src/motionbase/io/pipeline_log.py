"""The MCAP sink of the pipeline: one :class:`PipelineOutput` -> the topics of DESIGN.md.

Topics written per tick (``t`` in seconds, ``log_time`` = ``t`` in ns):

* ``/aircraft/state``: the sample as the source gave it (non-finite numbers kept:
  the logger writes them as strings), with ``fresh`` and ``accepted`` flags and the
  source's own time ``source_t``; replays feed it back.
* ``/washout/pose``: the washout output before fades and clamping.
* 6-RUS: ``/platform/pose`` (after clamping and safety, with ``clamped``,
  ``phase``, ``fade``, ``rate_limited``, ``held``), ``/platform/actuators``
  (crank angles, rad) and a ``foxglove.FrameTransform`` on ``/tf``.
* planar mode: ``/planar/pose`` and ``/planar/actuators`` (with ``servo_deg``).
* ``/health``: the safety counters, once per second of source time and at the end.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from motionbase.errors import SinkError
from motionbase.io._log_kernels import (
    MAX_TOKENS,
    OP_BEGIN,
    OP_END,
    OP_LITERAL,
    OP_NSEC,
    OP_SEC,
    OP_TOKEN,
)
from motionbase.io.mcap_log import (
    McapLogger,
    _orjson,
    encode_message,
    quaternion_from_euler_zyx,
    transform_message,
)

_SEC = 1_000_000_000
_MAX_T = 2.0**63 / 1e9  # s: log times beyond do not fit MCAP's u64 ns
STATIC_Q = (1.0, 0.0, 0.0, 0.0)  # world -> base: half a turn about x (see McapLogger.add_transform)
_ORJSON_NUMPY = _orjson.OPT_SERIALIZE_NUMPY if _orjson is not None else 0


def state_message(t: float, state, fresh: bool, accepted: bool) -> dict[str, Any]:
    """The ``/aircraft/state`` message of one sample (numpy arrays; the logger encodes them)."""
    msg: dict[str, Any] = {
        "t": t,
        "source_t": state.t,
        "specific_force": state.specific_force,
        "angular_velocity": state.angular_velocity,
        "attitude": state.attitude,
        "fresh": fresh,
        "accepted": accepted,
    }
    if state.angular_acceleration is not None:
        msg["angular_acceleration"] = state.angular_acceleration
    return msg


def tick_messages(out) -> list[tuple[str, dict[str, Any]]]:
    """The ``(topic, message)`` pairs of one output, ``/tf`` and ``/health`` aside."""
    t = out.t
    pose_msg = {
        "t": t,
        "pose": out.platform_pose,
        "clamped": out.clamped,
        "rate_limited": out.rate_limited,
        "held": out.held,
        "phase": out.phase,
        "fade": out.fade,
    }
    if out.servo_deg is None:
        items = [
            ("/washout/pose", {"t": t, "pose": out.washout_pose}),
            ("/platform/pose", pose_msg),
            ("/platform/actuators", {"t": t, "angles": out.angles}),
        ]
    else:
        items = [
            ("/washout/pose", {"t": t, "pose": out.washout_pose}),
            ("/planar/pose", pose_msg),
            ("/planar/actuators", {"t": t, "angles": out.angles, "servo_deg": out.servo_deg}),
        ]
    if out.state is not None:
        items.insert(0, ("/aircraft/state", state_message(t, out.state, out.fresh, out.accepted)))
    return items


def _tick_values(out, quaternion) -> tuple:
    """Every value of one tick's messages, in one nested tuple (formatted by one orjson call).

    The order is free (templates take it from here); one expression per kind of tick
    keeps it cheap.
    """
    st = out.state
    last = quaternion if out.servo_deg is None else (out.servo_deg,)
    if st is None:
        return (
            out.t,
            out.washout_pose,
            out.platform_pose,
            out.clamped,
            out.rate_limited,
            out.held,
            out.phase,
            out.fade,
            out.angles,
            *last,
        )
    acc = st.angular_acceleration
    if acc is None:
        return (
            out.t,
            st.t,
            st.specific_force,
            st.angular_velocity,
            st.attitude,
            out.fresh,
            out.accepted,
            out.washout_pose,
            out.platform_pose,
            out.clamped,
            out.rate_limited,
            out.held,
            out.phase,
            out.fade,
            out.angles,
            *last,
        )
    return (
        out.t,
        st.t,
        st.specific_force,
        st.angular_velocity,
        st.attitude,
        out.fresh,
        out.accepted,
        acc,
        out.washout_pose,
        out.platform_pose,
        out.clamped,
        out.rate_limited,
        out.held,
        out.phase,
        out.fade,
        out.angles,
        *last,
    )


class _Label(str):
    """A placeholder value of a template (encodes as the JSON string ``"@@<name>@@"``)."""

    __slots__ = ()


def _build_template(key: tuple[bool, bool, bool, bool], channel_id) -> tuple[Any, ...]:
    """Template of one kind of tick: (ops, pool, token count); see ``_log_kernels``.

    The messages are built by the very functions of the general path, with a
    labelled placeholder for every value, and encoded by the same encoder, so the
    template reproduces the general path's bytes; the placeholders' order in
    :func:`_tick_values` gives each one's token number.
    """
    has_state, has_acc, planar, static_tf = key
    n = 3 if planar else 6

    def vec(name: str, size: int) -> list[_Label]:
        return [_Label(f"@@{name}{i}@@") for i in range(size)]

    state = None
    if has_state:
        state = SimpleNamespace(
            t=_Label("@@st@@"),
            specific_force=vec("f", 3),
            angular_velocity=vec("w", 3),
            attitude=vec("a", 3),
            angular_acceleration=vec("aa", 3) if has_acc else None,
        )
    fake = SimpleNamespace(
        t=_Label("@@t@@"),
        state=state,
        fresh=_Label("@@fresh@@"),
        accepted=_Label("@@acc@@"),
        washout_pose=vec("wp", 6),
        platform_pose=vec("pp", n),
        clamped=_Label("@@cl@@"),
        angles=vec("q", n),
        servo_deg=vec("sd", 3) if planar else None,
        rate_limited=_Label("@@rl@@"),
        held=_Label("@@held@@"),
        phase=_Label("@@ph@@"),
        fade=_Label("@@fade@@"),
    )
    quat = vec("quat", 4)
    order: list[str] = []
    for leaf in _tick_values(fake, quat):
        order.extend(leaf if isinstance(leaf, list) else [leaf])
    token = {label[2:-2]: k for k, label in enumerate(order)}
    token.update(S=-1, N=-2)
    messages = tick_messages(fake)
    if not planar:
        sec, nsec = _Label("@@S@@"), _Label("@@N@@")
        if static_tf:
            messages.append(
                ("/tf", transform_message(sec, nsec, "world", "base", 0.0, 0.0, 0.0, STATIC_Q))
            )
        pose = fake.platform_pose
        messages.append(("/tf", transform_message(sec, nsec, "base", "platform", *pose[:3], quat)))
    ops: list[tuple[int, int, int]] = []
    pool = bytearray()
    for topic, message in messages:
        ops.append((OP_BEGIN, channel_id(topic), 0))
        parts = _PLACEHOLDER.split(encode_message(message))
        for k, part in enumerate(parts):
            if k % 2 == 0:
                if part:
                    ops.append((OP_LITERAL, len(pool), len(part)))
                    pool += part
            else:
                number = token[part.decode()]
                ops.append(
                    (OP_SEC, 0, 0)
                    if number == -1
                    else (OP_NSEC, 0, 0)
                    if number == -2
                    else (OP_TOKEN, number, 0)
                )
        ops.append((OP_END, 0, 0))
    return (
        np.array(ops, dtype=np.int64),
        np.frombuffer(bytes(pool), dtype=np.uint8),
        len(order),
        len(messages),
    )


_PLACEHOLDER = re.compile(rb'"@@(\w+)@@"')


class PipelineLog:
    """Sink writing every pipeline output to an MCAP file.

    Parameters
    ----------
    path : str or Path
        Output ``.mcap`` file (its folder is created).
    metadata : mapping
        The run's configuration (``PipelineConfig.to_dict()`` plus the source's
        description); stored in the file's ``motionbase`` metadata record.
    health : callable, optional
        Returns the current health counters (a dict) for ``/health``.
    planar : bool, optional
        The robot the outputs come from (True: the 3-RRR in planar mode). When
        given, the encodings of every kind of tick are prepared when the log starts
        instead of at each kind's first tick (about a millisecond each, which would
        make that tick late in a 1 kHz real-time loop).
    """

    def __init__(
        self,
        path: str | Path,
        metadata: Mapping[str, Any],
        health: Callable[[], dict[str, Any]] | None = None,
        *,
        planar: bool | None = None,
    ) -> None:
        self.path = Path(path)
        self._logger = McapLogger(self.path, metadata)
        self._health = health
        self._planar = planar
        self._next_health_t = -math.inf  # the first tick writes /health
        self._last_t = 0.0
        self._templates: dict[tuple[bool, bool, bool, bool], tuple[Any, ...]] = {}

    def __enter__(self) -> PipelineLog:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SinkError(
                f"{self.path}: cannot create the folder {self.path.parent}: "
                f"{exc.strerror or exc} (choose another --out path)"
            ) from None
        self._logger.start()
        if self._planar is not None and _orjson is not None:
            # every kind of tick of this robot: with or without a sample (park ticks),
            # with or without angular acceleration, with or without the static /tf
            for key in ((True, False), (True, True), (False, False)):
                for static in (True, False) if not self._planar else (False,):
                    self._template(self._logger, (*key, self._planar, static))
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Write the final health record and finish the file (idempotent)."""
        if self._logger is None:
            return
        logger, self._logger = self._logger, None
        try:
            if self._health is not None:
                logger.add("/health", self._last_t, {"t": self._last_t, **self._health()})
        finally:
            logger.finish()

    def write(self, out) -> None:
        """Log one :class:`~motionbase.pipeline.PipelineOutput`."""
        t = out.t
        self._last_t = t
        logger = self._logger
        if logger is None or not self._write_fast(logger, out, t):
            self._write_general(logger, out)
        if self._health is not None and t >= self._next_health_t:
            logger.add("/health", t, {"t": t, **self._health()})
            self._next_health_t = t + 1.0

    def _write_fast(self, logger: McapLogger, out, t: float) -> bool:
        """All the tick's messages by one template (False: take the general path).

        The template's bytes are the general path's (the same message builders and
        encoder, see :func:`_build_template`); this only saves the per-message work.
        """
        if _orjson is None or logger._state != "open" or not (0.0 <= t < _MAX_T):
            return False
        ns = round(t * 1e9)  # as McapLogger._ns, whose checks the condition above makes
        st = out.state
        planar = out.servo_deg is not None
        if planar:
            quaternion = ()
            static = False
        else:
            p = out.platform_pose.tolist()
            quaternion = quaternion_from_euler_zyx(p[3], p[4], p[5])
            last = logger._last_static_ns
            static = last < 0 or ns - last >= _SEC
        try:
            values = _orjson.dumps(_tick_values(out, quaternion), option=_ORJSON_NUMPY)
        except TypeError:  # an unusual value: the general path says what is wrong
            return False
        # a NaN or an infinity (orjson writes null): the general path writes it as text
        if b"null" in values:
            return False
        acc = st is not None and st.angular_acceleration is not None
        key = (st is not None, acc, planar, static)
        template = self._templates.get(key) or self._template(logger, key)
        if values.count(b",") + 1 != template[1]:  # not the template's values: general path
            return False
        if static:
            logger.static_transform_due(ns)
        # the writer thread fills the template in (compiled, GIL-free)
        logger.add_deferred(ns, template[0], values, template[2])
        return True

    def _template(
        self, logger: McapLogger, key: tuple[bool, bool, bool, bool]
    ) -> tuple[int, int, int]:
        """Build and register the template of one kind of tick: (id, tokens, messages)."""
        ops, pool, n_tokens, n_messages = _build_template(key, logger.channel_id)
        if n_tokens > MAX_TOKENS:  # more values than the compiled fill takes
            template = (-1, -1, 0)
        else:
            template = (
                logger.register_template(ops, pool, n_tokens, n_messages),
                n_tokens,
                n_messages,
            )
        self._templates[key] = template
        return template

    def _write_general(self, logger: McapLogger | None, out) -> None:
        if logger is None:
            raise SinkError(f"{self.path}: the pipeline log is closed")
        logger.add_many(out.t, tick_messages(out))
        if out.servo_deg is None:
            logger.add_transform(out.t, out.platform_pose)
