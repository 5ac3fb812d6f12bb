"""The jobs a user runs (``fly``, ``replay``, ``stream``): sources, pipeline and sinks put together.

The command line (:mod:`motionbase.cli`) only parses arguments and calls these
functions; tests call them directly too. Each returns a :class:`JobResult` whose
``summary_text()`` is what the command prints at the end.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from motionbase import __version__
from motionbase.config import DEFAULT_RUS6, refuse_out_over_inputs, same_file
from motionbase.errors import ConfigError, LogFormatError
from motionbase.pipeline import (
    Pipeline,
    PipelineConfig,
    PipelineOutput,
    RunSummary,
    StopRequest,
    run,
)
from motionbase.stopping import stop_on_signals, stop_signals_for, stopped_by

_log = logging.getLogger("motionbase")

RECORDINGS = Path("recordings")


def user_recordings_dir() -> Path:
    """Where ``stream`` logs when not told: ``$XDG_DATA_HOME/motionbase/recordings``, by
    default ``~/.local/share/motionbase/recordings`` (the log writer creates it on demand), so
    a live session leaves nothing in the folder it ran from, a checkout say.
    """
    base = os.environ.get("XDG_DATA_HOME", "")
    if not os.path.isabs(base):  # unset, empty or relative: the XDG default
        home = os.environ.get("HOME", "")
        if not os.path.isabs(home):  # empty or relative: the account's (it was "/" for "")
            import pwd

            home = pwd.getpwuid(os.getuid()).pw_dir
        base = os.path.join(home, ".local", "share")
    return Path(base) / "motionbase" / "recordings"


# --------------------------------------------------------------------------- configuration


def load_config(
    *,
    planar: bool = False,
    platform: str | None = None,
    washout: str | None = None,
    cueing: str = "classical",
    rate_hz: float = 120.0,
) -> PipelineConfig:
    """Build a pipeline configuration from preset names or TOML paths.

    Parameters
    ----------
    planar : bool
        Drive the 3-RRR robot (preset ``udesc_symmetric``) instead of a 6-DOF platform.
        The thesis's robot as built (``udesc``) has a type II singular curve 4 mm below home,
        so planar washout motion there clamps most sway; pass ``platform="udesc"`` for it.
    platform : str, optional
        A robot's name (``rus6``, ``stewart6``: its default geometry), or a geometry preset
        name or TOML path of the chosen robot (the 6-RUS unless ``planar``).
    washout : str, optional
        The cueing's parameters: a preset name (classical: ``default``, ``gentle``,
        ``telemetry``, ``tuned_ceart``) or a TOML path (``--params``, ``--washout``).
        By default the preset made for the geometry where one ships (classical on the
        ``ceart`` geometry: ``tuned_ceart``; mpc on the stewart6 ``seat``: ``seat``), else
        the cueing's default preset.
    cueing : str
        The cueing plug-in (``--cueing``), ``classical`` by default.
    rate_hz : float
        Pipeline rate, Hz.
    """
    from motionbase.platform.robot import load_geometry
    from motionbase.washout.cueing import cueing_spec

    robot, geometry = load_geometry(platform, planar=planar)
    spec = cueing_spec(cueing)
    if washout is None:
        washout = tuned_preset(spec, robot, geometry)
    params = spec.load_params(washout)
    return PipelineConfig(
        robot=robot, geometry=geometry, cueing=cueing, cueing_params=params, rate_hz=rate_hz
    )


def tuned_preset(spec: Any, robot: str, geometry: Any) -> str | None:
    """The preset of the cueing ``spec`` tuned for ``geometry`` (the same numbers as one of
    its ``tuned_presets``' geometry presets, whatever the file and name), or None."""
    from motionbase.platform.robot import load_geometry

    def numbers(g: Any) -> dict[str, Any]:
        return {k: v for k, v in g.to_dict().items() if k != "name"}

    for (tuned_robot, geometry_preset), preset in spec.tuned_presets.items():
        if tuned_robot == robot and numbers(load_geometry(geometry_preset)[1]) == numbers(geometry):
            return preset
    return None


def robot_title(config: PipelineConfig) -> str:
    """How a job's message names the robot (``6-RUS``)."""
    from motionbase.platform.robot import robot_spec

    return robot_spec(config.robot).description


def run_metadata(config: PipelineConfig, source: Any) -> dict[str, Any]:
    """The metadata record of a log: everything a replay needs."""
    return {"pipeline_config": config.to_dict(), "source": source.describe()}


# --------------------------------------------------------------------------- results


@dataclass
class JobResult:
    """What a job did: the run summary, where the log went, and what to tell the user.

    ``failed``: the command exits with status 1 although the run itself ended as usual
    (``replay --check`` found a difference or could not compare; the log is gone).
    """

    title: str
    summary: RunSummary
    out: Path | None
    notes: list[str] = field(default_factory=list)
    failed: bool = False
    actuator_unit: str = "rad"  # the robot's: "rad" (cranks, servos) or "m" (linear)

    def summary_text(self) -> str:
        s = self.summary
        h = s.health
        speedup = s.sim_time_s / s.wall_time_s if s.wall_time_s > 0 else float("inf")
        lines = [
            f"{self.title}: {s.samples} sample{'s' * (s.samples != 1)}, {s.sim_time_s:.1f} s "
            "simulated in "
            f"{s.wall_time_s:.1f} s wall ({speedup:.1f}x real time), stopped by {s.stopped_by}",
            f"clamped {100 * s.clamped_share:.1f} % of samples; "
            f"rejected inputs {h.rejected_inputs}; "
            f"rate-limited commands {h.rate_limited}; unsafe commands held {h.unsafe_commands}; "
            f"watchdog fades {h.watchdog_fades}; E-stops {h.estops}",
        ]
        if h.overruns:
            lines.append(
                f"real-time loop: {h.overruns} ticks late (worst by "
                f"{1e3 * h.worst_overrun_s:.1f} ms; {h.overruns_off_cpu} of them while the loop "
                "was waiting for the CPU, the interpreter lock or I/O; --busy-wait and a core "
                "of its own help, see the README's Safety section)"
            )
        if h.late_commands:
            lines.append(
                f"commands late for the actuators: {h.late_commands} reached them more than one "
                f"period after their sample was due (worst by {1e3 * h.worst_late_s:.1f} ms)"
            )
        if s.peak_angle is not None:
            lo, hi = s.angle_limits
            # shown in deg for rotary actuators, mm for linear ones
            linear = self.actuator_unit == "m"
            unit, what = ("mm", "length") if linear else ("deg", "angle")

            def deg(x: float) -> float:
                return 1000.0 * x if linear else math.degrees(x)

            if s.running_samples:
                low, high = s.angle_range
                lines.append(
                    f"flight ({s.running_samples} sample{'s' * (s.running_samples != 1)} at "
                    "full motion), per actuator: "
                    f"{what} used {unit} (limits), peak speed {unit}/s (limit)"
                )
                for i in range(len(s.peak_angle)):
                    lines.append(
                        f"{i + 1:>8}  {deg(low[i]):7.1f}..{deg(high[i]):<7.1f} "
                        f"({deg(lo[i]):6.1f}..{deg(hi[i]):5.1f})   "
                        f"{deg(s.peak_speed[i]):10.1f} ({deg(s.max_speed[i]):.1f})"
                    )
            else:
                lines.append("flight: none (stopped before the soft start reached full motion)")
            lines.append(
                f"parking: start ramp {s.start_s:.1f} s (peak speed "
                f"{deg(float(np.max(s.start_peak_speed))):.1f} {unit}/s), way back to park "
                f"{s.stop_s:.1f} s (peak speed {deg(float(np.max(s.stop_peak_speed))):.1f} "
                f"{unit}/s); speed limit {deg(float(np.min(s.max_speed))):.1f} {unit}/s"
            )
        if self.out is not None:
            try:
                what = f"({self.out.stat().st_size / 1e6:.2f} MB)"
            except OSError:  # (as Path.exists() says False)
                what = "is gone: removed during the run, nothing of it was kept"
            lines.append(f"log: {self.out} {what}")
        lines.extend(self.notes)
        return "\n".join(lines)


class ProgressBar:
    """A one-line progress bar on a terminal (simulated time / total); silent elsewhere."""

    def __init__(self, total_s: float | None, stream=None, min_interval_s: float = 0.1) -> None:
        self.total = total_s
        self.stream = stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.min_interval = min_interval_s
        self._next = 0.0
        self._t0: float | None = None

    def __call__(self, out: PipelineOutput) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + self.min_interval
        if self._t0 is None:
            self._t0 = out.t
        done = out.t - self._t0
        if self.total:
            frac = min(1.0, max(0.0, done / self.total))
            bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
            text = f"\r[{bar}] {done:7.1f} / {self.total:.1f} s  {out.phase:<9}"
        else:
            text = f"\r{done:9.1f} s  {out.phase:<9}"
        self.stream.write(text)
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\r" + " " * 72 + "\r")
            self.stream.flush()


class JobProgress:
    """The progress of a batch job (``tune``, ``omct``) on ``stream`` (stderr).

    On a terminal the line is redrawn in place at every :meth:`show`. Elsewhere (a log file,
    CI, a service manager's journal) a long job would otherwise print nothing for minutes:
    there a whole line is written at most every ``every_s`` seconds, the first one
    ``every_s`` after the start, so a short job stays silent and a long one is seen to be alive.
    """

    def __init__(self, stream=None, every_s: float = 30.0) -> None:
        self.stream = stream or sys.stderr
        self.terminal = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every_s = every_s
        self._next = time.monotonic() + every_s
        self._width = 0

    def show(self, text: str) -> None:
        if self.terminal:
            self.stream.write("\r" + text.ljust(self._width))
            self._width = len(text)
        else:
            now = time.monotonic()
            if now < self._next:
                return
            self._next = now + self.every_s
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self, *, erase: bool = False) -> None:
        """End the line on a terminal: ``erase`` it, or keep it and go to the next line."""
        if self.terminal and self._width:
            self.stream.write("\r" + " " * self._width + "\r" if erase else "\n")
            self.stream.flush()


