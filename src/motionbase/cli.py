"""The ``motionbase`` command line: parsing only, every action is a library call.

Subcommands: ``fly``, ``stream``, ``replay``, ``teleop``, ``workspace``, ``report``,
``output``, ``tune``.
A user mistake (bad file, bad value) prints one line to stderr and exits with
status 2; it is never a traceback.
"""

from __future__ import annotations

import sys


def _interrupted_at_start(argv: Sequence[str] | None = None) -> int:
    """Ctrl-C while the command was still starting (its imports, the parsing): one line,
    exit 130, as later on. The package imports nothing slow before this module's guard."""
    words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
    print(f"motionbase{' ' + words[0] if words else ''}: interrupted", file=sys.stderr)
    return 130


try:  # numpy and the rest take a few tenths of a second to import
    if __name__ == "__main__":  # python -m motionbase.cli (the command: motionbase.__main__)
        from motionbase.stopping import catch_early_stops  # (the standard library only)

        catch_early_stops()  # a SIGTERM while starting stops the job, not the process
    import argparse
    import functools
    import logging
    import re
    import signal
    from collections.abc import Callable, Sequence

    from motionbase import __version__
    from motionbase.config import DEFAULT_RRR3, DEFAULT_RUS6
    from motionbase.console import tell
    from motionbase.errors import ConfigError, MotionbaseError
    from motionbase.stopping import (
        STOP_SIGNALS,
        Stopped,
        insistent_ctrl_c,
        interrupting_signal,
        keep_what_ctrl_c_cut_short,
        other_signals_as_ctrl_c,
        stop_on_signals,
        stop_signals_for,
    )
except KeyboardInterrupt:
    sys.exit(_interrupted_at_start())

# Each subcommand registers (name, add_arguments, run). ``run(args) -> int``.
_Command = tuple[
    str, str, Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], int]
]
COMMANDS: list[_Command] = []


def command(name: str, help_text: str, add_arguments: Callable[[argparse.ArgumentParser], None]):
    """Decorator registering ``run(args)`` as the subcommand ``name``."""

    def register(run: Callable[[argparse.Namespace], int]):
        COMMANDS.append((name, help_text, add_arguments, run))
        return run

    return register


