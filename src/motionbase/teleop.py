"""Teleoperation of the planar 3-RRR robot from a cursor (mouse, eye tracker, file).

Each tick of a fixed-rate loop: cursor pixel -> calibration (metres) -> clamp toward home into
the valid workspace -> inverse kinematics -> the safety stage
(:func:`motionbase.safety.limit_command`: finite, inside the servo ranges, within the joint
speed and acceleration limits) -> servo degrees -> serial sink, logged to MCAP (``/cursor``,
``/planar/pose``, ``/planar/actuators``, ``/health``).

Rules
-----
* A target that is still invalid after clamping (non-finite, unreachable, singular, out of
  servo range; or any target when clamping is off) is never sent: it is counted (``held``)
  and the robot brakes to rest where it is (below).
* Joint angles are expressed inside each servo's interval (:attr:`Rrr3.angle_limits`), the
  space in which the safety stage checks the limits; the servo degrees sent are always
  ``rrr3.to_servo(q)`` of the safety stage's output ``q``.
* Coordinated motion: a parallel robot's joints must move together (three independently
  limited servos leave the mechanism unassemblable during a large jump). When the safety
  stage cannot reach the target in one tick, the target it is given is a point of the straight
  pose segment from the current pose toward the cursor target, advanced by the safety stage's
  own speed/acceleration/braking law applied to the joint-space distance
  (:func:`motionbase.safety.limit_command` on one virtual axis, at 80 % of the limits), so
  the joints stay on the inverse kinematics of a pose. The limits themselves are enforced
  only by the safety stage, which every command passes through.
* ``/planar/pose`` is the pose the servos realise: the target pose when the safety stage sent
  it unchanged, else forward kinematics of the command with the previous pose as guess.
* Stale input (``udp`` and ``mouse`` sources): when no new cursor point arrived for
  ``stale_timeout_s`` (tracker lost the eyes, sender stopped, pointer outside the window),
  the robot holds its position (brakes to a stop within the limits) until a new point
  arrives; counted in ``watchdog_fades`` (events) and ``stale_ticks``. A file source replays
  its own timing and has no watchdog.
* Braking: whenever the robot must stop where it is (a refused target, stale or no input, a
  stop) every joint's speed is scaled down by one factor per tick, so the joints decelerate
  within ``max_accel``, come to rest together and keep to the direction they were moving in;
  the command still passes the safety stage.
* Every stop ends the same way, at home and at rest: the end of the input (file end,
  ``duration_s``, window closed) and an E-stop (a :class:`~motionbase.pipeline.StopRequest`:
  SIGINT, SIGTERM, SIGHUP or SIGQUIT via :func:`motionbase.stopping.install_signal_stop`,
  Escape/space in the mouse window, or a caller) first brake the robot to rest within the
  speed and acceleration limits, then drive it home within them (the coordinated approach
  above, from rest), then the loop ends. Home, not where the input left it, because the next
  run's first tick sends home: a robot left elsewhere would jump there. The cursor is ignored
  from the stop on. When home is not reached within ``max_park_s`` the robot brakes to rest
  where it is. A stop asked before the loop starts (``teleop_job`` routes the signals before
  it opens anything) sends the first tick's home command and ends. The first tick of every
  run sends home (keep the robot near home when powering up).
* A failing source or log (a socket error, a full disk) stops the run the same way, through
  the serial sink, and is raised afterwards (a failing serial sink is the robot itself gone:
  raised at once).

Loop time is ``k / rate_hz`` for tick ``k``; a file source is looked up by that time and the
serial sink rate-limits on it, so a replay produces the same commands however the loop is
paced (``realtime=True`` sleeps to wall-clock time, never busy-waits).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from motionbase.config import DEFAULT_RRR3
from motionbase.errors import ConfigError, MotionbaseError
from motionbase.io.scene import SCENE_RATE_HZ, SceneBuilder
from motionbase.pipeline import StopRequest
from motionbase.platform.calibration import CursorCalibration
from motionbase.platform.rrr3 import OK, Rrr3
from motionbase.safety import RATE_LIMITED, UNSAFE_TARGET, ActuatorLimits, limit_command

__all__ = ["DEFAULT_GEOMETRY", "TeleopStats", "run_teleop", "teleop_job"]

#: The planar robot teleop and the planar pipeline drive unless told otherwise
#: (:data:`motionbase.config.DEFAULT_RRR3`, one default for every command).
DEFAULT_GEOMETRY = DEFAULT_RRR3

# Phases of the loop: following the cursor; braking to rest after a stop or the end of the
# input; going home from rest; braking to rest where it is when home was not reached within
# ``max_park_s``; stopped at rest after that time ran out while braking.
_RUN, _BRAKE, _HOME, _BRAKE_LAST, _DONE = range(5)


@dataclass
class TeleopStats:
    """Counts of one teleoperation run."""

    ticks: int = 0
    frames_sent: int = 0
    no_input: int = 0  #: ticks before the first cursor sample
    held: int = 0  #: targets refused (the last safe command was held)
    clamps: int = 0  #: targets moved toward home into the workspace
    rate_limited: int = 0  #: ticks on which the target could not be reached in one tick
    safety_trims: int = 0  #: ticks on which the safety stage changed the command it was given
    park_ticks: int = 0  #: ticks spent braking and going home after the stop (not counted above)
    stale_ticks: int = 0  #: ticks holding position because the input went stale
    watchdog_fades: int = 0  #: times the input went stale
    estops: int = 0
    worst_overrun_s: float = 0.0
    stopped_by: str = "end of input"

    def as_health(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(rejected_inputs=self.held)
        return d


class _Limiter:
    """The safety stage for the robot, plus the coordinated approach toward a far target."""

    def __init__(self, rrr3: Rrr3, dt: float) -> None:
        self.rrr3 = rrr3
        self.dt = dt
        lim = rrr3.angle_limits
        g = rrr3.geometry
        self.lower = np.ascontiguousarray(lim[:, 0])
        self.limits = ActuatorLimits.broadcast(3, lim[:, 0], lim[:, 1], g.max_speed, g.max_accel)
        # one virtual axis: progress along the path in joint radians (max norm), planned at
        # 80 % of the limits so that the joint path's curvature seldom makes the safety stage
        # trim (150 random jumps across the phi = 0 workspace of either preset: no tick left
        # the mechanism unassemblable or singular; the safety stage trimmed < 2 % of ticks)
        m = 0.8
        self.path_limits = ActuatorLimits.broadcast(1, -1e3, 1e3, m * g.max_speed, m * g.max_accel)
        self._zero = np.zeros(1)

    def angles(self, pose: tuple[float, float, float]) -> np.ndarray | None:
        """Joint angles inside the servo intervals, or None when the pose is not valid."""
        st, theta, _ = self.rrr3.solve_one(*pose)
        if st != OK:
            return None
        return self.lower + np.mod(theta - self.lower, 2 * np.pi)

    def path_step(self, distance: float, speed: float) -> float:
        """Joint-space progress (rad) allowed this tick toward a target ``distance`` away."""
        d = np.array([distance])  # a fixed target: no feed-forward
        s, _, _ = limit_command(self._zero, np.array([speed]), d, d, self.dt, self.path_limits)
        return float(s[0])

    def along(self, pose, goal, q, step: float, n_iter: int = 16):
        """The point of the pose segment ``pose -> goal`` whose joints lie ``step`` rad (max
        norm) from ``q``, by bisection on the fraction (the inverse kinematics is not linear);
        ``(pose, angles)`` or None when the segment start is already invalid."""
        lo, hi = 0.0, 1.0
        best = None
        for _ in range(n_iter):
            f = 0.5 * (lo + hi)
            cand = tuple(p + f * (g - p) for p, g in zip(pose, goal, strict=True))
            qc = self.angles(cand)
            if qc is not None and float(np.max(np.abs(qc - q))) <= step:
                lo, best = f, (cand, qc)
            else:
                hi = f
        return best

    def brake(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """The next command of a coordinated stop, through the safety stage.

        Every joint's speed is scaled by one factor, so that all joints come to rest together
        in the shortest time the slowest-braking joint allows (``max(|v| / max_accel)``): each
        decelerates by at most its ``max_accel``, and the joints keep moving in the direction
        they had (the mechanism stays on its path). Returns ``(q, v, status)`` as
        :func:`~motionbase.safety.limit_command` does.
        """
        t_stop = float(np.max(np.abs(v) / self.limits.max_accel))  # s
        scale = max(0.0, 1.0 - self.dt / t_stop) if t_stop > 0.0 else 0.0
        return self(q, v, q, q + scale * v * self.dt)

    def __call__(self, q, v, q_target_prev, q_target):
        return limit_command(q, v, q_target_prev, q_target, self.dt, self.limits)


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
) -> TeleopStats:
    """Run the teleoperation loop until the source ends, ``duration_s`` passes or a stop; then
    brake to rest and go home, within the limits (see the module docstring).

    Parameters
    ----------
    source : cursor source
        From :mod:`motionbase.io.cursor_input` (opened by the caller). A source with a true
        ``watchdog`` attribute reports ``updated_t`` (loop time of its latest new point, s).
    rrr3 : Rrr3
        The robot; its geometry's ``max_speed`` (rad/s) and ``max_accel`` (rad/s^2) and its
        servo ranges are the safety stage's limits.
    calibration : CursorCalibration
        Pixels -> metres; the orientation is kept at phi = 0 (as in the thesis).
    sink : ServoSerialSink, optional
        Opened by the caller; receives ``write(servo_deg, t=loop_time)`` every tick.
    logger : McapLogger, optional
        Started by the caller.
    rate_hz : float
        Loop rate, Hz.
    duration_s : float, optional
        Stop after this much loop time, s.
    realtime : bool
        Pace the loop to wall-clock time (sleep); False runs as fast as possible.
    clamp : bool
        Clamp unreachable targets toward home; when False they are held instead.
    stop : StopRequest, optional
        Raised (by a signal, a key or a test) to E-stop: brake to rest, go home, then return.
    stale_timeout_s : float
        Watchdog: hold position when a watched source gave no new point for this long, s.
    max_park_s : float
        Longest time given to braking and going home after a stop, s.

    Returns
    -------
    TeleopStats
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f"teleop: rate must be > 0 Hz, got {rate_hz!r}")
    if not (math.isfinite(stale_timeout_s) and stale_timeout_s > 0):
        raise ConfigError(f"teleop: stale timeout must be > 0 s, got {stale_timeout_s!r}")
    dt = 1.0 / rate_hz
    stop = stop if stop is not None else StopRequest()
    if hasattr(source, "bind_stop"):
        source.bind_stop(stop)
    limiter = _Limiter(rrr3, dt)
    scene = SceneBuilder(rrr3)
    scene_every = max(1, round(rate_hz / SCENE_RATE_HZ))
    stats = TeleopStats()
    pose = rrr3.home.copy()
    home_q = limiter.angles(tuple(pose))
    if home_q is None:  # Rrr3 refuses such geometries already
        raise ConfigError("teleop: home pose is not valid")
    q = home_q.copy()
    v = np.zeros(3)
    q_target_prev = q.copy()  # the last goal's angles (the safety stage feeds its speed forward)
    watched = bool(getattr(source, "watchdog", False))
    stale = False
    phase = _RUN
    park_end = math.inf
    wants_show = hasattr(source, "view")
    fault: Exception | None = None  # a failing source or log: park first, then raise it
    source_ok = True
    start = time.monotonic()
    k = 0
    while True:
        t = k * dt
        at_rest = not v.any()
        if phase == _RUN:
            why = ""
            if fault is not None:
                why = f"error: {fault}"
            elif stop:
                stats.estops += 1
                why = stop.reason or "stop"
            elif duration_s is not None and t > duration_s + 1e-9:
                why = "duration"
            elif source.finished(t):
                why = "end of input"
            if why:  # brake to rest, then home
                stats.stopped_by = why
                phase = _BRAKE
                park_end = t + max_park_s
        if phase == _BRAKE and at_rest:
            phase = _HOME if t <= park_end else _DONE
            q_target_prev = q  # from rest: no speed to feed forward
        if phase == _HOME and t > park_end:
            phase = _BRAKE_LAST  # home not reached in time: come to rest where it is
        if (phase == _HOME and at_rest and np.array_equal(q, home_q) and k > 0) or (
            phase in (_BRAKE_LAST, _DONE) and at_rest
        ):
            break
        if realtime:
            lag = time.monotonic() - (start + t)
            if lag < 0:
                time.sleep(-lag)
            else:
                stats.worst_overrun_s = max(stats.worst_overrun_s, lag)
        # read every tick (the mouse window handles its events in read), use only while running
        pixel = None
        if source_ok:
            try:
                if phase == _RUN or not source.finished(t):
                    pixel = source.read(t)
            except Exception as exc:  # parks first (the robot brakes at once), raised at the end
                fault, source_ok = fault or exc, False
        target_xy: tuple[float, float] | None = None
        goal: tuple[float, float, float] | None = None  # valid target pose
        refused = False
        if phase == _HOME:
            goal = tuple(rrr3.home)
        elif phase != _RUN:
            pass  # braking to rest
        elif pixel is None:
            stats.no_input += 1
        else:
            x, y = calibration.map_one(pixel[0], pixel[1])
            target_xy = (x, y)
            cand = (x, y, 0.0)
            if clamp and math.isfinite(x) and math.isfinite(y):
                cx, cy, cp, moved = rrr3.clamp_one(x, y, 0.0)
                if moved:
                    stats.clamps += 1
                cand = (cx, cy, cp)
            if limiter.angles(cand) is None:
                refused = True
                stats.held += 1
            else:
                goal = cand
            if watched:
                updated = getattr(source, "updated_t", None)
                now_stale = updated is None or t - updated > stale_timeout_s + 1e-9
                if now_stale and not stale:
                    stats.watchdog_fades += 1
                stale = now_stale
                if stale:
                    stats.stale_ticks += 1
                    goal = None

        # the safety stage: the goal's angles, or braking to rest (refused target, stale or no
        # input, a stop)
        if goal is None:
            q_new, v_new, status = limiter.brake(q, v)
            new_pose = pose if np.array_equal(q_new, q) else None
            q_target_prev = q_new
        else:
            wanted = limiter.angles(goal)
            goal_q = wanted
            q_new, v_new, status = limiter(q, v, q_target_prev, wanted)
            new_pose = goal
            counted = phase == _RUN  # the counts describe following the cursor, not parking
            if status & UNSAFE_TARGET:  # valid by status, yet a hair outside a servo interval
                stats.held += counted
                wanted = q_new
            elif status & RATE_LIMITED:
                # too far for one tick: approach along the pose segment, joints coordinated
                stats.rate_limited += counted
                dist = float(np.max(np.abs(wanted - q)))
                step = limiter.path_step(dist, float(np.max(np.abs(v))))
                if 0.0 < step < dist:  # else braking or overshooting: the safety stage's output
                    found = limiter.along(pose, goal, q, step)
                    if found is not None:
                        new_pose, wanted = found
                        q_new, v_new, status = limiter(q, v, q, wanted)
                    # else the segment leaves the valid region: the safety stage's own approach
                if status != 0:
                    stats.safety_trims += counted
            q_target_prev = goal_q if not status & UNSAFE_TARGET else q_new
            if not np.array_equal(q_new, wanted):
                new_pose = None
        if new_pose is None:
            # the servos realise another pose than the one asked: say which
            achieved = rrr3.forward(q_new, guess=pose)
            new_pose = achieved if np.isfinite(achieved).all() else pose
        pose = np.asarray(new_pose, dtype=float)
        q, v = q_new, v_new
        servo = [int(d) for d in rrr3.to_servo(q)]
        if sink is not None:
            if sink.write(servo, t=t):
                stats.frames_sent += 1
        if logger is not None:
            try:
                if target_xy is not None:  # a cursor sample that was used (not while parking)
                    logger.add("/cursor", t, {"pixel": list(pixel), "target": list(target_xy)})
                logger.add("/planar/pose", t, {"pose": pose.tolist()})
                logger.add("/planar/actuators", t, {"angles": q.tolist(), "servo_deg": servo})
                if k % scene_every == 0:  # the robot drawn for Foxglove, about 30 Hz
                    logger.add("/platform/scene", t, scene.message(t, pose, q))
                if k % max(1, int(round(rate_hz))) == 0:
                    logger.add("/health", t, stats.as_health())
            except Exception as exc:  # a full disk: park without the log, then raise
                fault, logger = fault or exc, None
        if wants_show and source_ok:
            try:
                source.show(
                    points=rrr3.joint_points(pose, angles=q),
                    target=target_xy,
                    held=refused or stale,
                    parking=phase != _RUN and bool(stop),
                )
            except Exception as exc:
                fault, source_ok = fault or exc, False
        stats.ticks += 1
        stats.park_ticks += phase != _RUN
        k += 1
    if logger is not None:
        logger.add("/health", max(0.0, (k - 1) * dt), stats.as_health())
    if fault is not None:
        if isinstance(fault, MotionbaseError):  # one clear line, saying where the robot is
            where = "parked at home" if np.array_equal(q, home_q) else "stopped at rest"
            raise type(fault)(f"{fault} (the robot was {where})") from fault
        raise fault
    return stats