# --------------------------------------------------------------------------- jobs


def _close_sinks(sinks: list[Any], *, quiet: bool) -> None:
    """Close every sink (last opened first), even when one fails; then raise the first failure."""
    first: BaseException | None = None
    for sink in reversed(sinks):
        try:
            sink.__exit__(None, None, None)
        except Exception as exc:  # noqa: BLE001 - the others must still close
            first = first or exc
    if first is not None and not quiet:
        raise first


def _drive(
    title: str,
    config: PipelineConfig,
    source: Any,
    out: Path | None,
    *,
    paced: bool,
    busy_wait: bool = False,
    progress: bool,
    extra_sinks: list[Any] | None = None,
    outputs: list[str] | None = None,
    on_output: Callable[[PipelineOutput], None] | None = None,
    stop: StopRequest | None = None,
    live: Any = None,
    preview: tuple[np.ndarray, np.ndarray] | None = None,
) -> JobResult:
    """Run ``source`` (already entered) through a new pipeline into an MCAP log and sinks.

    ``preview`` (offline runs): the whole reference ``(f, w)``, one row per sample, handed
    to the cueing (``set_preview``) before the first tick; the log's metadata and the
    result's notes say so.

    ``outputs`` are motor-drive output URLs (:func:`motionbase.io.motor_output.open_output`);
    their statistics end up in the result's notes. A run with outputs, or with a source that
    paces itself, is a real-time run (``paced``): the pipeline's loop paces every source
    that does not pace itself at the pipeline's rate (:func:`motionbase.pipeline.run`).
    ``live`` (a :class:`~motionbase.io.mcap_log.LiveAddress`) also serves the log's topics to
    Foxglove.
    """
    with stop_on_signals(stop) as stop:
        return _drive_stoppable(
            title, config, source, out, paced=paced, busy_wait=busy_wait, progress=progress,
            extra_sinks=extra_sinks, outputs=outputs, on_output=on_output, stop=stop, live=live,
            preview=preview,
        )  # fmt: skip


def _drive_stoppable(
    title: str,
    config: PipelineConfig,
    source: Any,
    out: Path | None,
    *,
    paced: bool,
    busy_wait: bool,
    progress: bool,
    extra_sinks: list[Any] | None,
    outputs: list[str] | None,
    on_output: Callable[[PipelineOutput], None] | None,
    stop: StopRequest,
    live: Any,
    preview: tuple[np.ndarray, np.ndarray] | None = None,
) -> JobResult:
    from motionbase.io.motor_output import format_file, open_outputs
    from motionbase.io.pipeline_log import PipelineLog

    pipeline = Pipeline(config)
    metadata = run_metadata(config, source)
    if preview is not None:
        pipeline.cueing.set_preview(*preview)  # type: ignore[attr-defined]
        metadata["preview"] = True
    elif getattr(pipeline.cueing, "made_for_preview", False):
        _log.warning(
            "the %s parameters were tuned for offline runs with --preview; without it they "
            "plan on the current sample alone: add --preview (fly, replay) or give a set "
            "tuned for real time (e.g. --params tuned_ceart)",
            pipeline.cueing.name,
        )
    drives = open_outputs(outputs, pipeline.robot, command_dt=pipeline.dt)
    if out:  # a drive's frame-format file has been read; the log must not overwrite it
        refuse_out_over_inputs(out, *(("--output format", format_file(u)) for u in outputs or []))
    if drives:  # which drives the log's commands went to, in what units and frames
        metadata["outputs"] = [drive.describe() for drive in drives]
    extra_sinks = [*(extra_sinks or []), *drives]
    paced = bool(paced or drives or getattr(source, "paces_itself", False))
    bar = ProgressBar(getattr(source, "duration_s", None)) if progress else None

    def on_tick(o: PipelineOutput) -> None:
        if bar is not None:
            bar(o)
        if on_output is not None:
            on_output(o)

    progress_fn = on_tick if (bar is not None and bar.enabled) or on_output is not None else None

    sinks: list[Any] = []
    try:
        try:
            for sink in extra_sinks or []:  # first: a port that will not open leaves no log
                sink.__enter__()
                sinks.append(sink)
            if out:
                log = PipelineLog(
                    out,
                    metadata,
                    health=pipeline.health.as_dict,
                    robot=pipeline.robot,
                    live=live,
                    cueing=pipeline.cueing,
                    realtime=paced,  # a tick never waits for the log's writer
                )
                log.__enter__()
                sinks.insert(0, log)  # the log stays the first sink, closed last
                if live is not None:
                    print(live.banner(log.live_port), file=sys.stderr, flush=True)
            summary = run(
                pipeline,
                source,
                sinks,
                paced=paced,
                busy_wait=busy_wait,
                stop=stop,
                progress=progress_fn,
            )
        except BaseException:
            _close_sinks(sinks, quiet=True)  # the failure that is propagating says it all
            raise
        _close_sinks(sinks, quiet=False)
    finally:
        if bar is not None:
            try:
                bar.close()
            except OSError:  # a closed terminal
                pass
    # a log removed while it was written (its folder deleted): the writer went on writing a
    # file without a name, so nothing of the run was kept
    log_gone = out is not None and not out.exists()
    if log_gone:
        _log.warning(
            "log %s is gone: it or its folder was removed during the run, so nothing of the "
            "run was kept (the run itself ended as usual, parked)",
            out,
        )
    return JobResult(
        title,
        summary,
        out,
        failed=log_gone,
        notes=[d.stats_line() for d in drives]
        + _lacking_notes(config, pipeline.robot)
        + _fallback_notes(pipeline.cueing, out)
        + (
            [
                f"preview: the {pipeline.cueing.name} cueing saw the flight's future "
                f"({len(preview[0])} samples; offline mode, not what a live run does)"
            ]
            if preview is not None
            else []
        ),
        actuator_unit=pipeline.robot.actuator_unit,
    )


def _refuse_out_over_cueing_files(out: str | Path, config: PipelineConfig) -> None:
    """A ConfigError when ``--out`` is a file the cueing's parameters name and the run
    reads: an MPC file's fallback washout (``solver.fallback``), which the log would
    overwrite as it would ``--params`` itself."""
    fallback = getattr(config.cueing_params, "fallback", None)
    if isinstance(fallback, str):
        refuse_out_over_inputs(out, ("--params file's solver.fallback", fallback))


def _lacking_notes(config: PipelineConfig, robot: Any) -> list[str]:
    """A note naming the cue's axes the robot does not render (the planar 3-RRR's heave,
    roll and pitch): dropped, the run said nothing of them."""
    from motionbase.platform.rus6_workspace import lacking_axes

    lacking = lacking_axes(robot)
    if not lacking:
        return []
    return [
        f"the {robot_title(config)} does not render {', '.join(lacking)}: dropped from "
        "the cue (/washout/pose holds them), not clamped"
    ]


def _fallback_notes(cueing: Any, out: Path | None) -> list[str]:
    """A warning when the cueing's solver failed on some ticks (an MPC's ``counts``), so
    that the pose blended toward its fallback washout: the summary says how often and
    which washout flew them (the log has each tick on ``/cueing/<name>``)."""
    counts = getattr(cueing, "counts", None)
    if not isinstance(counts, dict) or not counts.get("fallbacks"):
        return []
    fallback = getattr(getattr(cueing, "params", None), "fallback_name", "its fallback")
    where = f" (each tick on /cueing/{cueing.name} in {out})" if out is not None else ""
    return [
        f"warning: {cueing.name}: the solver failed on {counts['fallbacks']} of "
        f"{counts.get('ticks', '?')} ticks, which fell back: the pose blended toward the "
        f"fallback washout {fallback}{where}"
    ]


def _check_preview(cueing: str) -> None:
    """A ConfigError unless the cueing of this name can use a preview."""
    from motionbase.washout.cueing import cueing_spec

    if not hasattr(cueing_spec(cueing).cueing_type, "set_preview"):
        raise ConfigError(
            f"--preview: the {cueing} cueing does not use the flight's future; "
            "choose one that does (--cueing mpc) or drop --preview"
        )