class _Parser(argparse.ArgumentParser):
    """argparse that exits with status 2 and a one-line message (its default, kept explicit)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        # prog is "motionbase" for the top-level parser, "motionbase fly" for a subcommand
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="motionbase",
        description="Motion-platform middleware for flight simulators: aircraft states from "
        "JSBSim, MAVLink, FlightGear, X-Plane or a recording, through a cueing algorithm "
        "(classical washout or MPC) into a 6-RUS or Stewart platform or a planar 3-RRR "
        "robot, logged to MCAP.",
    )
    parser.add_argument("--version", action="version", version=f"motionbase {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, help_text, add_arguments, run in COMMANDS:
        p = sub.add_parser(name, help=help_text, description=help_text)
        add_arguments(p)
        p.set_defaults(_run=run, _parser=p)
    return parser


class _StderrHandler(logging.StreamHandler):  # type: ignore[type-arg]
    """A handler writing to ``sys.stderr`` as it is at each message, not as it was when the
    handler was made (a caller of ``main`` may have swapped it, and closed the old one)."""

    stream = property(lambda self: sys.stderr, lambda self, value: None)  # type: ignore[assignment]


def _setup_logging() -> None:
    """Warnings of the library (a truncated file, a stale link) as one plain line each."""
    log = logging.getLogger("motionbase")
    if not log.handlers:
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("motionbase: %(levelname)s: %(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.WARNING)
        log.propagate = False


def main(argv: Sequence[str] | None = None) -> int:
    try:
        _setup_logging()
        parser = build_parser()
        args, extra = parser.parse_known_args(argv)
    except KeyboardInterrupt:
        return _interrupted_at_start(argv)
    if extra:  # name the subcommand that does not know them, not the top-level parser
        getattr(args, "_parser", parser).error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        with insistent_ctrl_c():  # jobs that move the platform route the signals to a stop
            _notice_compiling()
            return int(args._run(args) or 0)
    except MotionbaseError as exc:
        tell(f"motionbase {args.command}: error: {exc}", sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        return _interrupted(args.command, exc)
    except Stopped as exc:  # a job that moves nothing, stopped by a signal (tune)
        by = "" if exc.reason == "SIGINT" else f" ({exc.reason})"
        kept = f"; {exc.kept}" if exc.kept else ""
        tell(f"motionbase {args.command}: interrupted{by}{kept}", sys.stderr)
        return exc.exit_status
    except Exception as exc:
        if not _raised_by_ctrl_c(exc):
            raise  # a bug: its traceback is what a bug report needs
        return _interrupted(args.command, exc)


#: Said at a terminal when numba starts compiling (:func:`_notice_compiling`).
COMPILING_NOTICE = (
    "motionbase: compiling for this processor, as the first runs after installing do "
    "(up to a minute); later runs load what they compiled"
)


def _notice_compiling() -> None:
    """At a terminal, one line when numba starts compiling. A fresh installation's first
    runs fill numba's cache, which takes half a minute or more and was silent; later runs
    load it and compile nothing (``tests/test_startup.py``), so they say nothing. Not said
    when stderr is a file or a pipe (a log, a test): there it would only be noise."""
    if not sys.stderr.isatty():
        return
    from numba.core import event

    class Notice(event.Listener):
        said = False

        def on_start(self, _event: event.Event) -> None:
            if not self.said:
                self.said = True
                print(COMPILING_NOTICE, file=sys.stderr, flush=True)

        def on_end(self, _event: event.Event) -> None:
            pass

    event.register("numba:compile", Notice())


def _interrupted(command: str, exc: BaseException) -> int:
    """One line for a command a Ctrl-C ended (or a SIGTERM turned into one); its status.
    ``exc``: what ended it (the frames it cut short are kept, never freed)."""
    keep_what_ctrl_c_cut_short(exc)
    sig = interrupting_signal()
    by = "" if sig == signal.SIGINT else f" ({sig.name})"
    print(f"motionbase {command}: interrupted{by}", file=sys.stderr)
    return 128 + int(sig)


def _moves_nothing(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """A command that moves nothing (a measurement, a plot): SIGTERM, SIGHUP and SIGQUIT
    end it as Ctrl-C does (:func:`~motionbase.stopping.other_signals_as_ctrl_c`)."""

    @functools.wraps(run)
    def wrapped(args: argparse.Namespace) -> int:
        with other_signals_as_ctrl_c():
            return run(args)

    return wrapped


def _raised_by_ctrl_c(exc: BaseException) -> bool:
    """A library turned the KeyboardInterrupt into another error (matplotlib's imports
    do: a Ctrl-C while ``omct`` loads it is a RuntimeError "calling __set_name__")."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


# --- subcommands -----------------------------------------------------------------
# One block per subcommand: an ``_args_<name>`` function adding its arguments and a
# ``run`` function decorated with @command that only calls into the library.


def _screen_size(text: str) -> tuple[int, int]:
    w, _, h = text.lower().partition("x")
    if not (w.isdigit() and h.isdigit() and int(w) > 0 and int(h) > 0):
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, got {text!r}")
    return int(w), int(h)


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def _positive_float(text: str) -> float:
    value = _number(text)
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a positive, finite number, got {text!r}")
    return value


def _non_negative_float(text: str) -> float:
    value = _number(text)
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return value + 0.0  # (-0 is 0)


def _print_result(result) -> int:
    tell(result.summary_text())  # (a closed terminal: the run itself ended properly)
    return 1 if result.failed else 0


def _job(name: str, *args: object, **kwargs: object) -> int:
    """Run a job that moves the platform, with the stop signals routed to it from now on:
    the first one parks the platform at the soft-start pace, a second one E-stops it (Ctrl-Z
    among them when the job drives motors: ``outputs``, a board's ``serial``)."""
    drives = bool(kwargs.get("outputs") or kwargs.get("serial"))
    with stop_on_signals(signals=stop_signals_for(drives)) as stop:
        from motionbase import app

        return _print_result(getattr(app, name)(*args, **kwargs, stop=stop))


