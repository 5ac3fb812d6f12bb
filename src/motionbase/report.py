"""Cueing report of a recording: what the aircraft did against what the platform cued.

:func:`build_report` takes the decoded messages of a recording (``read_messages``)
and its metadata (``read_metadata``) and returns a :class:`Report`: the aligned
time series the plots need, the cueing metrics of
:mod:`motionbase.washout.perception` and a text summary. It loads and writes
nothing; :mod:`motionbase.io.report_plots` draws the PNGs and writes the files.

What is compared
----------------
*Aircraft*: ``/aircraft/state`` specific force at the pilot (m/s^2) and body rates
(rad/s), body axes FRD. Rejected samples are replaced by the last accepted one,
as the pipeline did.

*Platform cue* (6-DOF platforms: the 6-RUS, the 6-UPS Stewart platform): the pose the
actuators realised (``/platform/pose``,
after clamping and safety), turned into what the seated pilot feels by
:func:`~motionbase.washout.perception.platform_specific_force` (cab specific
force ``R^T (p'' - g)``: translational acceleration plus the gravity component
of the tilt, so tilt coordination shows as a sustained surge/sway cue) and
:func:`~motionbase.washout.perception.platform_angular_velocity`.

*Platform cue* (planar 3-RRR): the robot's ``[x, y, phi]`` about its home pose
mapped back to a full-size cab exactly as the pipeline mapped the washout onto
it (divided by ``planar_scale_m`` and ``planar_yaw_scale``, sway and yaw with their signs
changed: the robot's plane is z up, the cab's axes FRD): surge, sway and yaw
of a virtual cab; heave, roll and pitch are zero (the robot cannot tilt, so
there is no tilt coordination cue and no gravity cue).

The metrics cover the ``running`` phase only (the soft start from park and the
ramp back are platform logistics, not cueing); the plots show the whole run.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from motionbase.config import is_number, to_float
from motionbase.errors import ConfigError, LogFormatError
from motionbase.state import PHASES
from motionbase.washout.perception import (
    CueingMetrics,
    PerceivedMotion,
    cueing_metrics,
    perceived_motion,
    platform_angular_velocity,
    platform_specific_force,
)

__all__ = ["AXES6", "PHASES", "Report", "build_report", "planar_reach", "robot_reach", "rus6_reach"]

#: Pose axis names, in pose order.
AXES6 = ("surge", "sway", "heave", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class Report:
    """Everything the report shows.

    Aircraft and cue series are on the ticks that carry an aircraft state
    (``t``, N samples); platform series on every tick (``tick_t``, M >= N).

    Attributes
    ----------
    name : str
        What the report is about (the recording's file name).
    robot : str
        The robot's registry name (``"rus6"``, ``"stewart6"``, ``"rrr3"``).
    dt : float
        Pipeline period, s.
    t : ndarray, shape (N,)
        Times of the aircraft states, s.
    aircraft_f, aircraft_w : ndarray, shape (N, 3)
        Aircraft specific force (m/s^2) and body rates (rad/s), FRD.
    cab_pose : ndarray, shape (N, 6)
        The platform pose the cue is computed from, ``[x, y, z, roll, pitch, yaw]`` (m, rad);
        in planar mode the robot's motion mapped back to a full-size cab.
    cue_f, cue_w : ndarray, shape (N, 3)
        Platform cue: cab specific force (m/s^2) and body rates (rad/s), FRD.
    running : ndarray of bool, shape (N,)
        Samples in the ``running`` phase (the metrics' window).
    perceived : PerceivedMotion
        Otolith and canal outputs, aircraft and platform, over the running window.
    perceived_t : ndarray, shape (K,)
        Times of ``perceived`` (the running samples).
    metrics : CueingMetrics
        Over the running window; ``workspace_usage`` against ``reach`` (NaN for axes the
        robot does not have).
    reach : ndarray, shape (2, 6)
        Lower (< 0) and upper (> 0) single-axis reach, m and rad (NaN where none).
    tick_t : ndarray, shape (M,)
        Times of every pipeline tick, s.
    washout_pose : ndarray, shape (M, 6)
        Washout output before fades and clamping (m, rad).
    platform_pose : ndarray, shape (M, 6) or (M, 3)
        The realised pose as logged (6-RUS pose, or planar ``[x, y, phi]``).
    tick_cab_pose : ndarray, shape (M, 6)
        ``cab_pose`` on every tick (the stop phase included): the realised 6-RUS pose, or the
        planar robot's motion mapped back to a full-size cab.
    actuators : ndarray, shape (M, n)
        Actuator commands in the robot's unit: crank angles (rad), actuator lengths (m), or
        planar servo commands (integer degrees, as float).
    actuator_unit : {"rad", "m", "deg"}
    actuator_limits : ndarray, shape (2, n)
        Lower and upper actuator limits in ``actuator_unit``.
    actuator_label : str
        What ``actuators`` holds, for axis labels.
    phase : ndarray of str, shape (M,)
    clamped, rate_limited, held : ndarray of bool, shape (M,)
    fade : ndarray, shape (M,)
        Watchdog fade factor (1 = full motion).
    rejected : ndarray of bool, shape (N,)
        Aircraft samples the pipeline rejected.
    compared : str
        One paragraph saying what is compared with what.
    text : str
        The text summary (metrics and run facts).
    refused : ndarray of bool, shape (M,), or None
        Planar mode: the ticks whose realised pose the robot's kinematics refuse (a chain
        within its singularity margin, or out of reach), where the limiter's commands left
        the valid poses; None for the other robots.
    cueing_fallbacks : (str, int, int) or None
        For a cueing that logs its solver's fallbacks (``/cueing/<name>`` messages with a
        ``fallback`` field: the MPC): its name, the ticks that fell back and the ticks
        logged; None without such a topic.
    """

    name: str
    robot: str
    dt: float
    t: np.ndarray
    aircraft_f: np.ndarray
    aircraft_w: np.ndarray
    cab_pose: np.ndarray
    cue_f: np.ndarray
    cue_w: np.ndarray
    running: np.ndarray
    perceived: PerceivedMotion
    perceived_t: np.ndarray
    metrics: CueingMetrics
    reach: np.ndarray
    tick_t: np.ndarray
    washout_pose: np.ndarray
    platform_pose: np.ndarray
    tick_cab_pose: np.ndarray
    actuators: np.ndarray
    actuator_unit: str
    actuator_limits: np.ndarray
    actuator_label: str
    phase: np.ndarray
    clamped: np.ndarray
    rate_limited: np.ndarray
    held: np.ndarray
    fade: np.ndarray
    rejected: np.ndarray
    compared: str
    text: str
    cueing_fallbacks: tuple[str, int, int] | None = None
    refused: np.ndarray | None = None

    @property
    def planar(self) -> bool:
        from motionbase.platform.robot import robot_spec

        return robot_spec(self.robot).planar

    @property
    def robot_title(self) -> str:
        """The robot as the titles name it (``6-RUS``, ``6-UPS``, ``planar 3-RRR``)."""
        from motionbase.platform.robot import robot_spec

        # (the description's first word: "3-RRR, planar mode" -> "3-RRR", without its comma)
        kind = robot_spec(self.robot).description.removeprefix("planar ").split()[0].rstrip(",")
        return f"planar {kind}" if self.planar else kind

    def actuators_shown(self) -> tuple[np.ndarray, np.ndarray, str]:
        """``(actuators (M, n), limits (2, n), unit)`` in display units: deg for angles, mm
        for lengths, servo degrees as they are."""
        scale = {"rad": np.degrees(1.0), "m": 1000.0}.get(self.actuator_unit, 1.0)
        unit = {"rad": "deg", "m": "mm"}.get(self.actuator_unit, self.actuator_unit)
        return self.actuators * scale, self.actuator_limits * scale, unit


# --------------------------------------------------------------------------- reach


def robot_reach(robot: Any, tol: float = 1e-6) -> np.ndarray:
    """Single-axis reach of a 6-DOF robot (anything with a batch ``reachable``), ``(2, 6)``:
    lower (< 0) and upper (> 0) bounds, m and rad.

    From :func:`motionbase.platform.rus6_workspace.single_axis_envelope`.
    """
    from motionbase.platform import single_axis_envelope

    env = single_axis_envelope(robot, tol=tol)
    return np.array([[-a.negative for a in env], [a.positive for a in env]])


def rus6_reach(geometry: Any, tol: float = 1e-6) -> np.ndarray:
    """:func:`robot_reach` of a 6-RUS geometry."""
    from motionbase.platform import Rus6

    return robot_reach(Rus6(geometry), tol=tol)


def planar_reach(
    geometry: Any,
    scale_m: float,
    yaw_scale: float,
    *,
    limit: float | None = None,
    n: int = 4001,
    tol: float = 1e-7,
) -> np.ndarray:
    """Reach of the 3-RRR from home along x, y and phi alone, mapped back to cab units.

    A scan from home finds the first pose that is not reachable (:meth:`Rrr3.reachable`:
    closed, outside the singularity margins, in the servos' range), then bisection refines
    it to ``tol``.

    Parameters
    ----------
    geometry : Rrr3Geometry
    scale_m, yaw_scale : float
        The pipeline's planar scales (robot m per cab m, robot rad per cab rad).
    limit : float, optional
        Scan up to this far from home, m and rad. By default as far as the robot could go:
        pi in phi, and in x and y the base side plus crank, rod and platform side (no
        reachable pose lies beyond), so the scan ends where the robot does, not the scan.
    n : int
        Scan points per direction.
    tol : float
        Bisection tolerance, robot m and rad.

    Returns
    -------
    ndarray, shape (2, 6)
        Lower and upper bounds of ``[x, y, z, roll, pitch, yaw]`` in cab units (robot reach
        divided by the pipeline's signed scale); NaN for heave, roll and pitch, which the
        robot does not have.
    """
    from motionbase.platform.rrr3 import Rrr3Robot

    robot = Rrr3Robot(geometry, scale_m, yaw_scale)
    kin, scales = robot.kin, robot.scale  # the pipeline's mapping (signed scales)
    home = np.asarray(kin.home, dtype=float)
    if limit is None:
        span = geometry.base_side + geometry.crank + geometry.rod + geometry.platform_side
        limits = (span, span, np.pi)
    else:
        limits = (limit, limit, limit)
    out = np.full((2, 6), np.nan)
    for j, col in enumerate((0, 1, 5)):
        s = np.linspace(0.0, limits[j], n)
        for row, sign in ((0, -1.0), (1, 1.0)):
            poses = np.tile(home, (n, 1))
            poses[:, j] += sign * s
            ok = np.asarray(kin.reachable(poses), dtype=bool)
            bad = np.flatnonzero(~ok)
            if bad.size == 0:
                reach = s[-1]
            elif bad[0] == 0:
                reach = 0.0
            else:
                lo, hi = s[bad[0] - 1], s[bad[0]]
                pose = home.copy()
                while hi - lo > tol:
                    mid = 0.5 * (lo + hi)
                    pose[j] = home[j] + sign * mid
                    if bool(kin.reachable(pose)):
                        lo = mid
                    else:
                        hi = mid
                reach = lo
            out[row, col] = sign * reach / scales[j]
    return np.sort(out, axis=0)  # (a negative scale swaps the ends)


# --------------------------------------------------------------------------- assembly


def _array(msgs: Sequence[Mapping[str, Any]], key: str, width: int, topic: str) -> np.ndarray:
    out = np.full((len(msgs), width), np.nan)
    for i, m in enumerate(msgs):
        v = m.get(key)
        if v is None:
            continue
        if not isinstance(v, list):  # (a number or a string: a traceback once)
            shown = repr(v) if len(repr(v)) <= 40 else repr(v)[:37] + "..."
            raise LogFormatError(
                f"{topic}: message {i + 1}: field {key!r} is {shown}, expected {width} numbers"
            )
        if len(v) != width:
            raise LogFormatError(f"{topic}: field {key!r} has {len(v)} values, expected {width}")
        bad = next((x for x in v if x is not None and not is_number(x)), None)
        if bad is not None:
            raise LogFormatError(
                f"{topic}: message {i + 1}: field {key!r} holds {bad!r:.40}, not a number"
            )
        out[i] = [np.nan if x is None else to_float(x) for x in v]
    return out


def _objects(messages: Mapping[str, Sequence[Any]], topic: str) -> list[Mapping[str, Any]]:
    """The messages on ``topic``; a LogFormatError names the first that is not a JSON object."""
    msgs = list(messages.get(topic) or [])
    for i, m in enumerate(msgs):
        if not isinstance(m, Mapping):
            shown = repr(m) if len(repr(m)) <= 40 else repr(m)[:37] + "..."
            raise LogFormatError(f"{topic}: message {i + 1} is {shown}, not a JSON object")
    return msgs


def _times(msgs: Sequence[Mapping[str, Any]], topic: str) -> np.ndarray:
    try:
        t = np.array([float(m["t"]) for m in msgs])
    except (KeyError, TypeError, ValueError, OverflowError):
        raise LogFormatError(f"{topic}: a message has no numeric 't'") from None
    return t


def _hold_last(x: np.ndarray, ok: np.ndarray, initial: np.ndarray) -> np.ndarray:
    """Replace rows where ``ok`` is False by the last good row (``initial`` before any)."""
    out = x.copy()
    last = np.asarray(initial, dtype=float)
    for i in range(out.shape[0]):
        if ok[i]:
            last = out[i]
        else:
            out[i] = last
    return out


def _flags(msgs: Sequence[Mapping[str, Any]], key: str, default: bool = False) -> np.ndarray:
    return np.array([bool(m.get(key, default)) for m in msgs], dtype=bool)


def _dt(metadata: Mapping[str, Any], t: np.ndarray) -> float:
    rate = (metadata.get("pipeline_config") or {}).get("pipeline", {}).get("rate_hz")
    if isinstance(rate, int | float) and not isinstance(rate, bool) and rate > 0:
        return 1.0 / float(rate)
    steps = np.diff(t)
    steps = steps[steps > 0]
    if steps.size == 0:
        raise LogFormatError("cannot tell the sample period: fewer than two distinct times")
    return float(np.median(steps))


def build_report(
    messages: Mapping[str, Sequence[Mapping[str, Any]]],
    metadata: Mapping[str, Any],
    *,
    name: str = "recording",
) -> Report:
    """Assemble the cueing report of a recording.

    Parameters
    ----------
    messages : mapping
        Topic -> decoded JSON messages in file order, as
        :func:`motionbase.io.mcap_source.read_messages` returns them.
    metadata : mapping
        The recording's configuration (:func:`motionbase.io.mcap_source.read_metadata`);
        ``metadata["pipeline_config"]`` gives the robot, its geometry (actuator limits,
        reach) and the pipeline rate.
    name : str
        Shown in titles and the summary.

    Returns
    -------
    Report

    Raises
    ------
    LogFormatError
        No ``/aircraft/state`` messages, no platform topic, or malformed messages.
    ConfigError
        The recorded configuration is missing or invalid.
    """
    try:
        return _build_report(messages, metadata, name)
    except LogFormatError as exc:  # a malformed message: say in which recording
        msg = str(exc)
        raise LogFormatError(msg if msg.startswith(name) else f"{name}: {msg}") from None


def _build_report(
    messages: Mapping[str, Sequence[Mapping[str, Any]]], metadata: Mapping[str, Any], name: str
) -> Report:
    from motionbase.pipeline import PipelineConfig
    from motionbase.platform.robot import robot_spec

    air_msgs = _objects(messages, "/aircraft/state")
    if not air_msgs:
        present = ", ".join(sorted(k for k, v in messages.items() if v)) or "none"
        raise LogFormatError(
            f"{name}: no /aircraft/state messages, nothing to report (topics present: {present})"
        )
    recorded = metadata.get("pipeline_config")
    if not isinstance(recorded, Mapping):
        raise ConfigError(
            f"{name}: no recorded pipeline configuration in the metadata; the report needs "
            "the geometry (record with motionbase fly or replay)"
        )
    config = PipelineConfig.from_dict(dict(recorded), source=f"{name}: metadata")
    planar = config.planar
    pose_topic, act_topic = (
        ("/planar/pose", "/planar/actuators")
        if planar
        else ("/platform/pose", "/platform/actuators")
    )
    pose_msgs = _objects(messages, pose_topic)
    act_msgs = _objects(messages, act_topic)
    if not pose_msgs:
        raise LogFormatError(f"{name}: no {pose_topic} messages (the {config.robot} output)")

    # every tick: platform side ------------------------------------------------
    robot = config.make_robot()
    tick_t = _times(pose_msgs, pose_topic)
    m = len(robot.neutral_pose)  # (a plug-in's pose may be < 6)
    platform_pose = _array(pose_msgs, "pose", m, pose_topic)
    if not np.isfinite(platform_pose).all():
        raise LogFormatError(f"{name}: {pose_topic} holds non-finite poses")
    wo_msgs = _objects(messages, "/washout/pose")
    wo_index = {float(x): i for i, x in enumerate(_times(wo_msgs, "/washout/pose"))}
    washout_pose = np.full((tick_t.size, 6), np.nan)
    wo_all = _array(wo_msgs, "pose", 6, "/washout/pose") if wo_msgs else None
    for k, tk in enumerate(tick_t):
        i = wo_index.get(float(tk))
        if i is not None and wo_all is not None:
            washout_pose[k] = wo_all[i]
    phase = np.array([str(m.get("phase", "running")) for m in pose_msgs])
    clamped = _flags(pose_msgs, "clamped")
    rate_limited = _flags(pose_msgs, "rate_limited")
    held = _flags(pose_msgs, "held")
    fades = [{"fade": [m.get("fade", 1.0)]} for m in pose_msgs]  # (a number each: 1 wide)
    fade = _array(fades, "fade", 1, pose_topic)[:, 0]

    g = config.geometry
    if planar:
        key = "servo_deg"
        actuators = _array(act_msgs, key, 3, act_topic)
        limits = np.array([g.servo_min_deg, g.servo_max_deg], dtype=float)
        unit, label = "deg", "servo command"
    else:
        actuators = _array(act_msgs, "angles", robot.n, act_topic)
        limits = np.array([robot.limits.lower, robot.limits.upper], dtype=float)
        unit = robot.actuator_unit
        label = "crank angle" if unit == "rad" else "actuator length"
    if actuators.shape[0] != tick_t.size:
        act_t = _times(act_msgs, act_topic)
        idx = {float(x): i for i, x in enumerate(act_t)}
        aligned = np.full((tick_t.size, actuators.shape[1]), np.nan)
        for k, tk in enumerate(tick_t):
            i = idx.get(float(tk))
            if i is not None:
                aligned[k] = actuators[i]
        actuators = aligned

    # ticks with an aircraft state --------------------------------------------------
    t_air = _times(air_msgs, "/aircraft/state")
    # a recording cut short (a killed run) can end between a tick's aircraft state and its
    # pose: those last states have no tick, and are left out
    whole = t_air.size
    while whole > 1 and t_air[whole - 1] > tick_t.max():
        whole -= 1
    air_msgs, t_air = air_msgs[:whole], t_air[:whole]
    tick_index = {float(x): i for i, x in enumerate(tick_t)}
    rows = np.array([tick_index.get(float(x), -1) for x in t_air])
    if (rows < 0).any():
        missing = int((rows < 0).sum())
        raise LogFormatError(
            f"{name}: {missing} /aircraft/state messages have no {pose_topic} at the same time"
        )
    f_raw = _array(air_msgs, "specific_force", 3, "/aircraft/state")
    w_raw = _array(air_msgs, "angular_velocity", 3, "/aircraft/state")
    accepted = _flags(air_msgs, "accepted", True)
    good = accepted & np.isfinite(f_raw).all(axis=1) & np.isfinite(w_raw).all(axis=1)
    gravity = float(config.cueing_params.gravity)
    aircraft_f = _hold_last(f_raw, good, np.array([0.0, 0.0, -gravity]))
    aircraft_w = _hold_last(w_raw, good, np.zeros(3))
    dt = _dt(metadata, t_air)

    # the cab pose the cue comes from, on every tick (so derivatives at the end of the
    # aircraft data use the following ticks), then on the aircraft ticks
    # the cue pose the robot realises (the pose itself on the 6-DOF robots; the planar
    # robot and a plug-in of fewer axes hold the others at neutral)
    cab_all = robot.cue_from_pose(platform_pose, np.zeros((len(platform_pose), 6)))
    refused = None
    if planar:
        from motionbase.platform.rrr3 import TYPE1, TYPE2, UNREACHABLE

        refused = (robot.kin.status(platform_pose) & (UNREACHABLE | TYPE1 | TYPE2)) != 0
        reach = planar_reach(g, config.planar_scale_m, config.planar_yaw_scale)
        compared = (
            "Planar mode: the 3-RRR's [x, y, phi] about its home pose, divided by "
            f"planar_scale_m = {config.planar_scale_m:g} and planar_yaw_scale = "
            f"{config.planar_yaw_scale:g} (y and phi negated: the plane is z up), read as the "
            "surge, sway and yaw of a full-size cab "
            "(the pipeline's own mapping, reversed). Heave, roll and pitch are zero: the robot "
            "cannot tilt, so there is no tilt-coordination (gravity) cue; its sustained "
            "surge/sway force is washed out to zero."
        )
    else:
        reach = robot_reach(robot)
        reach[:, (reach == 0.0).all(axis=0)] = np.nan  # axes the robot lacks
        kind = robot_spec(config.robot).description.split(" (")[0]
        compared = (
            f"{kind}: the aircraft's specific force at the pilot and body rates against the cab's "
            "specific force R^T (p'' - g) (acceleration plus the gravity component of the tilt) "
            "and body rates, from the realised platform pose (after clamping and safety)."
        )
    cab_pose = cab_all[rows]
    cue_f = platform_specific_force(cab_all, dt, gravity)[rows]
    cue_w = platform_angular_velocity(cab_all, dt)[rows]

    # metrics over the running phase ----------------------------------------------
    running = phase[rows] == "running"
    if running.sum() < 3:
        raise LogFormatError(
            f"{name}: fewer than 3 samples in the running phase; the recording is too short "
            "for cueing metrics (fly longer than the soft start)"
        )
    sel = np.flatnonzero(running)
    # the metrics' own reach check needs finite bounds; axes the robot lacks read NaN after
    reach_for_metrics = np.where(np.isfinite(reach), reach, np.array([[-1.0] * 6, [1.0] * 6]))
    metrics = cueing_metrics(
        t_air[sel],
        aircraft_f[sel],
        aircraft_w[sel],
        cab_pose[sel],
        dt,
        reach=reach_for_metrics,
        g=gravity,
    )
    if not np.isfinite(reach).all():  # axes the robot lacks: no usage
        usage = metrics.workspace_usage.copy()
        usage[~np.isfinite(reach).all(axis=0)] = np.nan
        metrics = replace(metrics, workspace_usage=usage)
    perceived = perceived_motion(aircraft_f[sel], aircraft_w[sel], cab_pose[sel], dt, gravity)

    fields = dict(
        name=name,
        robot=config.robot,
        dt=dt,
        t=t_air,
        aircraft_f=aircraft_f,
        aircraft_w=aircraft_w,
        cab_pose=cab_pose,
        cue_f=cue_f,
        cue_w=cue_w,
        running=running,
        perceived=perceived,
        perceived_t=t_air[sel],
        metrics=metrics,
        reach=reach,
        tick_t=tick_t,
        washout_pose=washout_pose,
        platform_pose=platform_pose,
        tick_cab_pose=cab_all,
        actuators=actuators,
        actuator_unit=unit,
        actuator_limits=limits,
        actuator_label=label,
        phase=phase,
        clamped=clamped,
        rate_limited=rate_limited,
        held=held,
        fade=fade,
        rejected=~good,
        compared=compared,
        text="",
        cueing_fallbacks=_cueing_fallbacks(messages),
        refused=refused,
    )
    report = Report(**fields)  # type: ignore[arg-type]
    return replace(report, text=summary_text(report, metadata))


def _cueing_fallbacks(
    messages: Mapping[str, Sequence[Mapping[str, Any]]],
) -> tuple[str, int, int] | None:
    """The cueing's name, its ticks that fell back and its ticks logged, from the first
    ``/cueing/<name>`` topic whose messages have a ``fallback`` field (the MPC's)."""
    for topic, msgs in messages.items():
        first = msgs[0] if msgs else None
        if topic.startswith("/cueing/") and isinstance(first, Mapping) and "fallback" in first:
            failed = sum(1 for m in msgs if isinstance(m, Mapping) and m.get("fallback") is True)
            return topic.removeprefix("/cueing/"), failed, len(msgs)
    return None


# --------------------------------------------------------------------------- text


def _cells(values: np.ndarray, fmt: str, width: int = 10) -> str:
    return "".join(f"{'n/a' if not np.isfinite(v) else format(v, fmt):>{width}s}" for v in values)


def _wrap(text: str, width: int = 92, indent: str = "  ") -> list[str]:
    import textwrap

    return textwrap.wrap(text, width, initial_indent=indent, subsequent_indent=indent)


def summary_text(report: Report, metadata: Mapping[str, Any] | None = None) -> str:
    """The text summary of a report (what ``summary.txt`` holds)."""
    r = report
    m = r.metrics
    robot = r.robot_title
    src = (metadata or {}).get("source")
    src = src if isinstance(src, Mapping) else {}  # (another tool's metadata: anything)
    what = src.get("script") or src.get("kind") or "unknown source"
    n_run = int(r.running.sum())
    lines = [
        f"motionbase report: {r.name} ({robot}, source {what}, {r.t.size} aircraft samples at "
        f"{1.0 / r.dt:g} Hz, {r.t[-1] - r.t[0] + r.dt:.1f} s)",
        "",
        "compared:",
        *_wrap(r.compared),
        f"  metrics over the running phase: {n_run} samples, {m.duration:.1f} s "
        "(soft start and stop excluded); perceived = otolith / semicircular-canal models",
        "",
        f"  {'':<36s}{'x':>10s}{'y':>10s}{'z':>10s}",
        f"  {'specific force RMSE [m/s^2]':<36s}" + _cells(m.rmse_specific_force, ".3f"),
        f"  {'specific force correlation':<36s}" + _cells(m.correlation_specific_force, ".2f"),
        f"  {'specific force false cues [%]':<36s}"
        + _cells(100 * m.false_cue_specific_force, ".1f"),
        f"  {'':<36s}{'roll':>10s}{'pitch':>10s}{'yaw':>10s}",
        f"  {'angular velocity RMSE [deg/s]':<36s}"
        + _cells(np.degrees(m.rmse_angular_velocity), ".2f"),
        f"  {'angular velocity correlation':<36s}" + _cells(m.correlation_angular_velocity, ".2f"),
        f"  {'angular velocity false cues [%]':<36s}"
        + _cells(100 * m.false_cue_angular_velocity, ".1f"),
        "",
        f"  {'':<36s}" + "".join(f"{a:>8s}" for a in AXES6),
        f"  {'workspace usage [% of reach]':<36s}" + _cells(100 * m.workspace_usage, ".0f", 8),
        f"  {'reach (-) [m | deg]':<36s}" + _cells(_display(r.reach[0]), ".3g", 8),
        f"  {'reach (+) [m | deg]':<36s}" + _cells(_display(r.reach[1]), ".3g", 8),
    ]
    off = r.refused is not None and bool(r.refused.any())
    if np.nanmax(m.workspace_usage) > 1.0:
        why = "by combining axes" + (" or past the valid poses (below)" if off else "")
        lines.append(f"  (over 100 %: the pose went beyond the single-axis reach {why})")
    lines += ["", "run:"]
    shares = [
        ("clamped", r.clamped),
        ("rate-limited", r.rate_limited),
        ("held (unsafe command)", r.held),
    ]
    lines.append(
        "  "
        + "; ".join(f"{k} {100 * v.mean():.1f} % of ticks" for k, v in shares)
        + f"; faded {100 * (r.fade < 1).mean():.1f} %; rejected inputs {int(r.rejected.sum())}"
    )
    if off:
        assert r.refused is not None
        lines += _wrap(
            f"warning: {int(r.refused.sum())} ticks ({100 * r.refused.mean():.1f} %) realised "
            "poses the robot's kinematics refuse (a chain within its singularity margin, or "
            "out of reach): each actuator's speed and acceleration limit lagged behind the "
            "cue where it ran into the workspace's edge at speed",
            indent="  ",
        )
    if r.cueing_fallbacks is not None and r.cueing_fallbacks[1]:
        name, failed, ticks = r.cueing_fallbacks
        lines.append(
            f"  warning: {name}: the solver failed on {failed} of {ticks} ticks, which fell "
            f"back (the pose blended toward its fallback washout; each tick on /cueing/{name})"
        )
    # as the end-of-run summary: the flight's range (full motion), the ramps apart (they
    # start and end at park, which would stand for the range's end otherwise)
    act, (lo, hi), unit = r.actuators_shown()
    flight, start = r.phase == "running", r.phase == "starting"
    lines.append(
        f"  flight ({int(flight.sum())} ticks at full motion): {r.actuator_label} [{unit}] "
        "range used (limits)"
    )
    for i in range(act.shape[1]):
        col = act[flight, i][np.isfinite(act[flight, i])]
        used = f"{col.min():7.1f} .. {col.max():6.1f}" if col.size else "    n/a"
        lines.append(f"    {i + 1}: {used}   ({lo[i]:.1f} .. {hi[i]:.1f})")
    lines.append(
        f"  parking: start ramp {start.sum() * r.dt:.1f} s, way back to park "
        f"{(~flight & ~start).sum() * r.dt:.1f} s (from and to park, not in the range above)"
    )
    return "\n".join(lines) + "\n"


def _display(reach_row: np.ndarray) -> np.ndarray:
    out = np.array(reach_row, dtype=float)
    out[3:] = np.degrees(out[3:])
    return out