def output_test(
    url: str,
    platform: Any = None,
    *,
    range_deg: float | None = None,
    speed_deg_s: float | None = None,
    range_mm: float | None = None,
    speed_mm_s: float | None = None,
    rate_hz: float | None = None,
    echo: Callable[[str], None] | None = None,
    stop: StopRequest | None = None,
) -> list[str]:
    """``motionbase output --test``: sweep each actuator in turn about neutral, slowly, for a
    wiring and sign check: park -> neutral, actuator 1 up, down, back, actuator 2, ...,
    neutral -> park.

    The sweep is a command source (:class:`motionbase.commanding.SweepSource`) run by the
    pipeline's loop (:func:`motionbase.pipeline.run`, paced at ``rate_hz``) in actuator
    mode (:class:`motionbase.commanding.CommandPipeline`): every command passes the soft
    start and the limiter with the robot's limits, and goes to the drive through
    :func:`motionbase.io.motor_output.open_output` (ramped at the drive within the same
    limits). Prints (``echo``) which actuator moves and its drive values.

    A stop (SIGINT, SIGTERM, SIGHUP, SIGQUIT or SIGTSTP, or ``stop`` raised by the caller) at
    any moment, start-up included, ends the sweep as it ends a flight: one line says so, the
    sweep holds where it is and the pipeline blends back to park over its soft-start time
    (a second signal: an E-stop, to park at once within the limits, said in a second line
    in the words of a flight's summary, :func:`motionbase.stopping.stopped_by`); the last
    frame is the park command and the function returns normally. The lines are the loop's
    display (``echo``, by default :func:`motionbase.console.tell`): a terminal or pipe that
    goes away loses them, never the sweep.

    Parameters
    ----------
    url : str
        The output URL.
    platform : str or Robot, optional
        A ``--platform`` value (a robot's name, a geometry preset or TOML path, its
        ``[output]`` table mapping the drive values; degrees or metres when it has none),
        or a robot. Default: the default 6-RUS.
    range_deg, speed_deg_s : float, optional
        Rotary actuators: half-range of each sweep about neutral (deg, default 5) and peak
        speed (deg/s, default 10, capped by the speed limit).
    range_mm, speed_mm_s : float, optional
        Linear actuators: the same in mm (default 10) and mm/s (default 20). The pair for
        the other kind of actuator is refused (a ConfigError): it would be ignored.
    rate_hz : float, optional
        The pipeline's rate and the drive's frame rate, Hz. Default: the URL's ``rate``
        (100 Hz when it has none); a URL rate that differs is refused.
    echo : callable, optional
        Prints a line (default: stdout).
    stop : StopRequest, optional
        Raised to stop the test (a new one, routed from the stop signals, when not given).

    Returns
    -------
    list of str
        The lines printed.
    """
    from motionbase.commanding import CommandPipeline, SweepSource
    from motionbase.console import tell
    from motionbase.io.motor_output import check_sendable, mapping_for, open_output
    from motionbase.platform.robot import Robot, load_geometry, names_planar_robot, robot_spec

    echo = echo or tell  # (a closed terminal or pipe neither stops nor crashes the test)
    lines: list[str] = []

    def say(s: str) -> None:
        lines.append(s)
        echo(s)

    with stop_on_signals(stop) as stop:  # first: a stop during start-up parks too
        if isinstance(platform, Robot):
            robot = platform
        else:  # a robot, preset or file of either mode: output has no --planar
            name, geometry = load_geometry(platform, planar=names_planar_robot(platform))
            robot = robot_spec(name).make(geometry)
        linear = robot.actuator_unit == "m"
        unit, scale = ("mm", 1e-3) if linear else ("deg", math.radians(1.0))
        other = (range_deg, speed_deg_s) if linear else (range_mm, speed_mm_s)
        if any(v is not None for v in other):
            given, kind, instead = (
                ("--range-deg/--speed-deg-s", "linear", "--range-mm/--speed-mm-s")
                if linear
                else ("--range-mm/--speed-mm-s", "rotary", "--range-deg/--speed-deg-s")
            )
            raise ConfigError(
                f"{given}: the {robot.name} platform's actuators are {kind}; give {instead} instead"
            )
        rng, speed, defaults = (
            (range_mm, speed_mm_s, (10.0, 20.0))
            if linear
            else (range_deg, speed_deg_s, (5.0, 10.0))
        )
        rng = defaults[0] if rng is None else rng
        speed = defaults[1] if speed is None else speed
        mapping = mapping_for(robot)
        # ramped at the drive within the robot's limits, as fly --output's drives are: a
        # drive back from an outage moves on from its last frame, one gone for good is
        # waited for at the end and said not to be parked (not open yet: opened to run)
        sink = open_output(url, mapping, rate_hz=rate_hz, limits=robot.limits)
        rate_hz = sink.rate_hz  # (the URL's when not given; the pipeline's = the frames')
        pipeline = CommandPipeline(robot, rate_hz=rate_hz, mode="actuators")

        carried = [i for i in range(robot.n) if i in sink.format.axes]
        sweep = SweepSource(
            robot, range_=rng * scale, speed=speed * scale, rate_hz=rate_hz,
            lead_s=pipeline.soft_start_s, stop=stop, motors=carried,
        )  # fmt: skip
        told = ""  # the stop said so far
        moving = 0  # the motor being swept (0: none, on the way from or to park)

        def on_tick(out: PipelineOutput) -> None:
            # The lines are the loop's progress display, never the source's business: one
            # that cannot be printed does not stop the sweep (run() drops a failing display)
            nonlocal told, moving
            motor = getattr(out.state, "info", None)  # (None: held after a stop, or parking)
            if motor is not None and motor != moving:
                moving = motor
                if motor:
                    say(_sweep_line(mapping, sweep.neutral, motor - 1, rng, unit, scale, robot))
                else:
                    say("moving from neutral back to park")
            if stop and out.phase in ("stopping", "parked"):
                why = stopped_by(stop.reason or "a stop request", stop)  # (fly's words)
                if why != told:  # the stop, then an E-stop if one comes
                    told = why
                    how = "moving back to park"
                    if stop.estop:
                        how = "heading for park at once, within the limits"
                    say(f"output test stopped by {why}: {how}")

        check_sendable(sink, robot)
        _check_sweep_sendable(sink, sweep.neutral, rng, unit, scale, carried)
        say(f"output test on {sink.label}: {mapping.describe()}")
        unsent = [str(i + 1) for i in range(robot.n) if i not in carried]
        if unsent:  # (one of two boards: motors 4..6 seemed miswired as nothing moved)
            say(
                f"motors {', '.join(unsent)} are in no field of this output's format: they are "
                "not swept here (check them through the output that carries them)"
            )
        say(f"moving from park to neutral at up to {sweep.speed / scale:.1f} {unit}/s")
        with sink:
            run(pipeline, sweep, [sink], paced=True, stop=stop, progress=on_tick)
        say(sink.stats_line())
        return lines


def _check_sweep_sendable(
    sink: Any, neutral: np.ndarray, rng: float, unit: str, scale: float, motors: list[int]
) -> None:
    """A ConfigError unless the drive can be sent each end of each swept actuator's sweep
    (``motors``, 0-based): one outside the drive range or the frame's fields would be held,
    and the actuator would stop short of it, the check silently not showing the move it
    says it makes."""
    option = "--range-mm" if unit == "mm" else "--range-deg"
    for i in motors:
        for side in (1.0, -1.0):
            q = np.array(neutral, dtype=float)
            q[i] += side * rng * scale
            values = sink.mapping.to_drive(q)
            if (
                not sink.mapping.in_range(values).all()
                or sink.format.encode(values.tolist()) is None
            ):
                raise ConfigError(
                    f"output {sink.url!r}: motor {i + 1} at {side * rng:+g} {unit} from neutral "
                    f"is drive value {values[i]:g}, which the drive range "
                    f"{sink.mapping.drive_min[i]:g}..{sink.mapping.drive_max[i]:g} or the frame "
                    f"format {sink.format.describe()!r} cannot carry: choose a smaller {option}"
                )


def _sweep_line(
    mapping: Any, neutral: np.ndarray, i: int, rng: float, unit: str, scale: float, robot: Any
) -> str:
    """What the sweep of actuator ``i`` (0-based) does, with its drive values."""
    from motionbase.platform.robot import robot_spec

    up, dn = neutral.copy(), neutral.copy()
    up[i] += rng * scale
    dn[i] -= rng * scale
    d0, d1, d2 = (float(np.round(mapping.to_drive(a)[i], 6)) + 0.0 for a in (neutral, up, dn))
    if robot.actuator_unit == "m":
        what, sense = "length", "longer"
    elif robot_spec(robot.name).planar:  # (joint angles grow counterclockwise in the base
        # frame, whose motors 1, 2, 3 at (0, 0), (L, 0), (L/2, L sqrt(3)/2) go round that way)
        what, sense = "arm", "turning the way motors 1, 2, 3 go round the base"
    else:
        what, sense = "crank", "tip up"
    return (
        f"motor {i + 1}: {what} +{rng:g} {unit} ({sense}), -{rng:g} {unit}, back to neutral; "
        f"drive value {d0:g} -> {d1:g} -> {d2:g} -> {d0:g}"
    )


def _live_address(live: str | None) -> Any:
    """``--live [HOST:]PORT`` checked before anything opens (None when not asked)."""
    from motionbase.io.mcap_log import LiveAddress

    return None if live is None else LiveAddress.parse(live)