#: Options that several subcommands take, by flag (added with :func:`_add_shared`).
_SHARED_OPTIONS: dict[str, dict[str, object]] = {
    "--busy-wait": {
        "action": "store_true",
        "help": "wait for each tick by busy-waiting, not sleeping: one CPU at 100 %%, "
        "fewer late ticks at 1 kHz (real-time runs)",
    },
    "--output": {
        "action": "append",
        "metavar": "URL",
        "help": "send the safe actuator commands (crank angles, or lengths of linear actuators) "
        "to motor drives (repeatable): "
        "serial:/dev/ttyUSB0?baud=250000&rate=500&format=... or udp:HOST:PORT?format=... "
        "(format: text:A{1}B{2}...\\n or bin:0xFFFE,6xi16be*100,sum8@2; see "
        "motionbase.io.motor_output); the run then goes in real time, paced by the pipeline",
    },
    "--live": {
        "metavar": "[HOST:]PORT",
        "help": "also serve every logged topic to Foxglove over WebSocket while running "
        "(host 127.0.0.1 unless given; 0.0.0.0 to watch from another PC; e.g. --live 8765)",
    },
}


def _add_shared(p: argparse.ArgumentParser, *flags: str) -> None:
    """Add the shared options named by their flags (see ``_SHARED_OPTIONS``)."""
    for flag in flags:
        p.add_argument(flag, **_SHARED_OPTIONS[flag])  # type: ignore[arg-type]


def _add_cueing(
    p: argparse.ArgumentParser, *, recorded: bool = False, preview: bool = True
) -> None:
    """``--cueing NAME``, ``--params PRESET|FILE.toml`` (``--washout`` is the same) and,
    with ``preview``, ``--preview``."""
    p.add_argument(
        "--cueing",
        default=None if recorded else "classical",
        metavar="NAME",
        help="the recorded cueing unless given, else classical"
        if recorded
        else "cueing algorithm (default classical)",
    )
    p.add_argument(
        "--params",
        "--washout",
        dest="washout",
        metavar="PRESET|FILE.toml",
        help="override the recorded cueing parameters"
        if recorded
        else "cueing parameters: preset (classical: default, gentle, telemetry, tuned_ceart, "
        "tuned_seat, profiles_example; unless given: the set tuned for the platform, "
        "tuned_ceart on ceart and tuned_seat on seat, else default; stream: telemetry; mpc: "
        "tuned_ceart, the default, seat, the default on the stewart6 seat, ceart, "
        "preview_ceart for --preview) or TOML path",
    )
    if not preview:
        return
    p.add_argument(
        "--preview",
        action="store_true",
        # replay: None, as the recording was made (app.replay), unless given
        default=None if recorded else False,
        help="offline runs (replay; fly without --realtime): the cueing sees the flight's "
        "future (mpc only)" + ("; replay: as recorded unless given" if recorded else ""),
    )


def _pipeline_options(args: argparse.Namespace) -> dict[str, object]:
    """The options ``fly``, ``replay`` and ``stream`` pass on alike: the robot, the cueing,
    the motor drives and the live view."""
    return {
        "platform": args.platform,
        "washout": args.washout,
        "cueing": args.cueing,
        "planar": args.planar,
        "outputs": args.output,
        "live": args.live,
        "preview": args.preview,
    }


def _args_fly(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "script",
        nargs="?",
        default="c1723",
        help="a JSBSim script shipped with jsbsim (e.g. c1723) or a path (default c1723)",
    )
    p.add_argument(
        "--platform",
        help=f"geometry preset or TOML path (default {DEFAULT_RUS6}; {DEFAULT_RRR3} with --planar)",
    )
    _add_cueing(p)
    p.add_argument("--planar", action="store_true", help="drive the planar 3-RRR robot instead")
    p.add_argument("--realtime", action="store_true", help="pace the flight to wall-clock time")
    _add_shared(p, "--busy-wait")
    p.add_argument(
        "--duration", type=_positive_float, metavar="S", help="stop after S simulated seconds"
    )
    p.add_argument("--out", metavar="FILE.mcap", help="log file (default recordings/<script>.mcap)")
    _add_shared(p, "--output", "--live")


