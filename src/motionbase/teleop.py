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
  and the safety stage holds the last safe command (it brakes to a stop within the limits).
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
* E-stop (a :class:`~motionbase.pipeline.StopRequest`: SIGINT/SIGTERM via
  :func:`~motionbase.pipeline.install_signal_stop`, or Escape/space in the mouse window):
  the cursor is ignored and the robot goes home within the limits, then the loop ends.
  The end of the input (file end, ``duration_s``, window closed) just stops the loop where the
  robot is. The first tick sends home (keep the robot near home when powering up).

Loop time is ``k / rate_hz`` for tick ``k``; a file source is looked up by that time and the
serial sink rate-limits on it, so a replay produces the same commands however the loop is
paced (``realtime=True`` sleeps to wall-clock time, never busy-waits).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from motionbase.config import DEFAULT_RRR3
from motionbase.errors import ConfigError
from motionbase.pipeline import StopRequest, install_signal_stop
from motionbase.platform.calibration import CursorCalibration
from motionbase.platform.rrr3 import OK, Rrr3
from motionbase.safety import RATE_LIMITED, UNSAFE_TARGET, ActuatorLimits, limit_command

__all__ = ["DEFAULT_GEOMETRY", "TeleopStats", "run_teleop", "teleop_job"]

#: The planar robot teleop and the planar pipeline drive unless told otherwise
#: (:data:`motionbase.config.DEFAULT_RRR3`, one default for every command).
DEFAULT_GEOMETRY = DEFAULT_RRR3


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
    """Run the teleoperation loop until the source ends, ``duration_s`` passes or a stop.

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
        Raised (by a signal, a key or a test) to E-stop: park at home, then return.
    stale_timeout_s : float
        Watchdog: hold position when a watched source gave no new point for this long, s.
    max_park_s : float
        Longest time given to the E-stop park, s.

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
    parking = False
    park_end = math.inf
    wants_show = hasattr(source, "view")
    start = time.monotonic()
    k = 0
    while True:
        t = k * dt
        if not parking:
            if stop:
                parking = True
                stats.estops += 1
                stats.stopped_by = stop.reason or "stop"
                park_end = t + max_park_s
            elif (duration_s is not None and t > duration_s + 1e-9) or source.finished(t):
                stats.stopped_by = "duration" if not source.finished(t) else "end of input"
                break
        elif t > park_end or (np.array_equal(q, home_q) and not v.any()):
            break
        if realtime:
            lag = time.monotonic() - (start + t)
            if lag < 0:
                time.sleep(-lag)
            else:
                stats.worst_overrun_s = max(stats.worst_overrun_s, lag)
        pixel = source.read(t)
        target_xy: tuple[float, float] | None = None
        goal: tuple[float, float, float] | None = None  # valid target pose
        refused = False
        if parking:
            goal = tuple(rrr3.home)
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

        # the safety stage: the goal's angles, or a hold of the last safe command
        if goal is None:
            # refused: an unsafe target makes the safety stage hold; stale/no input: brake here
            wanted = np.full(3, np.nan) if refused else q
            q_new, v_new, status = limiter(q, v, q, wanted)
            new_pose = pose if np.array_equal(q_new, q) else None
            q_target_prev = q_new
        else:
            wanted = limiter.angles(goal)
            goal_q = wanted
            q_new, v_new, status = limiter(q, v, q_target_prev, wanted)
            new_pose = goal
            if status & UNSAFE_TARGET:  # valid by status, yet a hair outside a servo interval
                stats.held += 1
                wanted = q_new
            elif status & RATE_LIMITED:
                # too far for one tick: approach along the pose segment, joints coordinated
                stats.rate_limited += 1
                dist = float(np.max(np.abs(wanted - q)))
                step = limiter.path_step(dist, float(np.max(np.abs(v))))
                if 0.0 < step < dist:  # else braking or overshooting: the safety stage's output
                    found = limiter.along(pose, goal, q, step)
                    if found is not None:
                        new_pose, wanted = found
                        q_new, v_new, status = limiter(q, v, q, wanted)
                    # else the segment leaves the valid region: the safety stage's own approach
                if status != 0:
                    stats.safety_trims += 1
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
            if target_xy is not None:  # a cursor sample that was used (not while parking)
                logger.add("/cursor", t, {"pixel": list(pixel), "target": list(target_xy)})
            logger.add("/planar/pose", t, {"pose": pose.tolist()})
            logger.add("/planar/actuators", t, {"angles": q.tolist(), "servo_deg": servo})
            if k % max(1, int(round(rate_hz))) == 0:
                logger.add("/health", t, stats.as_health())
        if wants_show:
            source.show(
                points=rrr3.joint_points(pose, angles=q),
                target=target_xy,
                held=refused or stale,
                parking=parking,
            )
        stats.ticks += 1
        k += 1
    if logger is not None:
        logger.add("/health", max(0.0, (k - 1) * dt), stats.as_health())
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
) -> TeleopStats:
    """The ``motionbase teleop`` command: build source, calibration, sink and log; run.

    Without ``calibration_path`` the mouse window uses its own view (the target sits under
    the pointer) and file/UDP input maps their screen (1310 x 715 px unless the source says
    otherwise) onto the largest valid rectangle at phi = 0 (:meth:`CursorCalibration.default`).
    SIGINT and SIGTERM E-stop the robot (park at home within the limits) while it runs.
    """
    from motionbase.config import resolve_preset_or_path
    from motionbase.io.cursor_input import open_cursor_source
    from motionbase.platform.rrr3 import Rrr3Geometry

    rrr3 = Rrr3(Rrr3Geometry.from_toml(resolve_preset_or_path("rrr3", geometry)))
    source = open_cursor_source(input_spec, rrr3)
    sink = None
    logger = None
    stop = stop if stop is not None else StopRequest()
    with source:
        if calibration_path is not None:
            cal = CursorCalibration.from_toml(calibration_path)
        elif hasattr(source, "unview"):
            w, h = source.size_px
            px = np.array([[u, v] for u in (0, w / 2, w) for v in (0, h / 2, h)], dtype=float)
            cal = CursorCalibration.fit(px, source.unview(px))
        else:
            cal = CursorCalibration.default(rrr3, *source.size_px)
        restore = install_signal_stop(stop)
        try:
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
                ).start()
            return run_teleop(
                source, rrr3, cal, sink=sink, logger=logger, rate_hz=rate_hz,
                duration_s=duration_s, realtime=realtime, clamp=clamp, stop=stop,
                stale_timeout_s=stale_timeout_s,
            )  # fmt: skip
        finally:
            restore()
            if logger is not None:
                logger.finish()
            if sink is not None:
                sink.close()