def _check_duration(duration_s: float | None) -> None:
    if duration_s is not None and not (duration_s > 0 and math.isfinite(duration_s)):
        raise ConfigError(f"--duration must be a positive number of seconds, got {duration_s}")


def fly(
    script: str = "c1723",
    *,
    platform: str | None = None,
    washout: str | None = None,
    cueing: str = "classical",
    planar: bool = False,
    realtime: bool = False,
    busy_wait: bool = False,
    duration_s: float | None = None,
    out: str | Path | None = None,
    progress: bool = True,
    outputs: list[str] | None = None,
    stop: StopRequest | None = None,
    live: str | None = None,
    preview: bool = False,
) -> JobResult:
    """Fly a JSBSim script through the pipeline and log it to MCAP.

    Parameters
    ----------
    script : str
        A script shipped with jsbsim (``c1723``) or a path to a script file.
    platform, washout : str, optional
        Presets or TOML paths (see :func:`load_config`; ``washout`` is the cueing's
        parameters, ``--params``).
    cueing : str
        The cueing plug-in (``--cueing``).
    planar : bool
        Drive the 3-RRR robot.
    realtime : bool
        Fly in real time: the pipeline's loop paces the ticks at the script's rate on the
        wall clock (never by the simulation's times, never bursting to catch up).
    busy_wait : bool
        With ``realtime`` or ``outputs``: wait for each tick by busy-waiting instead of
        sleeping (one processor at 100 %, fewer late ticks; :mod:`motionbase.pacing`).
    duration_s : float, optional
        Stop after this much simulated time, s.
    out : path, optional
        Output file; default ``recordings/<script>.mcap`` (``<script>_planar`` in planar mode).
    outputs : list of str, optional
        Motor-drive output URLs (:func:`motionbase.io.motor_output.open_output`). With them
        the flight runs in real time, paced by the pipeline's loop at the script's rate
        (never by the simulation's times, never bursting to catch up).
    stop : StopRequest, optional
        The run's stop request, when the caller routes the stop signals to it itself (the
        command line); by default the job does so from its start.
    live : str, optional
        ``[HOST:]PORT``: serve the log's topics to Foxglove while flying (needs ``realtime``).
    preview : bool
        Offline mode of a cueing that looks ahead (``--cueing mpc``): the script is flown
        once ahead (JSBSim is deterministic) and the cueing is given the whole reference.
        Not with ``realtime`` or ``outputs`` (a live flight has no known future).
    """
    from motionbase.io.jsbsim_source import JsbsimSource

    with stop_on_signals(stop, stop_signals_for(bool(outputs))) as stop:
        _check_duration(duration_s)
        if busy_wait and not (realtime or outputs):
            raise ConfigError("--busy-wait paces a real-time flight: add --realtime")
        if live is not None and not realtime:
            raise ConfigError("--live shows the flight as it happens: add --realtime")
        if preview and (realtime or outputs):
            raise ConfigError(
                "--preview looks at the flight's future: a real-time flight (--realtime, "
                "--output) has none; drop --preview or fly offline"
            )
        live_at = _live_address(live)
        name = Path(script).stem
        out_path = (
            Path(out)
            if out is not None
            else RECORDINGS / f"{name}{'_planar' if planar else ''}.mcap"
        )
        # a real-time flight is paced by the pipeline's loop (the source never waits)
        source = JsbsimSource(script, duration_s=duration_s)
        refuse_out_over_inputs(
            out_path,
            ("script", source.script_path),
            ("--platform", platform),
            ("--params", washout),
        )
        from motionbase.pipeline import check_rate

        # the script's time step sets the pipeline's rate: a bad one names the script, and
        # before JSBSim loads it (a dt of 1e-9 s alone held JSBSim's load for 20-30 s)
        where = f"{source.script_path or script}: its <run dt> ({1 / source.rate_hz:g} s)"
        check_rate(source.rate_hz, where)
        if duration_s is not None and duration_s * source.rate_hz + 1e-6 < 1.0:
            raise ConfigError(  # (no sample: nothing would be flown)
                f"--duration {duration_s:g} s is shorter than one sample of the script "
                f"({1 / source.rate_hz:g} s): give at least that"
            )
        with source:
            config = load_config(
                planar=planar,
                platform=platform,
                washout=washout,
                cueing=cueing,
                rate_hz=source.rate_hz,
            )
            _refuse_out_over_cueing_files(out_path, config)
            reference = None
            if preview:
                from motionbase.io.manoeuvres import preview_reference

                _check_preview(config.cueing)
                with JsbsimSource(script, duration_s=duration_s) as ahead:
                    reference = preview_reference(ahead, stop, config.input_limits)
            return _drive(
                f"flew {name} on the {robot_title(config)}",
                config,
                source,
                out_path,
                paced=realtime,
                busy_wait=busy_wait,
                progress=progress,
                outputs=outputs,
                stop=stop,
                live=live_at,
                preview=reference,
            )


def replay(
    path: str | Path,
    *,
    out: str | Path | None = None,
    check: bool = False,
    platform: str | None = None,
    washout: str | None = None,
    cueing: str | None = None,
    planar: bool | None = None,
    progress: bool = True,
    outputs: list[str] | None = None,
    stop: StopRequest | None = None,
    live: str | None = None,
    preview: bool | None = None,
) -> JobResult:
    """Re-run the pipeline on a recording's aircraft states, with its recorded configuration.

    Parameters
    ----------
    path : path
        The recording (``.mcap``); a truncated file replays what survived.
    out : path, optional
        Write the replay's own log here.
    check : bool
        Compare every output with the recording; the result is ``failed`` with a
        report of the largest difference per topic when they differ, and when a stop
        ended the replay early (nothing was compared).
    platform, washout, cueing, planar : optional
        Override the recorded configuration (the cueing then defaults to ``classical``).
    outputs : list of str, optional
        Motor-drive output URLs. With them the replay runs in real time, paced by the
        pipeline's loop at the configured rate; the recording's own times never pace it
        (a jump or a gap in them is the validation stage's business). They need
        ``platform``: motors are driven only with the limits of the user's own geometry,
        never with the geometry stored in a recording.
    stop : StopRequest, optional
        As for :func:`fly`.
    live : str, optional
        ``[HOST:]PORT``: serve the replay's topics to Foxglove; the replay then runs in real
        time, paced by the pipeline's loop like a replay to drives.
    preview : bool, optional
        The cueing sees the whole recording ahead (``--cueing mpc``; the recording's
        aircraft states are read first). Default: as the recording was made.

    Raises
    ------
    ConfigError
        ``out`` is the recording itself; ``outputs`` without ``platform``; a recorded
        configuration with wrong, non-finite or inverted limits.
    """
    with stop_on_signals(stop, stop_signals_for(bool(outputs))) as stop:
        return _replay(
            path, out=out, check=check, platform=platform, washout=washout, cueing=cueing,
            planar=planar, progress=progress, outputs=outputs, stop=stop, live=live,
            preview=preview,
        )  # fmt: skip