@command(
    "fly", "fly a JSBSim script through the washout and the platform, logged to MCAP", _args_fly
)
def run_fly(args: argparse.Namespace) -> int:
    return _job(
        "fly",
        args.script,
        realtime=args.realtime,
        busy_wait=args.busy_wait,
        duration_s=args.duration,
        out=args.out,
        **_pipeline_options(args),
    )


def _args_replay(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="IN.mcap", help="a recording made by motionbase")
    p.add_argument("--out", metavar="OUT.mcap", help="write the replay's log here")
    p.add_argument(
        "--check",
        action="store_true",
        help="compare every output with the recording; exit 1 when they differ",
    )
    p.add_argument("--platform", help="override the recorded geometry (preset or TOML path)")
    _add_cueing(p, recorded=True)
    p.add_argument("--planar", action="store_true", default=None, help="override: drive the 3-RRR")
    _add_shared(p, "--output", "--live")


@command("replay", "re-run the pipeline on a recording's aircraft states", _args_replay)
def run_replay(args: argparse.Namespace) -> int:
    return _job("replay", args.recording, out=args.out, check=args.check, **_pipeline_options(args))


def _args_workspace(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--platform",
        metavar="PRESET|FILE.toml",
        help="a robot (rus6, stewart6: its default geometry), a geometry preset name or a TOML "
        f"path (default: the 6-RUS {DEFAULT_RUS6}); with --planar the 3-RRR (default "
        f"{DEFAULT_RRR3})",
    )
    p.add_argument(
        "--plot",
        metavar="FILE.png|.svg|.pdf",
        help="draw the workspace to this file, in the format its extension names",
    )
    p.add_argument(
        "--planar",
        action="store_true",
        help="the planar 3-RRR robot instead: triple sweep, total workspace and phi = 0 slice",
    )
    p.add_argument(
        "--rrr3",
        metavar="PRESET|FILE.toml",
        help=f"with --planar, the same as --platform: the 3-RRR geometry (default {DEFAULT_RRR3})",
    )


@command(
    "workspace",
    "print the platform's single-axis reach and plot its workspace slices",
    _args_workspace,
)
@_moves_nothing
def run_workspace(args: argparse.Namespace) -> int:
    if args.planar:
        from motionbase.io.planar_plots import planar_workspace_report

        if args.platform and args.rrr3 and args.platform != args.rrr3:
            raise ConfigError(
                f"--platform {args.platform} and --rrr3 {args.rrr3} both name the 3-RRR "
                "geometry with --planar: give one of them"
            )
        from motionbase.platform.robot import names_planar_robot, robot_named

        named = args.rrr3 and not args.platform and robot_named(args.rrr3)
        if named and not names_planar_robot(args.rrr3):
            raise ConfigError(
                f"--rrr3 {args.rrr3}: a 6-DOF platform, not a 3-RRR geometry (give it as "
                "--platform, without --planar)"
            )
        tell(planar_workspace_report(args.platform or args.rrr3, args.plot))
    else:
        from motionbase.io.workspace_plots import workspace_report

        if args.rrr3:
            raise ConfigError(f"--rrr3 {args.rrr3} names a 3-RRR geometry: add --planar")
        tell(workspace_report(args.platform, args.plot))
    return 0


def _args_teleop(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--input",
        default="mouse",
        metavar="mouse|udp:HOST:PORT|file:PATH.csv",
        help="cursor source (default mouse: a Tk window; udp: 'x y' pixel lines; file: t,x,y CSV)",
    )
    p.add_argument(
        "--serial",
        default="none",
        metavar="URL|none",
        help="pyserial URL of the Arduino (/dev/ttyACM0, socket://h:p); default none",
    )
    p.add_argument("--calibration", metavar="PATH.toml", help="cursor calibration (TOML)")
    p.add_argument(
        "--rate",
        type=_positive_float,
        default=50.0,
        metavar="HZ",
        help="loop rate, Hz (default 50)",
    )
    p.add_argument("--out", metavar="FILE.mcap", help="log to this MCAP file")
    p.add_argument("--duration", type=_positive_float, metavar="S", help="stop after S seconds")
    p.add_argument(
        "--rrr3",
        default=DEFAULT_RRR3,
        metavar="PRESET|FILE.toml",
        help=f"3-RRR geometry (default {DEFAULT_RRR3}; the thesis's robot as built: udesc)",
    )
    p.add_argument(
        "--no-clamp",
        action="store_true",
        help="hold unreachable targets instead of clamping them toward home",
    )
    p.add_argument(
        "--deadband",
        type=_non_negative_float,
        default=0.0,
        metavar="PX",
        help="udp input: ignore points closer than PX pixels to the one in use (an eye "
        "tracker's jitter: about four times its standard deviation; 0, the default: off)",
    )
    p.add_argument(
        "--screen",
        type=_screen_size,
        metavar="WxH",
        help="the screen the udp or file pixels are on, without --calibration (default "
        "1310x715); the mouse window's size",
    )
    _add_shared(p, "--live")


