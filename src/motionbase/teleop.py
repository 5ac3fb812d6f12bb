"""Teleoperation of the planar 3-RRR robot from a cursor (mouse, eye tracker, file).

Each tick of a fixed-rate loop: cursor pixel -> calibration (metres) -> clamp toward home into
the valid workspace -> joint speed/acceleration limit -> inverse kinematics -> servo degrees
-> serial sink, logged to MCAP (``/cursor``, ``/planar/pose``, ``/planar/actuators``,
``/health``). A target that is still invalid after clamping (non-finite, unreachable,
singular, out of servo range; or any target when clamping is off) holds the last safe pose
and is counted, never sent. The first tick sends home (soft start from an unknown position
is the servos' own speed; keep the robot near home when powering up).

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

from motionbase.errors import ConfigError
from motionbase.platform.calibration import CursorCalibration
from motionbase.platform.rrr3 import OK, Rrr3

__all__ = ["TeleopStats", "run_teleop", "teleop_job"]


@dataclass
class TeleopStats:
    """Counts of one teleoperation run."""

    ticks: int = 0
    frames_sent: int = 0
    no_input: int = 0  #: ticks before the first cursor sample
    held: int = 0  #: targets refused (held the last safe pose)
    clamps: int = 0  #: targets moved toward home into the workspace
    rate_limited: int = 0  #: ticks whose step was shortened by the joint speed/accel limits
    worst_overrun_s: float = 0.0

    def as_health(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(rejected_inputs=self.held, watchdog_fades=0, estops=0)
        return d


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


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
    limit: bool = True,
) -> TeleopStats:
    """Run the teleoperation loop until the source ends or ``duration_s`` passes.

    Parameters
    ----------
    source : cursor source
        From :mod:`motionbase.io.cursor_input` (opened by the caller).
    rrr3 : Rrr3
        The robot; its geometry's ``max_speed`` (rad/s) and ``max_accel`` (rad/s^2) bound
        every joint's motion when ``limit`` is true.
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
    limit : bool
        Apply the joint speed and acceleration limits (along the straight pose segment).

    Returns
    -------
    TeleopStats
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f"teleop: rate must be > 0 Hz, got {rate_hz!r}")
    dt = 1.0 / rate_hz
    g = rrr3.geometry
    vmax, amax = g.max_speed, g.max_accel
    stats = TeleopStats()
    pose = rrr3.home.copy()
    st, theta, servo = rrr3.solve_one(*pose)
    if st != OK:  # Rrr3 refuses such geometries already
        raise ConfigError("teleop: home pose is not valid")
    speed = 0.0
    wants_show = hasattr(source, "view")
    start = time.monotonic()
    k = 0
    pixel: tuple[float, float] | None = None
    while True:
        t = k * dt
        if duration_s is not None and t > duration_s + 1e-9:
            break
        if source.finished(t):
            break
        if realtime:
            lag = time.monotonic() - (start + t)
            if lag < 0:
                time.sleep(-lag)
            else:
                stats.worst_overrun_s = max(stats.worst_overrun_s, lag)
        pixel = source.read(t)
        target_xy: tuple[float, float] | None = None
        held = False
        if pixel is None:
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
            st_c, th_c, sv_c = rrr3.solve_one(*cand)
            if st_c != OK:
                stats.held += 1
                held = True
            else:
                step = float(np.max(np.abs(_wrap(th_c - theta))))
                if limit and step > 0.0:
                    allow = min(vmax, speed + amax * dt, math.sqrt(2.0 * amax * step))
                    if step > allow * dt * (1 + 1e-9):
                        frac = allow * dt / step
                        cand = tuple(p + frac * (c - p) for p, c in zip(pose, cand, strict=True))
                        st_c, th_c, sv_c = rrr3.solve_one(*cand)
                        stats.rate_limited += 1
                        if st_c != OK:
                            stats.held += 1
                            held = True
                if not held:
                    speed = float(np.max(np.abs(_wrap(th_c - theta)))) / dt
                    pose = np.array(cand, dtype=float)
                    theta, servo = th_c, sv_c
        if held:
            speed = 0.0
        if sink is not None:
            if sink.write([int(v) for v in servo], t=t):
                stats.frames_sent += 1
        if logger is not None:
            if pixel is not None:
                logger.add("/cursor", t, {"pixel": list(pixel), "target": list(target_xy)})
            logger.add("/planar/pose", t, {"pose": pose.tolist()})
            logger.add(
                "/planar/actuators",
                t,
                {"angles": theta.tolist(), "servo_deg": [int(v) for v in servo]},
            )
            if k % max(1, int(round(rate_hz))) == 0:
                logger.add("/health", t, stats.as_health())
        if wants_show:
            source.show(points=rrr3.joint_points(pose, angles=theta), target=target_xy, held=held)
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
    geometry: str = "udesc",
    realtime: bool = True,
    clamp: bool = True,
) -> TeleopStats:
    """The ``motionbase teleop`` command: build source, calibration, sink and log; run.

    Without ``calibration_path`` the mouse window uses its own view (the target sits under
    the pointer) and file/UDP input maps their screen (1310 x 715 px unless the source says
    otherwise) onto the largest valid rectangle at phi = 0 (:meth:`CursorCalibration.default`).
    """
    from motionbase.io.cursor_input import open_cursor_source
    from motionbase.platform.rrr3 import Rrr3Geometry

    rrr3 = Rrr3(Rrr3Geometry.preset(geometry))
    source = open_cursor_source(input_spec, rrr3)
    sink = None
    logger = None
    with source:
        if calibration_path is not None:
            cal = CursorCalibration.from_toml(calibration_path)
        elif hasattr(source, "unview"):
            w, h = source.size_px
            px = np.array([[u, v] for u in (0, w / 2, w) for v in (0, h / 2, h)], dtype=float)
            cal = CursorCalibration.fit(px, source.unview(px))
        else:
            cal = CursorCalibration.default(rrr3, *source.size_px)
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
                    },
                ).start()
            return run_teleop(
                source, rrr3, cal, sink=sink, logger=logger, rate_hz=rate_hz,
                duration_s=duration_s, realtime=realtime, clamp=clamp,
            )  # fmt: skip
        finally:
            if logger is not None:
                logger.finish()
            if sink is not None:
                sink.close()