def _replay(
    path: str | Path,
    *,
    out: str | Path | None,
    check: bool,
    platform: str | None,
    washout: str | None,
    cueing: str | None,
    planar: bool | None,
    progress: bool,
    outputs: list[str] | None,
    stop: StopRequest,
    live: str | None,
    preview: bool | None = None,
) -> JobResult:
    from motionbase.io.mcap_source import RECORDED_STOP, McapSource, read_messages

    src_path = Path(path)
    if out is not None and same_file(src_path, out):
        raise ConfigError(
            f"--out {out} is the recording being replayed ({src_path}): writing it would destroy "
            "it; give another file"
        )
    if out is not None:
        refuse_out_over_inputs(out, ("--platform", platform), ("--params", washout))
    if outputs and platform is None:
        raise ConfigError(
            "replay --output drives motors: give --platform with your own geometry (preset or "
            "TOML); a recording's stored geometry and limits never drive motors"
        )
    live_at = _live_address(live)
    with McapSource(src_path) as source:
        recorded = source.metadata.get("pipeline_config") if source.metadata else None
        if recorded is not None and not isinstance(recorded, dict):
            raise ConfigError(f"{src_path}: metadata: 'pipeline_config' is not a table")
        asked = (platform, washout, planar, cueing)
        if recorded is not None and all(x is None for x in asked):
            config = PipelineConfig.from_dict(recorded, source=f"{src_path}: metadata")
        else:
            from motionbase.platform.robot import ROBOTS, robot_named

            spec = ROBOTS.get((recorded or {}).get("robot"))  # type: ignore[arg-type]
            base_planar = (spec is not None and spec.planar) if planar is None else planar
            named = robot_named(platform)
            if planar is None and named is not None:  # the robot asked for, in its own mode
                base_planar = ROBOTS[named].planar
            if platform is None and spec is not None and spec.planar == base_planar:
                platform = None if spec.planar else spec.name  # the recorded robot's default
            _check_recorded_rate(src_path, source)
            recorded_cueing = (recorded or {}).get("cueing")
            if not isinstance(recorded_cueing, str):
                recorded_cueing = "classical"
            config = load_config(
                planar=base_planar,
                platform=platform,
                washout=washout,
                cueing=cueing or recorded_cueing,  # the recorded cueing unless given
                rate_hz=source.rate_hz,
            )
            key = PipelineConfig.cueing_params_key(recorded or {})
            kept = (recorded or {}).get(key)
            if kept is not None and washout is None and config.cueing == recorded_cueing:
                # and its parameters: another platform alone must not bring another set (a
                # recording of --params gentle replayed to motors with --platform got the
                # platform's tuned default, harder, without a word). Only they are read:
                # the recorded geometry is not the one asked for.
                from motionbase.washout.cueing import cueing_spec

                params = cueing_spec(config.cueing).params_type.from_dict(
                    kept, source=f"{src_path}: metadata: {key}"
                )
                config = replace(config, cueing_params=params)
        why = source.unusable_with(config.input_limits)
        if why:
            raise LogFormatError(
                f"{src_path}: none of its {source.count} aircraft states can be used, each is "
                f"malformed, not finite or beyond the input limits ({why}); nothing to replay "
                "(a state needs a time t, s, and specific_force, angular_velocity and attitude, "
                "3 numbers each, SI units)"
            )
        if out is not None:
            _refuse_out_over_cueing_files(out, config)
        as_recorded = preview is None
        if as_recorded:  # as recorded, unless the configuration was overridden
            same = recorded is not None and all(x is None for x in asked)
            preview = same and bool((source.metadata or {}).get("preview"))
        reference = None
        if preview:
            from motionbase.io.manoeuvres import preview_reference

            try:
                _check_preview(config.cueing)
            except ConfigError:
                if not as_recorded:
                    raise
                raise ConfigError(
                    f"{src_path}: its metadata says it was made with --preview, which its "
                    f"{config.cueing} cueing does not use: the metadata is wrong (replay it "
                    "with --cueing or --params given, which makes no preview)"
                ) from None
            reference = preview_reference(source, stop, config.input_limits)  # one read more
        source.reproduce_stop(stop)  # a run stopped while its source went on stops here too
        notes = []
        if recorded is None:
            notes.append(f"{src_path}: no recorded configuration; used the defaults")
        # (a truncated recording: the source itself warns, for every command that reads it)
        # the check's reading of the recording, before anything moves: one it cannot read
        # (a topic that is not JSON, say) is refused before the replay, not after it
        from motionbase.io.mcap_log import LOG_FORMAT

        if check and source.log_format not in (None, "1", LOG_FORMAT):
            raise ConfigError(
                f"{src_path}: log format {source.log_format!r} (motionbase "
                f"{source.version or 'unsaid'}); this motionbase ({__version__}) writes format "
                f"{LOG_FORMAT} and cannot check it: check it with the version that made it"
            )
        recording = read_messages(src_path) if check else {}  # (its format's topics known)
        tmp = None
        out_path = Path(out) if out is not None else None
        if (check or live_at is not None) and out_path is None:  # a live view needs a log
            tmp = tempfile.TemporaryDirectory(prefix="motionbase-replay-")
            out_path = Path(tmp.name) / "replay.mcap"
        try:
            result = _drive(
                f"replayed {src_path.name}",
                config,
                source,
                out_path,
                paced=bool(outputs) or live_at is not None,
                progress=progress,
                outputs=outputs,
                stop=stop,
                live=live_at,
                preview=reference,
            )
            result.notes.extend(notes)
            if source.malformed:
                result.notes.append(
                    f"warning: {src_path}: {source.malformed} malformed aircraft states rejected "
                    f"and held (first: {source.first_malformed})"
                )
            # (the stop the recording holds is reproduced, and compared; a user's is not)
            if check and stop and (stop.reason != RECORDED_STOP or stop.estop):
                # a part of the recording only: nothing to compare it with
                why = stop.estop_reason if stop.reason == RECORDED_STOP else stop.reason
                result.notes.append(f"check: not made, the replay was stopped ({why})")
                result.failed = True
            elif check and not out_path.exists():  # (the log removed during the run: warned)
                result.notes.append("check: not made, the replay's log is gone")
                result.failed = True
            elif check:
                if source.log_format in (None, "1"):  # its /tf: the pose alone (see below)
                    origin = getattr(config.geometry, "platform_origin", None)
                    if origin is not None:
                        recording = _tf_at_platform_origin(recording, origin)
                report = compare_recordings(recording, read_messages(out_path))
                result.notes.extend(report.lines())
                result.failed = not report.identical
                health = (recording.get("/health") or [{}])[-1]
                if result.failed and isinstance(health, dict) and health.get("estops"):
                    result.notes.append(
                        "  (the recorded run was E-stopped: a replay stops where the recording "
                        "did, but the log does not say at which tick the E-stop came, so it is "
                        "not reproduced)"
                    )
            if tmp is not None:
                result.out = None
        finally:
            if tmp is not None:
                tmp.cleanup()
    return result


def _check_recorded_rate(path: Path, source: Any) -> None:
    """A ConfigError naming the recording when the rate it gives (its configuration's, or
    its messages' spacing) is one the pipeline cannot tick at."""
    from motionbase.pipeline import MIN_RATE_HZ, check_rate

    try:
        check_rate(source.rate_hz)
    except ConfigError:
        spacing = source.rate_from.startswith("the spacing")
        raise ConfigError(
            f"{path}: {source.rate_from} gives rate_hz {source.rate_hz:g}, "
            + (f"below {MIN_RATE_HZ:g} Hz" if source.rate_hz < MIN_RATE_HZ else "above 10 kHz")
            + ", which no pipeline ticks at; "
            + (
                "MCAP log times are nanoseconds (a recording in other units, or at a few "
                "samples a second, cannot be replayed)"
                if spacing
                else "the recorded rate is wrong, so the recording cannot be replayed"
            )
        ) from None


class StatusLine:
    """A live one-line status of a streaming run (terminal only), at most 5 times a second.

    Shows the message rate, the age of the last sample, clamping and the watchdog state.
    """

    def __init__(self, source: Any, stream=None, min_interval_s: float = 0.2) -> None:
        self.source = source
        self.stream = stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.min_interval = min_interval_s
        self._next = 0.0
        self._clamped = 0
        self._ticks = 0

    def __call__(self, out: PipelineOutput) -> None:
        self._ticks += 1
        self._clamped += out.clamped
        if not self.enabled:
            return
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + self.min_interval
        stats = self.source.stats
        watchdog = "ok" if out.fade == 1.0 else ("FADED" if out.fade == 0.0 else "fading")
        self.stream.write(
            f"\r{out.t:8.1f} s  {stats.message_rate_hz:6.0f} msg/s  "
            f"age {1000 * self.source.sample_age_s:6.0f} ms  "
            f"clamped {100 * self._clamped / self._ticks:5.1f} %  watchdog {watchdog:<6} "
            f"{out.phase:<9}"
        )
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()


class PlanarServoOutput:
    """Sink sending the planar robot's safe servo degrees over the thesis's serial protocol."""

    def __init__(self, url: str) -> None:
        from motionbase.io.serial_link import ServoSerialSink

        self.link = ServoSerialSink(url)

    def __enter__(self) -> PlanarServoOutput:
        self.link.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.link.close()

    def write(self, out: PipelineOutput) -> None:
        self.link.write(out.servo_deg, t=out.t)


def stream(
    mavlink: str | None = None,
    *,
    sysid: int | None = None,
    compid: int | None = None,
    signing_key: str | Path | None = None,
    rate_hz: float = 100.0,
    platform: str | None = None,
    washout: str | None = None,
    cueing: str = "classical",
    planar: bool = False,
    serial: str | None = None,
    duration_s: float | None = None,
    out: str | Path | None = None,
    realtime: bool = True,
    busy_wait: bool = False,
    progress: bool = True,
    outputs: list[str] | None = None,
    source_url: str | None = None,
    stop: StopRequest | None = None,
    live: str | None = None,
    preview: bool = False,
) -> JobResult:
    """Drive the platform from live MAVLink telemetry (or a .tlog/.bin log) until Ctrl-C.

    Parameters
    ----------
    mavlink : str, optional
        A pymavlink connection string (default ``udpin:127.0.0.1:14550``; ``udpout:``,
        ``tcp:``, a serial device) or a ``.tlog``/``.bin`` log file; not with
        ``source_url``.
    sysid, compid : int, optional
        MAVLink: accept messages from this system (default 1) and component (default:
        every one) only. Refused with ``source_url``.
    signing_key : path, optional
        MAVLink 2 signing key file; unsigned or badly signed messages are rejected.
    rate_hz : float
        Pipeline rate, Hz (the stream is resampled to it by holding the latest sample).
    platform, washout, cueing, planar :
        As for :func:`fly`, but the classical washout's parameters default to the
        ``telemetry`` preset (an input low-pass for sparse telemetry and the gentle gains:
        real flights stay inside the platform's reach).
    serial : str, optional
        Planar mode: a pyserial URL of the 3-RRR's Arduino. Its servos are motors: a log
        file then replays in real time, as with ``outputs`` (``realtime`` aside).
    duration_s : float, optional
        Stop (and park) after this long, s.
    out : path, optional
        MCAP log; default ``stream-<UTC time>.mcap`` in :func:`user_recordings_dir`.
    realtime : bool
        For log files: replay at the recorded timing (True) or as fast as possible (False,
        refused for a live source).
    busy_wait : bool
        Wait for each tick by busy-waiting instead of sleeping (see :func:`fly`).
    outputs : list of str, optional
        Motor-drive output URLs (see :func:`fly`). A log file then replays in real time,
        paced by the pipeline's loop (``realtime`` aside).
    source_url : str, optional
        A simulator instead of MAVLink: ``fgnative:udp:HOST:PORT`` (FlightGear) or
        ``xplane:HOST:PORT`` (X-Plane), see :func:`motionbase.io.sources.open_live_source`.
    stop : StopRequest, optional
        As for :func:`fly`.
    live : str, optional
        ``[HOST:]PORT``: serve the log's topics to Foxglove while streaming.
    preview : bool
        Refused (a ConfigError): a live source has no future to preview.
    """
    if preview:
        raise ConfigError(
            "--preview looks at the flight's future: a live stream has none; drop --preview "
            "(replay a recording with --preview instead)"
        )
    with stop_on_signals(stop, stop_signals_for(bool(outputs or serial))) as stop:
        return _stream(
            mavlink, sysid=sysid, compid=compid, signing_key=signing_key, rate_hz=rate_hz,
            platform=platform, washout=washout, cueing=cueing, planar=planar, serial=serial,
            duration_s=duration_s, out=out, realtime=realtime, busy_wait=busy_wait,
            progress=progress, outputs=outputs, source_url=source_url, stop=stop, live=live,
        )  # fmt: skip