@command("teleop", "teleoperate the planar 3-RRR robot from a cursor", _args_teleop)
def run_teleop(args: argparse.Namespace) -> int:
    drives = args.serial not in (None, "none")  # (Ctrl-Z stops the board's servos too)
    # before the slow imports: a stop then is one park tick
    with stop_on_signals(signals=stop_signals_for(drives)) as stop:
        from motionbase.teleop import teleop_job

        stats = teleop_job(
            args.input, serial_url=args.serial, calibration_path=args.calibration,
            rate_hz=args.rate, out=args.out, duration_s=args.duration, geometry=args.rrr3,
            clamp=not args.no_clamp, live=args.live, stop=stop, deadband_px=args.deadband,
            screen_px=args.screen,
        )  # fmt: skip
    tell(
        f"teleop: {stats.ticks} ticks, {stats.frames_sent} serial frames, {stats.clamps} clamped, "
        f"{stats.held} held, {stats.rate_limited} rate-limited, {stats.no_input} without input, "
        f"{stats.stale_ticks} stale, {stats.estops} E-stops (stopped by {stats.stopped_by})"
        + ("; log lost" if stats.log_lost else "")
    )
    return 1 if stats.log_lost else 0  # the run was fine, its log was lost


def _args_stream(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mavlink",
        metavar="URL",
        help="pymavlink connection string or .tlog/.bin file "
        "(default udpin:127.0.0.1:14550, loopback only)",
    )
    p.add_argument(
        "--source",
        metavar="URL",
        help="a simulator instead of MAVLink: fgnative:udp:HOST:PORT (FlightGear) "
        "or xplane:HOST:PORT (X-Plane)",
    )
    p.add_argument("--sysid", type=int, help="MAVLink: accept this system id only (default 1)")
    p.add_argument("--compid", type=int, help="accept this component id only")
    p.add_argument(
        "--signing-key", metavar="FILE", help="MAVLink 2 signing key (32 bytes or 64 hex)"
    )
    p.add_argument(
        "--rate",
        type=_positive_float,
        default=100.0,
        metavar="HZ",
        help="pipeline rate (default 100)",
    )
    p.add_argument("--platform", help="geometry preset or TOML path")
    _add_cueing(p)
    p.add_argument("--planar", action="store_true", help="drive the planar 3-RRR robot")
    p.add_argument("--serial", metavar="URL", help="planar: the Arduino's pyserial URL")
    p.add_argument("--duration", type=_positive_float, metavar="S", help="stop after S seconds")
    p.add_argument("--fast", action="store_true", help="log files: as fast as possible")
    _add_shared(p, "--busy-wait")
    p.add_argument(
        "--out",
        metavar="FILE.mcap",
        help="log file (default ~/.local/share/motionbase/recordings/stream-<time>.mcap, "
        "under $XDG_DATA_HOME when set)",
    )
    _add_shared(p, "--output", "--live")


@command("stream", "drive the platform live from MAVLink, FlightGear or X-Plane", _args_stream)
def run_stream(args: argparse.Namespace) -> int:
    return _job(
        "stream",
        args.mavlink,
        sysid=args.sysid,
        compid=args.compid,
        signing_key=args.signing_key,
        rate_hz=args.rate,
        serial=args.serial,
        duration_s=args.duration,
        out=args.out,
        realtime=not args.fast,
        busy_wait=args.busy_wait,
        source_url=args.source,
        **_pipeline_options(args),
    )


