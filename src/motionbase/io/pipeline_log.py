"""The MCAP sink of the pipeline: one :class:`PipelineOutput` -> the topics of DESIGN.md.

Topics written per tick (``t`` in seconds, ``log_time`` = ``t`` in ns):

* ``/aircraft/state``: the sample as the source gave it (non-finite numbers kept:
  the logger writes them as strings), with ``fresh`` and ``accepted`` flags, the
  source's own time ``source_t`` and the flight phase ``on_ground`` when the source
  gives one; replays feed it back.
* ``/washout/pose``: the washout output before fades and clamping, with the cueing's
  status (a profiled cueing: ``profile`` and ``profile_weights``).
* 6-RUS: ``/platform/pose`` (after clamping and safety, with ``clamped``,
  ``phase``, ``fade``, ``rate_limited``, ``held``), ``/platform/actuators``
  (crank angles, rad) and a ``foxglove.FrameTransform`` on ``/tf``. A robot plug-in of
  fewer axes logs its own pose there, and ``/tf`` from the cue pose it realises, its
  other axes at neutral (its ``cue_from_pose``).
* planar mode: ``/planar/pose`` and ``/planar/actuators`` (with ``servo_deg``).
* ``/cueing/<name>``: the cueing's own per-tick diagnostics, for a cueing that has them
  (``/cueing/mpc``: solver status, iterations, solve time, fallback, blend weight).
* ``/health``: the safety counters, once per second of source time and at the end.
* ``/platform/scene``: the robot drawn at its logged pose (``foxglove.SceneUpdate``, see
  :mod:`motionbase.io.scene`), when the log is given the robot: at
  :data:`~motionbase.io.scene.SCENE_RATE_HZ` (30 Hz) of source time, not every tick, and at
  the last tick. A scene is about 14 kB of JSON: the tick computes its numbers (the robot's
  compiled ``joint_points``, :meth:`~motionbase.io.scene.SceneBuilder.parts`) and the log's
  writer process builds and encodes the message, as it does ``/tf``'s.

The tick packs its numbers into one record (:func:`motionbase.tick_record.pack`, a few
byte copies); the log's writer process makes these messages from it and encodes them
(:func:`motionbase.tick_record.messages`), off the tick's thread.

With ``live``, a Foxglove WebSocket server (:class:`~motionbase.io.mcap_log.McapLogger`)
also gets every topic above, each message encoded once for both, at most 60 messages per
second of source time per topic (the file keeps every tick).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from motionbase.errors import SinkError
from motionbase.io.mcap_log import LIVE_RATE_HZ, LiveAddress, McapLogger, encode_message
from motionbase.io.scene import SCENE_RATE_HZ, SceneBuilder
from motionbase.io.schemas import CUEING_DIAGNOSTICS, platform_topics
from motionbase.state import PipelineOutput
from motionbase.tick_record import pack


def cueing_schema(cueing: Any) -> tuple[str, Any] | None:
    """(schema name, JSON Schema) of the cueing's diagnostics: the shipped cueings' from
    :data:`~motionbase.io.schemas.CUEING_DIAGNOSTICS`, a plug-in's from its
    :attr:`~motionbase.washout.cueing.Cueing.diagnostics_schema`; None: it has none."""
    if cueing is None:
        return None
    return CUEING_DIAGNOSTICS.get(cueing.name) or getattr(cueing, "diagnostics_schema", None)


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
    robot : Robot, optional
        The robot plug-in the outputs come from: ``/platform/scene`` is written when given,
        and ``/tf`` places the ``platform`` frame at its geometry's ``platform_origin`` plus
        the pose (without a robot, at the pose alone).
    live : LiveAddress, optional
        Also serve every topic to Foxglove over WebSocket while the log is written (at
        most :data:`~motionbase.io.mcap_log.LIVE_RATE_HZ` messages a second per topic).
    live_rate_hz : float
        That rate, messages per second of source time per topic.
    cueing : Cueing, optional
        The pipeline's cueing: its per-tick diagnostics go on ``/cueing/<name>``
        (:func:`cueing_schema`), read right after the tick it describes.
    realtime : bool
        A real-time run: a tick never waits for the log's writer process
        (:class:`~motionbase.io.mcap_log.McapLogger`'s ``realtime``).
    """

    def __init__(
        self,
        path: str | Path,
        metadata: Mapping[str, Any],
        health: Callable[[], dict[str, Any]] | None = None,
        *,
        robot: Any = None,
        live: LiveAddress | None = None,
        live_rate_hz: float = LIVE_RATE_HZ,
        cueing: Any = None,
        realtime: bool = False,
    ) -> None:
        self.path = Path(path)
        schema = cueing_schema(cueing)
        #: the cueing whose diagnostics go on ``/cueing/<name>`` (None: it has no schema)
        self._cueing = cueing if schema is not None else None
        self._cueing_topic = f"/cueing/{cueing.name}" if schema is not None else ""
        topics = {self._cueing_topic: schema} if schema is not None else {}
        self._scene = SceneBuilder(robot) if robot is not None else None
        # a robot of fewer axes than the cue (not planar): the tick record's pose is its
        # own, and /tf is the cue pose it realises with its other axes at neutral
        self._tf_robot = None
        if self._scene is not None and not self._scene.planar:
            axes = len(robot.neutral_pose)
            if axes != 6:
                self._tf_robot = robot
            if (axes, robot.n) != (6, 6):  # its platform topics' schemas, sized to it
                topics.update(platform_topics(axes, robot.n))
        # /tf places the platform frame at its origin (the centroid of its joints, at
        # neutral_height above the base) plus the pose, as the scene draws the platform
        origin = getattr(getattr(robot, "geometry", None), "platform_origin", None)
        self._logger: McapLogger | None = McapLogger(
            self.path,
            metadata,
            live=live,
            live_rate_hz=live_rate_hz,
            realtime=realtime,
            topics=topics,
            platform_origin=origin,
        )
        self._scene_period = 1.0 / SCENE_RATE_HZ
        self._next_scene_t = -math.inf  # the first tick draws the scene
        self._scene_t: float | None = None  # time of the last scene drawn
        self._last_out: Any = None
        self._health = health
        self._next_health_t = -math.inf  # the first tick writes /health
        self._last_t = 0.0

    def __enter__(self) -> PipelineLog:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SinkError(
                f"{self.path}: cannot create the folder {self.path.parent}: "
                f"{exc.strerror or exc} (choose another --out path)"
            ) from None
        assert self._logger is not None
        self._logger.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def live_port(self) -> int | None:
        """The live Foxglove server's port (None without ``live`` or once closed)."""
        return None if self._logger is None else self._logger.live_port

    def close(self) -> None:
        """Write the final health record and finish the file (idempotent)."""
        if self._logger is None:
            return
        logger, self._logger = self._logger, None
        try:
            out = self._last_out
            if out is not None and out.t != self._scene_t:
                self._write_scene(logger, out)  # the last pose (parked), unless just drawn
            if self._health is not None:
                logger.add("/health", self._last_t, {"t": self._last_t, **self._health()})
        finally:
            logger.finish()

    def write(self, out: PipelineOutput) -> None:
        """Log one :class:`~motionbase.state.PipelineOutput`."""
        logger = self._logger
        if logger is None:
            raise SinkError(f"{self.path}: the pipeline log is closed")
        t = out.t
        self._last_t = t
        diagnostics = None if self._cueing is None else self._cueing.diagnostics()
        logger.add_tick(t, pack(out, diagnostics, self._cueing_topic, encode_message))
        if self._tf_robot is not None:
            zero = [0.0] * 6
            logger.add_transform(t, self._tf_robot.cue_from_pose(out.platform_pose, zero))
        if self._scene is not None:
            self._last_out = out
            if t >= self._next_scene_t - 1e-6:  # on a 30 Hz grid of source time (1 us slack)
                self._write_scene(logger, out)
        if self._health is not None and t >= self._next_health_t:
            logger.add("/health", t, {"t": t, **self._health()})
            self._next_health_t = t + 1.0

    def _write_scene(self, logger: McapLogger, out: PipelineOutput) -> None:
        assert self._scene is not None
        t = out.t
        logger.add_scene(t, self._scene.parts(t, out.platform_pose, out.angles, out.clamped))
        self._scene_t = t
        nxt = self._next_scene_t + self._scene_period
        self._next_scene_t = nxt if t < nxt else t + self._scene_period  # none owed after a gap