def _stream(
    mavlink: str | None,
    *,
    sysid: int | None,
    compid: int | None,
    signing_key: str | Path | None,
    rate_hz: float,
    platform: str | None,
    washout: str | None,
    cueing: str,
    planar: bool,
    serial: str | None,
    duration_s: float | None,
    out: str | Path | None,
    realtime: bool,
    busy_wait: bool,
    progress: bool,
    outputs: list[str] | None,
    source_url: str | None,
    stop: StopRequest,
    live: str | None,
) -> JobResult:
    from motionbase.io.sources import open_live_source, stats_line

    _check_duration(duration_s)
    if serial and not planar:
        raise ConfigError("--serial drives the planar 3-RRR's Arduino: add --planar")
    if busy_wait and not realtime:
        raise ConfigError("--busy-wait paces the stream in real time: drop --fast")
    live_at = _live_address(live)
    if washout is None and cueing == "classical":
        washout = "telemetry"
    config = load_config(
        planar=planar, platform=platform, washout=washout, cueing=cueing, rate_hz=rate_hz
    )
    if out is None:
        out = user_recordings_dir() / time.strftime("stream-%Y%m%dT%H%M%SZ.mcap", time.gmtime())
    refuse_out_over_inputs(
        out,
        ("--mavlink", mavlink),
        ("--signing-key", signing_key),
        ("--platform", platform),
        ("--params", washout),
    )
    _refuse_out_over_cueing_files(out, config)
    source = open_live_source(
        source_url,
        mavlink=mavlink,
        rate_hz=rate_hz,
        sysid=sysid,
        compid=compid,
        signing_key=signing_key,
        duration_s=duration_s,
        # a log is paced by the pipeline's loop (its source never waits); a live link's
        # ticks come on the wall clock
        realtime=realtime,
        busy_wait=busy_wait,
        stale_timeout_s=config.stale_timeout_s,
        free_port=False,  # a port picked at random is shown nowhere: nothing could send to it
    )
    extra = [PlanarServoOutput(serial)] if serial else []
    with source:
        status = StatusLine(source) if progress else None
        try:
            result = _drive(
                f"streamed {source.url}",
                config,
                source,
                Path(out),
                paced=bool(realtime or serial),  # the board's servos move in real time only
                busy_wait=busy_wait,
                progress=False,
                extra_sinks=extra,
                outputs=outputs,
                on_output=status,
                stop=stop,
                live=live_at,
            )
        finally:
            if status is not None:
                try:
                    status.close()
                except OSError:  # a closed terminal
                    pass
        result.notes.append(stats_line(source))
    return result


# --------------------------------------------------------------------------- replay check


# Fields that depend on the wall clock or the machine, never compared.
_UNCOMPARED = {
    "/health": {"overruns", "overruns_off_cpu", "worst_overrun_s", "late_commands", "worst_late_s"},
    "/cueing/mpc": {"solve_time_s"},  # wall time
}
# Topics drawn from others, compared only when both recordings have them.
_DRAWN = {"/platform/scene"}


@dataclass
class CheckReport:
    """Largest difference per topic between two recordings: a recording (a) and its
    replay (b)."""

    per_topic: dict[str, tuple[int, int, float]]  # topic -> (count a, count b, max |diff|)

    @property
    def identical(self) -> bool:
        return all(a == b and d == 0.0 for a, b, d in self.per_topic.values())

    def lines(self) -> list[str]:
        out = [
            "check: "
            + ("identical to the recording" if self.identical else "DIFFERS from the recording")
        ]
        for topic, (a, b, d) in sorted(self.per_topic.items()):
            if a != b:  # compared over the first min(a, b) messages only
                line = f"  DIFF {topic:<22} {a} messages recorded, {b} replayed"
                if min(a, b):
                    same = "are identical" if d == 0.0 else f"differ by up to {d:.3g}"
                    line += f"; the first {min(a, b)} {same}"
                out.append(line)
                continue
            mark = "ok" if d == 0.0 else "DIFF"
            out.append(f"  {mark:4} {topic:<22} messages {a} vs {b}, largest difference {d:.3g}")
        return out


def _max_diff(a: Any, b: Any, skip: set[str]) -> float:
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        keys = (set(a) | set(b)) - skip
        return max((_max_diff(a.get(k), b.get(k), set()) for k in keys), default=0.0)
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return math.inf
        return max((_max_diff(x, y, set()) for x, y in zip(a, b, strict=True)), default=0.0)
    if isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or isinstance(b, str):
        return 0.0 if a == b else math.inf
    if a is None or b is None:
        return 0.0 if a is b else math.inf
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        if a == b:  # (also the same infinity, whose difference is NaN)
            return 0.0
        try:
            if math.isnan(a) or math.isnan(b):  # NaN against NaN: the same value, bit for bit
                return 0.0 if math.isnan(a) and math.isnan(b) else math.inf
            return float(abs(a - b))
        except OverflowError:  # an integer beyond any float (a crafted file)
            return math.inf
    return 0.0 if a == b else math.inf


def _tf_at_platform_origin(recording: dict[str, list[dict]], origin: Any) -> dict[str, list[dict]]:
    """A recording of log format "1" with its ``/tf`` written as the log writes it now.

    Format "1" gave the ``platform`` frame the pose's displacement alone as its translation,
    which put it ``neutral_height`` below the platform; the writer now adds the platform's
    origin at neutral (:class:`~motionbase.io.mcap_log.McapLogger`'s ``platform_origin``),
    the same sum done here, so a replay of an older recording still compares bit for bit.
    """
    ox, oy, oz = (float(v) for v in origin)
    tfs = []
    for m in recording.get("/tf", []):
        tr = m.get("translation") if isinstance(m, dict) else None
        if isinstance(tr, dict) and m.get("child_frame_id") == "platform":
            x, y, z = tr.get("x"), tr.get("y"), tr.get("z")
            if all(isinstance(v, int | float) and not isinstance(v, bool) for v in (x, y, z)):
                m = {**m, "translation": {"x": ox + x, "y": oy + y, "z": oz + z}}
        tfs.append(m)
    return {**recording, "/tf": tfs} if "/tf" in recording else recording


def compare_recordings(a: Mapping[str, list[dict]], b: Mapping[str, list[dict]]) -> CheckReport:
    """Compare the messages of two recordings topic by topic (``/health`` timing excluded)."""
    per_topic = {}
    # the scene is drawn from /platform/pose and /platform/actuators (compared): a recording
    # made before /platform/scene existed has none, which is no difference
    drawn = {t for t in _DRAWN if t not in a or t not in b}
    for topic in sorted((set(a) | set(b)) - drawn):
        ma, mb = a.get(topic, []), b.get(topic, [])
        skip = _UNCOMPARED.get(topic, set())
        if topic == "/health":
            # health records are written once per second: compare only the last counts
            ma, mb = ma[-1:], mb[-1:]
        d = max((_max_diff(x, y, skip) for x, y in zip(ma, mb, strict=False)), default=0.0)
        per_topic[topic] = (len(ma), len(mb), d)
    return CheckReport(per_topic)


# --------------------------------------------------------------------------- omct