def _args_report(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="FILE.mcap", help="a recording made by motionbase")
    p.add_argument(
        "--out", metavar="DIR", help="folder for the PNGs and summary.txt (default <stem>_report/)"
    )


@command(
    "report",
    "plot a recording's cueing (aircraft vs platform, perceived motion, actuators) with metrics",
    _args_report,
)
@_moves_nothing
def run_report(args: argparse.Namespace) -> int:
    from motionbase.io.report_plots import write_report

    tell(write_report(args.recording, args.out).summary_text())
    return 0


# --- objective motion cueing test (issue 15) ---


def _args_omct(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--platform",
        metavar="PRESET|FILE.toml",
        help=f"geometry preset or TOML path (default {DEFAULT_RUS6}; {DEFAULT_RRR3} with --planar)",
    )
    _add_cueing(p, preview=False)
    p.add_argument(
        "--preview",
        action="store_true",
        help="the cueing's offline mode: it sees each run's whole input first, as fly "
        "--preview runs it (mpc only)",
    )
    p.add_argument(
        "--planar", action="store_true", help="the planar 3-RRR robot (surge, sway, yaw tests)"
    )
    p.add_argument(
        "--rate", type=_positive_float, default=120.0, metavar="HZ", help="pipeline rate (120)"
    )
    p.add_argument(
        "--scale",
        type=_positive_float,
        default=1.0,
        metavar="K",
        help="multiply every input amplitude by K (default 1: small enough for the default "
        "cueing on ceart to stay linear; larger shows where the limits act)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the JSON, tables, PNGs")


@command(
    "omct",
    "objective motion cueing test: gain and phase of the whole chain at 12 frequencies, "
    "against the classical washout's linear response (table, JSON, Bode plots)",
    _args_omct,
)
@_moves_nothing
def run_omct(args: argparse.Namespace) -> int:
    from motionbase import app

    files = app.omct(
        args.out, platform=args.platform, washout=args.washout, cueing=args.cueing,
        planar=args.planar,
        rate_hz=args.rate, scale=args.scale, preview=args.preview,
    )  # fmt: skip
    tell(files.summary_text())
    return 0


# --- motor-drive output (issue 8) ---


def _args_output(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--test",
        metavar="URL",
        required=True,
        help="sweep each motor in turn about neutral through this output URL",
    )
    p.add_argument(
        "--platform",
        default=None,
        help="robot name, geometry preset or TOML path with [output] (default ceart)",
    )
    p.add_argument(
        "--range-deg",
        type=_positive_float,
        help="sweep half-range of a crank, deg (default 5)",
    )
    p.add_argument(
        "--speed-deg-s",
        type=_positive_float,
        help="peak crank speed, deg/s (default 10)",
    )
    p.add_argument(
        "--range-mm",
        type=_positive_float,
        help="sweep half-range of a linear actuator, mm (default 10)",
    )
    p.add_argument(
        "--speed-mm-s",
        type=_positive_float,
        help="peak linear actuator speed, mm/s (default 20)",
    )
    p.add_argument(
        "--rate",
        type=_positive_float,
        default=None,
        help="command and frame rate, Hz (default: the URL's rate, else 100)",
    )


@command(
    "output",
    "check motor wiring and signs: sweep each motor slowly about neutral, one at a time "
    "(Ctrl-C ramps the motors back to park)",
    _args_output,
)
def run_output(args: argparse.Namespace) -> int:
    from motionbase.app import output_test

    output_test(
        args.test,
        args.platform,
        range_deg=args.range_deg,
        speed_deg_s=args.speed_deg_s,
        range_mm=args.range_mm,
        speed_mm_s=args.speed_mm_s,
        rate_hz=args.rate,
    )
    return 0


# --- tuning the cueing (issue 15) ---


def _names(text: str) -> list[str]:
    """``a,b,c`` -> ``["a", "b", "c"]`` (``none`` or nothing: no names)."""
    if text.strip().lower() in ("", "none"):
        return []
    return [part.strip() for part in text.split(",") if part.strip()]


