"""Manoeuvres for the tuner (aircraft motion read once, kept as arrays) and its output file.

``motionbase tune`` scores every candidate washout over the same manoeuvres, hundreds
of times. Each one is read here once, from a JSBSim script (run headless through
:class:`~motionbase.io.jsbsim_source.JsbsimSource`), an MCAP recording (its
``/aircraft/state`` through :class:`~motionbase.io.mcap_source.McapSource`) or a MAVLink
log (``.tlog``/``.bin`` through :class:`~motionbase.io.mavlink_source.MavlinkSource`,
as fast as it reads), and kept as a :class:`Manoeuvre`: plain arrays, cheap to send to
worker processes or cluster workers. The pipeline rate of a manoeuvre is its source's
(the script's rate, 120 Hz for the shipped ones; the recording's; 100 Hz for MAVLink).

A script is named ``NAME`` or ``NAME@START:END``: the samples from ``START`` to ``END``
seconds of simulated time. Without a window a script in :data:`SCRIPT_WINDOWS` takes its
window from there, any other its first :data:`DEFAULT_SCRIPT_LENGTH_S` seconds.

The default set, in one place: :data:`DEFAULT_MANOEUVRES` (tuning) and
:data:`DEFAULT_HOLDOUT` (held out, to show whether the tuning overfits).

:func:`write_washout` writes the tuner's result: a washout TOML file (the format
:meth:`~motionbase.washout.params.WashoutParams.from_toml` reads) under a comment
header saying how it was made.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from motionbase.config import same_file
from motionbase.errors import ConfigError
from motionbase.io.whole_files import whole_file
from motionbase.safety import InputLimits, input_problem
from motionbase.state import AircraftState
from motionbase.washout.params import STANDARD_GRAVITY, WashoutParams

__all__ = [
    "DEFAULT_HOLDOUT",
    "DEFAULT_MANOEUVRES",
    "DEFAULT_SCRIPT_LENGTH_S",
    "MAVLINK_RATE_HZ",
    "SCRIPT_WINDOWS",
    "Manoeuvre",
    "RECORDING_SUFFIXES",
    "load_manoeuvres",
    "load_recording",
    "load_script",
    "load_spec",
    "parse_script_spec",
    "write_washout",
]

#: File extensions read as recordings (the rest are script names or paths).
RECORDING_SUFFIXES = (".mcap", ".tlog", ".bin")

#: Simulated seconds taken from a script that :data:`SCRIPT_WINDOWS` does not know.
DEFAULT_SCRIPT_LENGTH_S = 60.0
#: Pipeline rate of a MAVLink log, Hz (the stream command's default).
MAVLINK_RATE_HZ = 100.0

#: Windows of the scripts shipped with the ``jsbsim`` package that make good manoeuvres,
#: ``name: (start_s, end_s, what happens)``. The windows leave out JSBSim's trim
#: transients (the state jumps when a script trims), which no aircraft flies.
SCRIPT_WINDOWS: dict[str, tuple[float, float, str]] = {
    "c1723": (0.0, 60.0, "C172 take-off run with a turn on the ground, rotation, climb"),
    "c172_elevator_doublet": (1.5, 20.0, "C172 elevator doublet at 5-7 s (up to 4 g)"),
    "rudder_kick": (0.0, 20.0, "737 rudder kick with aileron, into a sideslipping bank"),
    "737_cruise_steady_turn": (5.5, 35.5, "737 trimmed in a steady 30 deg banked turn"),
    "c172_cross_wind": (0.5, 25.0, "C172 on the ground pitching in a building cross wind"),
    "b737_runway_new": (44.0, 80.0, "737 take-off run and full braking (rejected take-off)"),
}

#: The manoeuvres ``motionbase tune`` and ``benchmarks/bench_cueing.py`` tune over.
DEFAULT_MANOEUVRES: tuple[str, ...] = (
    "c1723",
    "c172_elevator_doublet",
    "rudder_kick",
    "737_cruise_steady_turn",
    "c172_cross_wind",
)
#: Held out of the tuning, scored before and after: the 737's rejected take-off and the
#: C172's aileron doublet (the second half of the doublet script: a roll at up to 69 deg/s).
DEFAULT_HOLDOUT: tuple[str, ...] = ("b737_runway_new", "c172_elevator_doublet@20.5:40")

_ARRAY = re.compile(r"\[\n((?:    [-+0-9.eE]+,\n)+)\]")
_SPEC = re.compile(r"^(?P<name>[^@]+?)(?:@(?P<start>[^:]*):(?P<end>.*))?$")


@dataclass(frozen=True, eq=False)
class Manoeuvre:
    """Aircraft motion at the pilot, sampled at the pipeline rate, as arrays.

    Attributes
    ----------
    name : str
        What to call it in tables (the script spec or the file name).
    source : str
        Where it came from (script path and window, or file path).
    dt : float
        Sample period, s (the pipeline's period for this manoeuvre).
    t : ndarray, shape (N,)
        Sample times, s (the source's clock).
    specific_force : ndarray, shape (N, 3)
        m/s^2, body axes FRD (level flight reads ``(0, 0, -g)``).
    angular_velocity : ndarray, shape (N, 3)
        Body rates, rad/s.
    attitude : ndarray, shape (N, 3)
        Roll, pitch, yaw, rad.
    fresh : ndarray of bool, shape (N,)
        False where a live source's sample was a stale hold (the watchdog fades then).
    on_ground : ndarray of float, shape (N,)
        The flight phase: 1 on the ground, 0 in the air, NaN where the source did not say
        (a flight-phase profiled cueing runs the profile of the phase).
    """

    name: str
    source: str
    dt: float
    t: np.ndarray
    specific_force: np.ndarray
    angular_velocity: np.ndarray
    attitude: np.ndarray
    fresh: np.ndarray = field(default=None)  # type: ignore[assignment]
    on_ground: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        n = np.asarray(self.t).shape[0]
        if self.fresh is None:
            object.__setattr__(self, "fresh", np.ones(n, dtype=bool))
        if self.on_ground is None:
            object.__setattr__(self, "on_ground", np.full(n, np.nan))
        for key in ("t", "specific_force", "angular_velocity", "attitude", "fresh", "on_ground"):
            arr = np.array(getattr(self, key), dtype=bool if key == "fresh" else float)
            arr.flags.writeable = False
            object.__setattr__(self, key, arr)
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ConfigError(f"manoeuvre {self.name}: sample period must be > 0 s, got {self.dt}")
        if n < 3:
            raise ConfigError(
                f"manoeuvre {self.name}: only {n} samples; give a longer window or recording"
            )

    @property
    def rate_hz(self) -> float:
        """Pipeline rate, Hz."""
        return 1.0 / self.dt

    @property
    def duration_s(self) -> float:
        """Length, s."""
        return float(self.t.shape[0] * self.dt)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def shares_samples_with(self, other: Manoeuvre) -> bool:
        """Whether ``other`` holds some of the same samples: windows of one script that
        overlap in time, or the same recording (however each was named: through a symlink,
        a hard link, or a copy of the file, whose samples are the same to the bit)."""

        def origin(m: Manoeuvre) -> str:
            if m.source.startswith("jsbsim:"):
                return m.source.rsplit("@", 1)[0]  # the script, without the window
            return str(Path(m.source).resolve())

        if origin(self) != origin(other):
            scripts = self.source.startswith("jsbsim:") or other.source.startswith("jsbsim:")
            if scripts or not (same_file(self.source, other.source) or self._same_samples(other)):
                return False
        return bool(self.t[0] <= other.t[-1] and other.t[0] <= self.t[-1])

    def _same_samples(self, other: Manoeuvre) -> bool:
        return all(
            np.array_equal(getattr(self, k), getattr(other, k))
            for k in ("t", "specific_force", "angular_velocity", "attitude")
        )

    def states(self) -> list[AircraftState]:
        """The samples as :class:`~motionbase.state.AircraftState` objects (what sources yield)."""
        rows = np.ascontiguousarray(
            np.column_stack([self.specific_force, self.angular_velocity, self.attitude])
        )
        return [AircraftState.from_vector(float(t), rows[i]) for i, t in enumerate(self.t)]


def parse_script_spec(spec: str) -> tuple[str, float, float]:
    """``NAME`` or ``NAME@START:END`` -> ``(name, start_s, end_s)`` with the default window.

    Raises
    ------
    ConfigError
        An empty name, a window that is not two numbers, or ``END <= START``.
    """
    text = str(spec).strip()
    m = _SPEC.match(text)
    if not text or m is None or not m.group("name").strip():
        raise ConfigError(f"script {spec!r}: expected NAME or NAME@START:END (seconds)")
    name = m.group("name").strip()
    if m.group("start") is None:
        known = SCRIPT_WINDOWS.get(name)
        start, end = (known[0], known[1]) if known else (0.0, DEFAULT_SCRIPT_LENGTH_S)
        return name, start, end
    try:
        start, end = float(m.group("start")), float(m.group("end"))
    except ValueError:
        raise ConfigError(
            f"script {spec!r}: the window must be two numbers of seconds, e.g. {name}@0:60"
        ) from None
    if not (math.isfinite(start) and math.isfinite(end) and 0.0 <= start < end):
        raise ConfigError(f"script {spec!r}: the window needs 0 <= START < END seconds")
    return name, start, end


def load_script(spec: str) -> Manoeuvre:
    """Run a JSBSim script (name or path, optional ``@START:END``) once; keep its states.

    Raises
    ------
    SourceError
        Unknown script (the message lists how to find the shipped ones) or JSBSim fails.
    ConfigError
        A bad window, or a window past the end of the script.
    """
    from motionbase.io.jsbsim_source import JsbsimSource

    name, start, end = parse_script_spec(spec)
    with JsbsimSource(name, duration_s=end) as source:
        dt = 1.0 / source.rate_hz
        states = [s for s in source if s.t >= start - 0.5 * dt]
    if len(states) < 3:
        why = (
            f"at least {3 * dt:.3g} s at the script's {source.rate_hz:g} Hz: choose a longer window"
            if end - start < 3 * dt
            else "the script is shorter: choose an earlier window"
        )
        raise ConfigError(
            f"script {spec!r}: the window {start:g}-{end:g} s holds {len(states)} samples "
            f"(it needs 3, {why})"
        )
    label = name if "@" not in str(spec) else str(spec).strip()
    return _from_states(label, f"jsbsim:{source.script_path}@{start:g}:{end:g}", dt, states)


def load_recording(path: str | Path) -> Manoeuvre:
    """An MCAP recording's ``/aircraft/state``, or a MAVLink ``.tlog``/``.bin`` log.

    Raises
    ------
    ConfigError
        Another kind of file (by its extension).
    SourceError, LogFormatError
        The file is missing or unreadable.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".mcap":
        from motionbase.io.mcap_source import McapSource

        with McapSource(p) as source:
            states, fresh = _collect(source)
            rate = source.rate_hz
    elif suffix in (".tlog", ".bin"):
        from motionbase.io.mavlink_source import MavlinkSource

        with MavlinkSource(str(p), rate_hz=MAVLINK_RATE_HZ, realtime=False) as source:
            states, fresh = _collect(source)
            rate = source.rate_hz
    else:
        raise ConfigError(
            f"{p}: a recording must be an MCAP file (.mcap) or a MAVLink log (.tlog, .bin)"
        )
    if not (math.isfinite(rate) and rate > 0):
        raise ConfigError(f"{p}: cannot tell its sample rate")
    return _from_states(p.name, str(p), 1.0 / rate, states, fresh)


def load_manoeuvres(
    scripts: list[str] | tuple[str, ...] = (), recordings: list[str] | tuple[str, ...] = ()
) -> list[Manoeuvre]:
    """Scripts (:func:`load_script`) then recordings (:func:`load_recording`), in order."""
    out = [load_script(s) for s in scripts]
    out.extend(load_recording(r) for r in recordings)
    return out


def load_spec(spec: str) -> Manoeuvre:
    """A recording (a path ending in :data:`RECORDING_SUFFIXES`) or else a script spec."""
    if Path(str(spec).strip()).suffix.lower() in RECORDING_SUFFIXES:
        return load_recording(str(spec).strip())
    return load_script(spec)


def write_washout(path: str | Path, params: WashoutParams, header: list[str]) -> None:
    """Write ``params`` as a washout TOML file (its folder created), ``header`` lines first
    as ``#`` comments.

    Raises
    ------
    ConfigError
        The file cannot be written (the message says why).
    """
    p = Path(path)
    comments = "".join(f"# {line}".rstrip() + "\n" for line in header)
    # tomli_w writes one number per line; one line per axis triple reads better
    body = _ARRAY.sub(
        lambda m: "[" + ", ".join(x.strip().rstrip(",") for x in m.group(1).splitlines()) + "]",
        tomli_w.dumps(params.to_dict()),
    )
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        # whole or not at all: a second Ctrl-C while a stopped tuning writes leaves no half file
        with whole_file(p) as part:
            part.write_text(comments + body, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{p}: cannot write: {exc.strerror}") from None


def preview_reference(
    source: Any, stop: Any = None, limits: InputLimits | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Every sample of an (entered) offline source, as the preview of a cueing
    (:meth:`motionbase.washout.mpc.MpcCueing.set_preview`): specific force (N, 3), m/s^2,
    and body rates (N, 3), rad/s, one row per sample the source gives. A sample the
    pipeline rejects (:func:`motionbase.safety.input_problem` with ``limits``, the run's
    input limits: non-finite, absurd, its time not after the last usable one) holds the
    last usable one (level flight before any), as the pipeline holds it.

    ``stop`` (the run's :class:`~motionbase.stopping.StopRequest`): once it is set, the
    rest of the source is not read, and the run this prepares stops before its first
    tick. (A stop signal during the look-ahead of a long flight waited for all of it: as
    long as simulating the whole script took.) Level flight when it was set before the
    first sample.

    Raises
    ------
    ConfigError
        The source gave no sample.
    """
    limits = limits or InputLimits()
    f, w = [], []
    last_f, last_w = np.array([0.0, 0.0, -STANDARD_GRAVITY]), np.zeros(3)
    last_t = None
    for state in source:
        if stop is not None and stop.is_set():
            break
        sf = np.asarray(state.specific_force, dtype=float)
        av = np.asarray(state.angular_velocity, dtype=float)
        att = np.asarray(state.attitude, dtype=float)
        if input_problem(state.t, sf, av, att, last_t, limits) is None:
            last_f, last_w, last_t = sf, av, state.t
        f.append(last_f)
        w.append(last_w)
    if not f:
        if stop is not None and stop.is_set():
            return last_f[None, :].copy(), last_w[None, :].copy()
        raise ConfigError("--preview: the source gave no aircraft state to preview")
    return np.array(f), np.array(w)


def _collect(source) -> tuple[list[AircraftState], list[bool]]:
    states, fresh = [], []
    for state in source:
        states.append(state)
        fresh.append(bool(getattr(source, "fresh", True)))
    return states, fresh


def _from_states(
    name: str,
    source: str,
    dt: float,
    states: list[AircraftState],
    fresh: list[bool] | None = None,
) -> Manoeuvre:
    if len(states) < 3:
        raise ConfigError(f"{name}: only {len(states)} aircraft states; nothing to tune on")
    return Manoeuvre(
        name=name,
        source=source,
        dt=dt,
        t=np.array([s.t for s in states]),
        specific_force=np.array([s.specific_force for s in states]),
        angular_velocity=np.array([s.angular_velocity for s in states]),
        attitude=np.array([s.attitude for s in states]),
        fresh=np.ones(len(states), dtype=bool) if fresh is None else np.array(fresh, dtype=bool),
        on_ground=np.array([np.nan if s.on_ground is None else float(s.on_ground) for s in states]),
    )