def omct(
    out: str | Path,
    *,
    platform: str | None = None,
    washout: str | None = None,
    cueing: str = "classical",
    planar: bool = False,
    rate_hz: float = 120.0,
    scale: float = 1.0,
    progress: bool = True,
    preview: bool = False,
) -> Any:
    """The objective motion cueing test (``motionbase omct``) into the folder ``out``.

    Parameters
    ----------
    out : path
        Folder for ``omct.json``, ``table.md``, ``table.txt`` and the Bode plots (created).
    platform, washout, cueing, planar :
        As for :func:`fly` (``washout``: the cueing's parameters, preset or TOML file).
    rate_hz : float
        Pipeline rate, Hz.
    scale : float
        Every input amplitude times this (1: amplitudes that keep the default cueing on
        ``ceart`` linear, :class:`motionbase.omct.Amplitudes`).
    preview : bool
        Offline mode (``--preview``): the cueing sees each run's whole input first, as
        ``fly --preview`` runs it. Refused (a ConfigError) for a cueing without it.

    Returns
    -------
    motionbase.io.omct_plots.OmctFiles
        Its ``summary_text()`` is what the command prints.
    """
    from motionbase.io.omct_plots import write_omct
    from motionbase.omct import Amplitudes, run_omct

    if not str(out).strip():
        raise ConfigError("--out: empty; give the folder for the test's files (--out omct_ceart)")
    config = load_config(
        planar=planar, platform=platform, washout=washout, cueing=cueing, rate_hz=rate_hz
    )
    if preview:
        _check_preview(cueing)
    amplitudes = Amplitudes().scaled(scale)
    _writable_folder(Path(out), Path(out))  # before the test's minutes, not after them
    options = [
        ("--planar", planar),
        (f"--platform {platform}", platform),
        (f"--cueing {cueing}", cueing != "classical"),
        (f"--params {washout}", washout),
        (f"--rate {rate_hz:g}", rate_hz != 120.0),
        (f"--scale {scale:g}", scale != 1.0),
        ("--preview", preview),
    ]
    command = " ".join(["motionbase omct", *(o for o, on in options if on), f"--out {out}"])
    line = JobProgress() if progress else None

    def tick(done: int, total: int, axis: str, w: float) -> None:
        if line is not None:
            line.show(f"omct: {done}/{total} runs ({axis} at {w:.3g} rad/s)")

    try:
        result = run_omct(
            config, amplitudes=amplitudes, progress=tick, command=command, preview=preview
        )
    finally:
        if line is not None:
            line.close(erase=True)
    return write_omct(result, out)


# --------------------------------------------------------------------------- tune

#: Evaluations of a tuning when neither budget is given (``tune --budget``).
DEFAULT_TUNE_BUDGET = 200


class EvaluationProgress:
    """The progress of a tuning run (evaluations / budget, best cost), as a :class:`JobProgress`.

    ``time_budget_s``: the run's time budget, s, if it has one (the time to go is then the
    sooner of the two ends)."""

    def __init__(
        self, stream=None, every_s: float = 30.0, time_budget_s: float | None = None
    ) -> None:
        self.line = JobProgress(stream, every_s=every_s)
        self._t0 = time.monotonic()
        self._start: float | None = None
        self._time_budget_s = time_budget_s

    def __call__(self, done: int, budget: int | None, best: float) -> None:
        if self._start is None:
            self._start = best
        elapsed = time.monotonic() - self._t0
        ends = []  # seconds to go, and the share done, by each budget
        if budget is not None:
            ends.append((elapsed * (budget - done) / done if done else 0.0, done / budget))
        if self._time_budget_s is not None:
            ends.append((max(0.0, self._time_budget_s - elapsed), elapsed / self._time_budget_s))
        eta, frac = min(ends)
        of = f" / {budget}" if budget is not None else ""
        counts = f"{done:5d}{of} evaluations  best {best:.4f} (start {self._start:.4f})"
        times = f"{elapsed:5.0f} s, about {eta:4.0f} s to go"
        if self.line.terminal:
            frac = min(1.0, frac)
            bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
            self.line.show(f"[{bar}] {counts}  {times}")
        else:
            self.line.show(f"tune: {counts.strip()}, {times.strip()}")

    def close(self) -> None:
        self.line.close()


@dataclass
class TuneResult:
    """What :func:`tune` did: the optimiser's result, the held-out scores, the file written."""

    result: Any  # motionbase.tuning.TuningResult
    holdout: tuple[Any, Any] | None  # SetScore before, after
    out: Path
    wall_time_s: float
    improved: bool
    cueing: str = "classical"
    time_budget_s: float | None = None

    def summary_text(self) -> str:
        from motionbase.tuning import format_table

        r = self.result
        sections = [("tuning set", r.start_score, r.best_score)]
        if self.holdout is not None:
            sections.append(("held out (not tuned on)", *self.holdout))
        found = "tuned" if self.improved else "nothing beat the start set (written as it was)"
        ended = {
            "time": f", ended by the time budget ({duration_text(self.time_budget_s or 0.0)})",
            "converged": ", ended by CMA-ES's own stopping rules",
        }.get(r.ended_by, "")
        return "\n".join(
            [
                f"tune: {r.evaluations} evaluations ({r.generations} CMA-ES generations) in "
                f"{self.wall_time_s:.0f} s{ended}, seed {r.seed}: {found}; score terms in "
                "motionbase.tuning",
                format_table(sections),
                f"wrote {self.out} (motionbase fly"
                + ("" if self.cueing == "classical" else f" --cueing {self.cueing}")
                + f" --params {self.out})",
            ]
        )


def duration_text(seconds: float) -> str:
    """``seconds`` as ``--time-budget`` takes it: ``"8h"``, ``"30m"``, ``"90s"``."""
    for unit, size in (("h", 3600.0), ("m", 60.0)):
        if seconds >= size and seconds % size == 0:
            return f"{seconds / size:g}{unit}"
    return f"{seconds:g}s"


def _writable_folder(folder: Path, given: Path) -> None:
    """Check, creating nothing yet, that ``folder`` is a folder files can be written in, or
    can be made one (the writer creates it, as ``fly --out`` does): a run that takes
    minutes must not fail at its end for want of a folder, and a mistake found later must
    not leave an empty one. ``given``: the ``--out`` value the messages name."""
    from motionbase.io.whole_files import folder_problem

    problem = folder_problem(folder)
    if problem:
        raise ConfigError(f"--out {given}: {problem} (choose another --out path)")