def _whole(minimum: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected a whole number >= {minimum}, got {value}")
        return value

    return parse


def _duration(text: str) -> float:
    """``90``, ``90s``, ``30m``, ``1.5h`` -> seconds."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(s|m|min|h)?\s*", text)
    value = float(match.group(1)) if match else 0.0
    if not value > 0:
        raise argparse.ArgumentTypeError(
            f"expected a duration such as 90s, 30m or 8h, got {text!r}"
        )
    unit = match.group(2) if match else None
    return value * {"m": 60.0, "min": 60.0, "h": 3600.0}.get(unit or "s", 1.0)


def _args_tune(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--platform",
        help=f"a 6-DOF robot (rus6, stewart6), geometry preset or TOML path "
        f"(default {DEFAULT_RUS6})",
    )
    p.add_argument(
        "--cueing",
        default="classical",
        choices=["classical", "mpc"],
        help="cueing algorithm (default classical)",
    )
    p.add_argument(
        "--params",
        "--washout",
        dest="washout",
        metavar="START.toml",
        help="the start set: the cueing's preset or TOML path (default: classical default, "
        "mpc tuned_ceart, seat on the stewart6 seat)",
    )
    p.add_argument(
        "--scripts",
        type=_names,
        action="extend",  # (given twice: both, as --recordings; the first was dropped)
        metavar="NAME,NAME,...",
        help="JSBSim scripts to tune on, NAME or NAME@START:END seconds (default: c1723, "
        "c172_elevator_doublet, rudder_kick, 737_cruise_steady_turn, c172_cross_wind, unless "
        "--recordings are given)",
    )
    p.add_argument(
        "--recordings",
        nargs="+",
        action="extend",
        metavar="FILE",
        help="MCAP recordings or MAVLink .tlog/.bin logs to tune on too",
    )
    p.add_argument(
        "--holdout",
        type=_names,
        action="extend",
        metavar="NAME,...|none",
        help="scripts or recordings scored before and after but not tuned on "
        "(default: b737_runway_new, c172_elevator_doublet@20.5:40)",
    )
    p.add_argument(
        "--budget",
        type=_whole(1),
        metavar="N",
        help="evaluations of one parameter set over all the manoeuvres (default 200; no "
        "limit when only --time-budget is given)",
    )
    p.add_argument(
        "--time-budget",
        type=_duration,
        metavar="DURATION",
        help="time the tuning may take, e.g. 90s, 30m, 8h (no generation starts that would "
        "end after it; with --budget, the sooner end ends it)",
    )
    p.add_argument("--seed", type=_whole(0), default=0, metavar="S", help="seed (default 0)")
    p.add_argument(
        "--preview",
        action="store_true",
        help="tune for offline runs, the cueing seeing each manoeuvre's future (mpc only; "
        "the set is for fly --preview and replay --preview)",
    )
    p.add_argument(
        "--profile",
        metavar="ground|air",
        help="tune this flight-phase profile of the start file (its [profile.NAME] table, "
        "made when the file has none) instead of the file's own values; the manoeuvres' "
        "flight phase decides where it runs",
    )
    p.add_argument(
        "--out", required=True, metavar="FILE.toml", help="cueing parameters TOML to write"
    )
    p.add_argument(
        "--workers",
        type=_whole(1),
        metavar="K",
        help="local worker processes (default: one per processor; 1: no pool)",
    )
    p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run the evaluations on a Dask distributed scheduler (pip install "
        "'motionbase[cluster]')",
    )


@command(
    "tune",
    "tune the washout for a platform over manoeuvres (CMA-ES on perceived-motion error)",
    _args_tune,
)
def run_tune(args: argparse.Namespace) -> int:
    # a stop cancels the evaluations, keeps the best so far (Ctrl-Z suspends: nothing moves)
    with stop_on_signals(signals=STOP_SIGNALS) as stop:
        from motionbase import app

        result = app.tune(
            out=args.out,
            platform=args.platform,
            washout=args.washout,
            cueing=args.cueing,
            scripts=args.scripts,
            recordings=args.recordings,
            holdout=args.holdout,
            budget=args.budget,
            seed=args.seed,
            workers=args.workers,
            scheduler=args.scheduler,
            stop=stop,
            profile=args.profile,
            time_budget_s=args.time_budget,
            preview=args.preview,
        )
    tell(result.summary_text())
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
