"""Teleoperation of the planar 3-RRR robot from a cursor (mouse, eye tracker, file).

Teleop is the pipeline's loop (:func:`motionbase.pipeline.run`) with a cursor source and
the 3-RRR robot in pose mode (:class:`motionbase.commanding.CommandPipeline`): each tick,
cursor pixel -> calibration (metres, phi = 0) -> the robot's clamp toward home into the
valid workspace -> inverse kinematics -> the coordinated approach of far jumps -> the
safety limiter (:func:`motionbase.stages.limit_stage`) -> servo degrees -> serial sink,
logged to MCAP (``/cursor``, ``/planar/pose``, ``/planar/actuators``,
``/platform/scene``, ``/health``). The rules of pose mode (refused targets, the approach,
braking, going home) are in :mod:`motionbase.commanding`; what teleop adds:

* Stale input (``udp`` and ``mouse`` sources): when no new cursor point arrived for
  ``stale_timeout_s`` (tracker lost the eyes, sender stopped, pointer outside the window),
  the source marks its samples not fresh and the robot holds its position (brakes to a stop
  within the limits) until a new point arrives; counted in ``watchdog_fades`` (events) and
  ``stale_ticks``. A file source replays its own timing and has no watchdog.
* Every stop ends the same way, at home and at rest: the end of the input (file end,
  ``duration_s``, window closed or lost), a stop or E-stop (a
  :class:`~motionbase.stopping.StopRequest`: SIGINT, SIGTERM, SIGHUP or SIGQUIT, and
  SIGTSTP with a board, via :func:`motionbase.stopping.install_signal_stop`, Escape/space
  in the mouse window, or a caller) first brake the robot to rest within the speed and
  acceleration limits, then drive it home within them, then the run ends. The cursor is
  ignored from the stop on. When home is not reached within ``max_park_s`` the robot
  brakes to rest where it is. A
  stop asked before the run starts (``teleop_job`` routes the signals before it opens
  anything) sends one home command and ends.
* A failing source or sink (a socket error, a full disk) stops the run the same way,
  through the other sinks, and is raised afterwards, saying where the robot was left.

Loop time is ``k / rate_hz`` for tick ``k``; a file source is looked up by that time and the
serial sink rate-limits on it, so a replay produces the same commands however the loop is
paced (``realtime=True``: the pipeline's loop paces it on the wall clock).
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from motionbase.commanding import Command, CommandPipeline
from motionbase.config import DEFAULT_RRR3, refuse_out_over_inputs
from motionbase.errors import ConfigError, MotionbaseError
from motionbase.io.scene import SCENE_RATE_HZ, SceneBuilder
from motionbase.pipeline import PipelineOutput, check_rate, run
from motionbase.platform.calibration import CursorCalibration
from motionbase.platform.rrr3 import Rrr3, Rrr3Robot
from motionbase.stopping import StopRequest

__all__ = [
    "CursorCommands",
    "TeleopStats",
    "run_teleop",
    "teleop_job",
    "teleop_pipeline",
]


@dataclass
class TeleopStats:
    """Counts of one teleoperation run."""

    ticks: int = 0
    frames_sent: int = 0
    no_input: int = 0  #: ticks before the first cursor sample
    held: int = 0  #: targets refused (the robot braked and held where it was)
    clamps: int = 0  #: targets moved toward home into the workspace
    rate_limited: int = 0  #: ticks on which the target could not be reached in one tick
    safety_trims: int = 0  #: ticks on which the limiter changed the approach command
    park_ticks: int = 0  #: ticks spent braking and going home after the stop (not counted above)
    stale_ticks: int = 0  #: ticks holding position because the input went stale
    watchdog_fades: int = 0  #: times the input went stale
    estops: int = 0  #: stops asked by a key, a signal or the caller
    worst_overrun_s: float = 0.0
    stopped_by: str = "end of input"
    log_lost: bool = False  #: the log (``--out``) was removed while it was written

    @classmethod
    def of(cls, pipeline: CommandPipeline, **more: Any) -> TeleopStats:
        h = pipeline.health
        return cls(
            ticks=h.samples, no_input=pipeline.no_input, held=h.unsafe_commands,
            clamps=h.clamps, rate_limited=h.rate_limited, safety_trims=pipeline.trims,
            park_ticks=pipeline.park_ticks, stale_ticks=pipeline.stale_ticks,
            watchdog_fades=h.watchdog_fades, worst_overrun_s=h.worst_overrun_s, **more,
        )  # fmt: skip

    def as_health(self) -> dict[str, Any]:
        health = {**asdict(self), "rejected_inputs": self.held}
        del health["log_lost"]  # (known only once the log is closed)
        return health


class CursorCommands(Iterator[Command]):
    """A cursor source as the pipeline's source of robot poses ``[x, y, 0]``.

    Tick ``k`` (loop time ``k / rate_hz``) reads the cursor and maps its pixel through the
    calibration; the sample's ``info`` is ``(pixel, (x, y))``. It ends when the cursor
    does (``ended``: the cursor's ``ended`` if it says why, else ``"end of input"``) or
    after ``duration_s`` (``"duration"``). A live cursor (``watchdog``) marks its samples
    not ``fresh`` when its latest new point is older than ``stale_timeout_s``.
    """

    def __init__(
        self,
        cursor: Any,
        calibration: CursorCalibration,
        *,
        rate_hz: float,
        duration_s: float | None = None,
        stale_timeout_s: float = 0.5,
    ) -> None:
        if not (math.isfinite(stale_timeout_s) and stale_timeout_s > 0):
            raise ConfigError(f"teleop: stale timeout must be > 0 s, got {stale_timeout_s!r}")
        self.cursor = cursor
        self.calibration = calibration
        self.dt = 1.0 / rate_hz
        self.duration_s = duration_s
        self.stale_timeout_s = stale_timeout_s
        self.watched = bool(getattr(cursor, "watchdog", False))
        self.fresh = True
        self.ended = ""
        self._k = 0

    def __next__(self) -> Command:
        t = self._k * self.dt
        if self.duration_s is not None and t > self.duration_s + 1e-9:
            self.ended = "duration"
            raise StopIteration
        if self.cursor.finished(t):
            self.ended = getattr(self.cursor, "ended", "") or "end of input"
            raise StopIteration
        pixel = self.cursor.read(t)
        self._k += 1
        if pixel is None:
            return Command(t, None)
        x, y = self.calibration.map_one(pixel[0], pixel[1])
        if self.watched:
            updated = getattr(self.cursor, "updated_t", None)
            self.fresh = not (updated is None or t - updated > self.stale_timeout_s + 1e-9)
        return Command(t, np.array([x, y, 0.0]), (tuple(pixel), (x, y)))


def _cursor_used(out: PipelineOutput) -> tuple[Any, Any] | None:
    """The (pixel, target) of a tick that followed the cursor (not while parking)."""
    if out.phase not in ("starting", "running") or out.state is None:
        return None
    return out.state.info


class _ServoSink:
    """The serial link (``write(servo_deg, t=loop time) -> sent``) as a pipeline sink."""

    def __init__(self, link: Any) -> None:
        self.link = link
        self.label = getattr(link, "url", None) or type(link).__name__
        self.frames_sent = 0
        self.failed = False  # (then the robot is where its last frame put it)

    def write(self, out: PipelineOutput) -> None:
        try:
            sent = self.link.write([int(d) for d in out.servo_deg], t=out.t)
        except Exception:
            self.failed = True
            raise
        self.frames_sent += bool(sent)


class _TeleopLog:
    """Teleop's topics, to a logger with ``add(topic, t, message)``."""

    label = "MCAP log"

    def __init__(self, logger: Any, robot: Rrr3Robot, rate_hz: float, stats: Any) -> None:
        self.logger = logger
        self.scene = SceneBuilder(robot)
        self.scene_every = max(1, round(rate_hz / SCENE_RATE_HZ))
        self.health_every = max(1, int(round(rate_hz)))
        self.stats = stats  # () -> TeleopStats
        self._k = 0

    def write(self, out: PipelineOutput) -> None:
        add, t, k = self.logger.add, out.t, self._k
        used = _cursor_used(out)
        if used is not None:
            add("/cursor", t, {"pixel": list(used[0]), "target": list(used[1])})
        add("/planar/pose", t, {"pose": out.platform_pose.tolist()})
        add(
            "/planar/actuators", t,
            {"angles": out.angles.tolist(), "servo_deg": [int(d) for d in out.servo_deg]},
        )  # fmt: skip
        if k % self.scene_every == 0:  # the robot drawn for Foxglove, about 30 Hz
            add("/platform/scene", t, self.scene.message(t, out.platform_pose, out.angles))
        if k % self.health_every == 0:
            add("/health", t, self.stats().as_health())
        self._k += 1


class _Window:
    """The mouse window's drawing of the robot, as a pipeline sink."""

    label = "mouse window"

    def __init__(self, cursor: Any, rrr3: Rrr3, stop: StopRequest) -> None:
        self.cursor, self.rrr3, self.stop = cursor, rrr3, stop

    def write(self, out: PipelineOutput) -> None:
        used = _cursor_used(out)
        self.cursor.show(
            points=self.rrr3.joint_points(out.platform_pose, angles=out.angles),
            target=None if used is None else used[1],
            held=out.held,
            parking=out.phase not in ("starting", "running") and bool(self.stop),
        )


def teleop_pipeline(
    rrr3: Rrr3, *, rate_hz: float = 50.0, clamp: bool = True, max_park_s: float = 10.0
) -> CommandPipeline:
    """The pipeline teleop runs: the 3-RRR in pose mode (see :func:`run_teleop`); a rate
    it cannot tick at is a ConfigError (:func:`motionbase.pipeline.check_rate`)."""
    return CommandPipeline(
        Rrr3Robot(rrr3.geometry), rate_hz=rate_hz, mode="poses", clamp=clamp,
        max_home_s=max_park_s,
    )  # fmt: skip


def run_teleop(
    source: Any,
    rrr3: Rrr3,
    calibration: CursorCalibration,
    *,
    sink: Any = None,
    logger: Any = None,
    rate_hz: float = 50.0,
    duration_s: float | None = None,
    realtime: bool = True,
    clamp: bool = True,
    stop: StopRequest | None = None,
    stale_timeout_s: float = 0.5,
    max_park_s: float = 10.0,
    pipeline: CommandPipeline | None = None,
) -> TeleopStats:
    """Teleoperate until the source ends, ``duration_s`` passes or a stop; then brake to
    rest and go home, within the limits (see the module docstring).

    Parameters
    ----------
    source : cursor source
        From :mod:`motionbase.io.cursor_input` (opened by the caller). A source with a true
        ``watchdog`` attribute reports ``updated_t`` (loop time of its latest new point, s).
    rrr3 : Rrr3
        The robot; its geometry's ``max_speed`` (rad/s) and ``max_accel`` (rad/s^2) and its
        servo ranges are the limiter's limits.
    calibration : CursorCalibration
        Pixels -> metres; the orientation is kept at phi = 0 (as in the thesis).
    sink : ServoSerialSink, optional
        Opened by the caller; receives ``write(servo_deg, t=loop_time)`` every tick.
    logger : McapLogger, optional
        Started by the caller.
    rate_hz : float
        Loop rate, Hz (10 Hz or more).
    duration_s : float, optional
        Stop after this much loop time, s.
    realtime : bool
        The pipeline's loop paces the ticks on the wall clock; False runs as fast as possible.
    clamp : bool
        Clamp unreachable targets toward home; when False they are held instead.
    stop : StopRequest, optional
        Raised (by a signal, a key or a test) to stop: brake to rest, go home, then return.
    stale_timeout_s : float
        Watchdog: hold position when a watched source gave no new point for this long, s.
    max_park_s : float
        Longest time given to braking and going home after the stop, s.
    pipeline : CommandPipeline, optional
        Made by :func:`teleop_pipeline` with the same settings beforehand (its kernels load
        then, not after a mouse window opened).

    Returns
    -------
    TeleopStats
    """
    stop = stop if stop is not None else StopRequest()
    if hasattr(source, "bind_stop"):
        source.bind_stop(stop)
    if pipeline is None:
        pipeline = teleop_pipeline(rrr3, rate_hz=rate_hz, clamp=clamp, max_park_s=max_park_s)
    robot = pipeline.robot
    commands = CursorCommands(
        source, calibration, rate_hz=rate_hz, duration_s=duration_s,
        stale_timeout_s=stale_timeout_s,
    )  # fmt: skip
    servo = _ServoSink(sink) if sink is not None else None
    sinks: list[Any] = [] if servo is None else [servo]
    if logger is not None:
        sinks.append(_TeleopLog(logger, robot, rate_hz, lambda: TeleopStats.of(pipeline)))
    if hasattr(source, "view"):
        sinks.append(_Window(source, rrr3, stop))

    # the pipeline gives up going home after max_park_s and brakes to rest (a few tenths of
    # a second at most): the loop's own bound is only a backstop
    try:
        summary = run(
            pipeline, commands, sinks, paced=realtime, stop=stop, max_park_s=max_park_s + 10.0
        )
    except MotionbaseError as exc:
        cause = exc.__cause__
        if not isinstance(cause, MotionbaseError):
            raise
        # one clear line, saying where the robot was left
        home = np.array_equal(pipeline.command, robot.park_angles) and not pipeline.speed.any()
        where = "parked at home" if home else "stopped at rest"
        if servo is not None and servo.failed:  # parked in the log only
            where = "not parked: it was left where the last command the board got put it"
        raise type(cause)(f"{cause} (the robot was {where})") from cause
    stopped_by = summary.stopped_by  # the commands' end: "duration" or "end of input"
    asked = bool(stop) and stopped_by.startswith(stop.reason) and "failure" not in stop.reason
    result = TeleopStats.of(
        pipeline, frames_sent=servo.frames_sent if servo is not None else 0,
        estops=int(asked), stopped_by=stopped_by,
    )  # fmt: skip
    if logger is not None:  # (a sink that failed, the log too, made run raise above)
        logger.add("/health", max(0.0, float(pipeline.state[0]["t"])), result.as_health())
    return result


def teleop_job(
    input_spec: str = "mouse",
    *,
    serial_url: str | None = None,
    calibration_path: str | None = None,
    rate_hz: float = 50.0,
    out: str | None = None,
    duration_s: float | None = None,
    geometry: str = DEFAULT_RRR3,
    realtime: bool = True,
    clamp: bool = True,
    stale_timeout_s: float = 0.5,
    stop: StopRequest | None = None,
    live: str | None = None,
    deadband_px: float = 0.0,
    screen_px: tuple[int, int] | None = None,
) -> TeleopStats:
    """The ``motionbase teleop`` command: build source, calibration, sink and log; run.

    Without ``calibration_path`` the mouse window uses its own view (the target sits under
    the pointer) and file/UDP input maps their screen (1310 x 715 px unless the source says
    otherwise) onto the largest valid rectangle at phi = 0 (:meth:`CursorCalibration.default`).
    SIGINT, SIGTERM, SIGHUP, SIGQUIT and, with a board, SIGTSTP (Ctrl-Z) stop the robot
    (brake, then home, within the limits), from the start of this call on: during start-up
    too. ``live`` (``[HOST:]PORT``) also serves the log's topics to Foxglove while running
    (needs ``out``). With a ``serial_url`` the run is paced in real time whatever
    ``realtime`` says: the board's servos are motors, and move in real time only (as
    ``stream``'s ``serial``). ``deadband_px``: UDP input ignores points closer than this to
    the one in use, pixels (:class:`~motionbase.io.cursor_input.UdpCursor`); ``screen_px``:
    the source's screen (or window) size, pixels, for the default calibration.
    """
    from motionbase.config import resolve_preset_or_path
    from motionbase.io.cursor_input import open_cursor_source
    from motionbase.io.mcap_log import LiveAddress, McapLogger
    from motionbase.platform.rrr3_geometry import Rrr3Geometry
    from motionbase.stopping import install_signal_stop, stop_signals_for

    if live is not None and out is None:
        raise ConfigError("--live serves the run's log: add --out FILE.mcap")
    check_rate(rate_hz, "teleop --rate")  # (the user's option, not "command pipeline")
    if out is not None:
        refuse_out_over_inputs(
            out,
            ("--input", input_spec[5:] if input_spec.startswith("file:") else None),
            ("--calibration", calibration_path),
            ("--rrr3", geometry),
        )
    live_at = None if live is None else LiveAddress.parse(live)
    stop = stop if stop is not None else StopRequest()
    sink = logger = None
    with contextlib.ExitStack() as cleanup:  # (undone in reverse: the log, the link, the signals)
        drives = serial_url not in (None, "none")  # (Ctrl-Z stops the board's servos too)
        # first: a stop during start-up parks too
        cleanup.callback(install_signal_stop(stop, stop_signals_for(drives)))
        rrr3 = Rrr3(Rrr3Geometry.from_toml(resolve_preset_or_path("rrr3", geometry)))
        pipeline = teleop_pipeline(rrr3, rate_hz=rate_hz, clamp=clamp)  # before the window
        source = open_cursor_source(input_spec, rrr3, stale_timeout_s, deadband_px, screen_px)
        with source:
            if calibration_path is not None:
                cal = CursorCalibration.from_toml(calibration_path)
            elif hasattr(source, "unview"):
                w, h = source.size_px
                px = np.array([[u, v] for u in (0, w / 2, w) for v in (0, h / 2, h)], dtype=float)
                cal = CursorCalibration.fit(px, source.unview(px))
            else:
                cal = CursorCalibration.default(rrr3, *source.size_px)
            if drives:
                from motionbase.io.serial_link import ServoSerialSink

                sink = ServoSerialSink(serial_url, rate_hz=rate_hz).open()
                cleanup.callback(sink.close)
                realtime = True  # the board's servos move in real time only
            if out is not None:
                logger = McapLogger(
                    out,
                    {
                        "mode": "teleop",
                        "rate_hz": rate_hz,
                        "geometry": rrr3.geometry.to_dict(),
                        "calibration": cal.to_dict(),
                        "input": source.describe(),
                        "serial": sink.describe() if sink is not None else None,
                        "clamp": clamp,
                        "stale_timeout_s": stale_timeout_s,
                    },
                    live=live_at,
                    realtime=realtime,  # a tick never waits for the log's writer
                ).start()
                cleanup.callback(logger.finish)
                if live_at is not None:
                    print(live_at.banner(logger.live_port), file=sys.stderr, flush=True)
            stats = run_teleop(
                source, rrr3, cal, sink=sink, logger=logger, rate_hz=rate_hz,
                duration_s=duration_s, realtime=realtime, clamp=clamp, stop=stop,
                stale_timeout_s=stale_timeout_s, pipeline=pipeline,
            )  # fmt: skip
    # a log removed while it was written (its folder deleted): the writer went on into a
    # file without a name, so nothing of the run was kept (as fly, replay and stream say)
    if out is not None and not Path(out).exists():
        stats.log_lost = True
        logging.getLogger("motionbase").warning(
            "log %s is gone: it or its folder was removed during the run, so nothing of the "
            "run was kept (the run itself ended as usual, at home)",
            out,
        )
    return stats