def tune(
    *,
    out: str | Path,
    platform: str | None = None,
    washout: str | None = None,
    cueing: str = "classical",
    scripts: list[str] | None = None,
    recordings: list[str] | None = None,
    holdout: list[str] | None = None,
    budget: int | None = None,
    seed: int = 0,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    stop: StopRequest | None = None,
    profile: str | None = None,
    time_budget_s: float | None = None,
    preview: bool = False,
) -> TuneResult:
    """Tune the washout for a platform over manoeuvres (:mod:`motionbase.tuning`); write it.

    Parameters
    ----------
    out : path
        The washout TOML file to write (``fly --washout FILE`` takes it).
    platform : str, optional
        The platform: a 6-DOF robot's name (``rus6``, ``stewart6``), geometry preset name
        or TOML path (default ``ceart``); a planar robot is refused.
    washout : str, optional
        The start set: the cueing's preset or TOML path (default: its default preset; for
        the MPC, whose sets hold a platform's limits, the one made for ``platform`` where
        one ships: ``seat`` on the stewart6 seat).
    cueing : str
        The cueing algorithm (a name of :data:`~motionbase.washout.cueing.CUEINGS` with
        knobs in :data:`motionbase.tuning.KNOBS_BY_CUEING`: classical, mpc).
    scripts : list of str, optional
        JSBSim scripts, ``NAME`` or ``NAME@START:END``
        (:func:`motionbase.io.manoeuvres.load_script`); default
        :data:`~motionbase.io.manoeuvres.DEFAULT_MANOEUVRES` unless ``recordings`` are given.
    recordings : list of str, optional
        MCAP recordings and MAVLink ``.tlog``/``.bin`` logs, tuned on too.
    holdout : list of str, optional
        Scripts or recordings scored before and after but not tuned on; default
        :data:`~motionbase.io.manoeuvres.DEFAULT_HOLDOUT` (an empty list: none).
    budget : int, optional
        Evaluations of one parameter set over the whole manoeuvre set (>= 1); default
        200, or no limit when ``time_budget_s`` is given.
    seed : int
        CMA-ES seed (>= 0); the same seed and inputs give the same result.
    workers : int, optional
        Local worker processes (default: the processors available; 1: this process); not
        with ``scheduler``.
    scheduler : str, optional
        A Dask distributed scheduler, ``tcp://HOST:PORT``, instead of local processes.
    progress : bool
        Progress bar on stderr (a terminal only).
    stop : StopRequest, optional
        Watched between manoeuvres and evaluations: once set, the evaluations not yet
        started are cancelled and :class:`~motionbase.stopping.Stopped` is raised. When
        the generations completed found a set better than the start, it is written first,
        its header saying "Interrupted" (the exception's ``kept`` names the file);
        otherwise nothing is written.
    profile : str, optional
        Tune this flight-phase profile of the start file (``ground``, ``air``; written as
        the profile's overrides) instead of the file's own values (classical washout).
    time_budget_s : float, optional
        Seconds the tuning may take, from this call (the manoeuvres' loading counted, the
        held-out scoring at the end not): no generation starts that the last one's
        duration says would end after it. With ``budget`` too, the sooner end ends it.
    preview : bool
        Tune for offline runs: the cueing sees each manoeuvre's future (``--preview``; a
        cueing with ``set_preview`` only, the MPC). The set written is for ``fly --preview``
        and ``replay --preview``, not for real-time runs.
    """
    from motionbase import tuning
    from motionbase.io.executors import check_workers, open_evaluator
    from motionbase.io.manoeuvres import (
        DEFAULT_HOLDOUT,
        DEFAULT_MANOEUVRES,
        Manoeuvre,
        load_recording,
        load_spec,
        write_washout,
    )
    from motionbase.platform.robot import load_geometry, names_planar_robot, robot_spec
    from motionbase.platform.rus6_workspace import lacking_axes
    from motionbase.report import robot_reach
    from motionbase.stopping import Stopped, raise_if_stopped
    from motionbase.washout.cueing import cueing_spec

    called = time.monotonic()  # the time budget counts from here
    spec = cueing_spec(cueing)
    knobs = tuning.knobs_for(cueing)
    if preview:
        _check_preview(cueing)
    if workers is not None and scheduler is not None:  # (the workers were ignored)
        raise ConfigError(
            f"--workers {workers} and --scheduler {scheduler}: the evaluations run in local "
            "processes or on a Dask cluster, not both; give one of them"
        )
    if scheduler is None:
        check_workers(workers)  # before the manoeuvres are flown, not after
    if budget is None and time_budget_s is None:
        budget = DEFAULT_TUNE_BUDGET
    if budget is not None and (
        isinstance(budget, bool) or not isinstance(budget, int) or budget < 1
    ):
        raise ConfigError(f"--budget must be a whole number of evaluations >= 1, got {budget!r}")
    if time_budget_s is not None and not (
        isinstance(time_budget_s, int | float) and 0 < time_budget_s < math.inf
    ):
        raise ConfigError(f"--time-budget must be a positive duration, got {time_budget_s!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= tuning.MAX_SEED:
        raise ConfigError(
            f"--seed must be a whole number from 0 to {tuning.MAX_SEED}, got {seed!r}"
        )
    out_path = Path(out)
    if out_path.suffix.lower() != ".toml":
        raise ConfigError(f"--out {out}: the result is a washout TOML file; name it *.toml")
    if os.path.isdir(out_path):  # (pathlib's is_dir raises for a name too long)
        raise ConfigError(f"--out {out} is a folder; give a file name ending in .toml")
    _writable_folder(out_path.parent, out_path)  # before the tuning's minutes, not after them
    platform_name = platform or DEFAULT_RUS6
    if names_planar_robot(platform_name):
        raise ConfigError(
            f"--platform {platform_name}: tune scores 6-DOF platforms; give a 6-RUS or a "
            "Stewart platform (rus6, stewart6, a preset or a TOML path)"
        )
    robot_name, geometry = load_geometry(platform_name)
    robot = robot_spec(robot_name).make(geometry)
    lacking = lacking_axes(robot)
    if lacking:  # the score weighs every axis of the cue against the robot's reach
        raise ConfigError(
            f"--platform {platform_name}: tune scores the cue on all six axes, and the "
            f"{robot_spec(robot_name).description} does not render {', '.join(lacking)}; "
            "tune it on a 6-DOF platform"
        )
    # an MPC set holds its platform's limits, which the tuner leaves as they are: by default
    # it starts from the set made for this geometry where one ships
    made_for = tuned_preset(spec, robot_name, geometry) if cueing == "mpc" else None
    start_name = washout or made_for or spec.default_preset
    start = spec.load_params(start_name)
    fallback = getattr(start, "fallback", None)
    # (--out may be the start set itself, not the geometry nor the start set's fallback)
    refuse_out_over_inputs(
        out_path,
        ("--platform", platform),
        ("start set's solver.fallback", fallback if isinstance(fallback, str) else None),
        writing="the tuned set",
    )
    if profile is not None:
        from motionbase.washout.params import PROFILES

        if profile not in PROFILES:
            raise ConfigError(
                f"--profile {profile}: unknown; a file's profiles are {', '.join(PROFILES)}"
            )
        if not hasattr(start, "with_profile"):
            raise ConfigError(
                f"--profile: the {cueing} cueing's parameter files have no flight-phase "
                "profiles; leave --profile out, or tune a classical washout (--cueing classical)"
            )
    recordings = list(recordings or [])
    scripts = list(DEFAULT_MANOEUVRES if scripts is None and not recordings else scripts or [])
    holdout = list(DEFAULT_HOLDOUT if holdout is None else holdout)
    if not scripts and not recordings:
        raise ConfigError("tune: no manoeuvres; give --scripts NAME,... or --recordings FILE")

    def loaded(load: Callable[[str], Manoeuvre], name: str) -> Manoeuvre:
        raise_if_stopped(stop)  # each JSBSim script takes a second or more to fly
        return load(name)

    manoeuvres = [loaded(load_spec, s) for s in scripts]
    manoeuvres += [loaded(load_recording, r) for r in recordings]
    held = [loaded(load_spec, s) for s in holdout]
    for h in held:
        for m in manoeuvres:
            if h.name == m.name or h.shares_samples_with(m):
                same = "" if h.name == m.name else f" (as {m.name}: the same flight's samples)"
                raise ConfigError(
                    f"--holdout {h.name} is also in the tuning set{same}; a held-out "
                    "manoeuvre must not be tuned on (drop it from one of them)"
                )
    reach = robot_reach(robot)
    problem = tuning.TuningProblem(
        geometry, tuple(manoeuvres), reach, cueing=cueing, robot=robot_name, preview=preview
    )
    held_problem = held_start = None
    if held:  # scored first: a held-out window too short to score is refused before tuning
        held_problem = tuning.TuningProblem(
            geometry, tuple(held), reach, cueing=cueing, robot=robot_name, preview=preview
        )
        held_start = held_problem.evaluate(start)
    bar = None
    t0 = time.monotonic()
    stopped_by = ""  # the reason of a stop after the start set was scored
    try:
        with open_evaluator(
            problem, workers=workers, scheduler=scheduler, stop=stop
        ) as evaluate_many:
            # what the loading and the workers' start (a minute or more on a loaded machine
            # with an empty numba cache) left of the budget: it used to be reckoned before
            # the workers started, and their start-up ran over it
            time_left_s = (
                None
                if time_budget_s is None
                else max(1e-9, time_budget_s - (time.monotonic() - called))
            )
            bar = EvaluationProgress(time_budget_s=time_left_s) if progress else None
            result = tuning.tune(
                start,
                evaluate_many,
                budget=budget,
                seed=seed,
                knobs=knobs,
                on_progress=bar,
                profile=profile,
                time_budget_s=time_left_s,
            )
    except tuning.TuningStopped as exc:  # (a stop before the start was scored passes on)
        result, stopped_by = exc.found, exc.reason
    finally:
        if bar is not None:
            bar.close()
    holdout_scores = None
    if held_problem is not None and not stop:
        holdout_scores = (held_start, held_problem.evaluate(result.best))
    if stop and not stopped_by:  # the budget was spent; the stop came in the held-out scoring
        stopped_by, holdout_scores = stop.reason, None
    improved = result.best is not result.start
    if stopped_by and not improved:
        raise Stopped(stopped_by)  # nothing worth keeping: nothing is written
    wall = time.monotonic() - t0
    description, header = tuning.describe_result(
        result, platform=platform_name, start=start_name, holdout=holdout_scores
    )
    if stopped_by:
        of = f" of {budget}" if budget is not None else ""
        n = result.evaluations
        interrupted = (
            f"interrupted ({stopped_by}) while the held-out manoeuvres were scored, after all "
            f"{n} evaluations"
            if budget is not None and n >= budget
            else f"interrupted ({stopped_by}) after {n}{of} evaluations"
        )
        description += f"; {interrupted}"
        header[:0] = [
            f"I{interrupted[1:]}: the best set so far"
            + (", not scored on the held-out manoeuvres." if held else ".")
        ]
    best = replace(result.best, description=description)
    if hasattr(best, "mode"):  # an MPC set says which mode it was tuned in
        best = replace(best, mode="preview" if preview else "real-time")
    which = " --washout" if cueing == "classical" else f" --cueing {cueing} --params"
    command = [f"motionbase tune --platform {platform_name}{which} {start_name}"]
    command.append(f"--scripts {','.join(scripts)}" if scripts else "--scripts none")
    command += [f"--recordings {' '.join(recordings)}"] if recordings else []
    command.append(f"--holdout {','.join(holdout) or 'none'}")
    command += [f"--budget {budget}"] if budget is not None else []
    command += [f"--time-budget {duration_text(time_budget_s)}"] if time_budget_s else []
    command.append(f"--seed {seed}")
    command += [f"--profile {profile}"] if profile else []
    command += ["--preview"] if preview else []
    if result.ended_by == "time" and not stopped_by:
        header[:0] = [
            f"The time budget ({duration_text(time_budget_s or 0.0)}) ended the tuning after "
            f"{result.evaluations} evaluations: the same command on another machine may find "
            "another set."
        ]
    header[:0] = [
        f"{'Washout' if cueing == 'classical' else cueing.upper() + ' cueing'} parameters "
        f"made by `motionbase tune` (motionbase {__version__}):",
        f"{' '.join(command)} --out {out_path.name}",
    ]
    write_washout(out_path, best, header)
    if stopped_by:
        raise Stopped(
            stopped_by,
            kept=f"kept the best set of {result.evaluations} evaluations in {out_path} "
            f"(cost {result.start_score.cost:.4g} -> {result.best_score.cost:.4g})",
        )
    return TuneResult(
        replace(result, best=best), holdout_scores, out_path, wall, improved, cueing, time_budget_s
    )