def teleop_job(
    input_spec: str = "mouse",
    *,
    serial_url: str | None = None,
    calibration_path: str | None = None,
    rate_hz: float = 50.0,
    out: str | None = None,
    duration_s: float | None = None,
    geometry: str = DEFAULT_GEOMETRY,
    realtime: bool = True,
    clamp: bool = True,
    stale_timeout_s: float = 0.5,
    stop: StopRequest | None = None,
    live: str | None = None,
) -> TeleopStats:
    """The ``motionbase teleop`` command: build source, calibration, sink and log; run.

    Without ``calibration_path`` the mouse window uses its own view (the target sits under
    the pointer) and file/UDP input maps their screen (1310 x 715 px unless the source says
    otherwise) onto the largest valid rectangle at phi = 0 (:meth:`CursorCalibration.default`).
    SIGINT, SIGTERM, SIGHUP and SIGQUIT stop the robot (brake, then home, within the limits),
    from the start of this call on: during start-up too. ``live`` (``[HOST:]PORT``) also
    serves the log's topics to Foxglove while running (needs ``out``).
    """
    from motionbase.config import resolve_preset_or_path
    from motionbase.io.cursor_input import open_cursor_source
    from motionbase.io.mcap_log import LiveAddress
    from motionbase.platform.rrr3_geometry import Rrr3Geometry
    from motionbase.stopping import install_signal_stop

    if live is not None and out is None:
        raise ConfigError("--live serves the run's log: add --out FILE.mcap")
    live_at = None if live is None else LiveAddress.parse(live)
    stop = stop if stop is not None else StopRequest()
    restore = install_signal_stop(stop)  # first: a stop during start-up parks too
    sink = None
    logger = None
    try:
        rrr3 = Rrr3(Rrr3Geometry.from_toml(resolve_preset_or_path("rrr3", geometry)))
        source = open_cursor_source(input_spec, rrr3)
        with source:
            if calibration_path is not None:
                cal = CursorCalibration.from_toml(calibration_path)
            elif hasattr(source, "unview"):
                w, h = source.size_px
                px = np.array([[u, v] for u in (0, w / 2, w) for v in (0, h / 2, h)], dtype=float)
                cal = CursorCalibration.fit(px, source.unview(px))
            else:
                cal = CursorCalibration.default(rrr3, *source.size_px)
            if serial_url not in (None, "none"):
                from motionbase.io.serial_link import ServoSerialSink

                sink = ServoSerialSink(serial_url, rate_hz=rate_hz).open()
            if out is not None:
                from motionbase.io.mcap_log import McapLogger

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
                ).start()
                if live_at is not None:
                    print(live_at.banner(logger.live_port), file=sys.stderr, flush=True)
            return run_teleop(
                source, rrr3, cal, sink=sink, logger=logger, rate_hz=rate_hz,
                duration_s=duration_s, realtime=realtime, clamp=clamp, stop=stop,
                stale_timeout_s=stale_timeout_s,
            )  # fmt: skip
    finally:
        try:
            if logger is not None:
                logger.finish()
        finally:
            if sink is not None:
                sink.close()
            restore()
