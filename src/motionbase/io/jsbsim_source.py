"""JSBSim as a source of aircraft states: scripted flights or an aircraft at given conditions.

Headless and quiet: JSBSim's banner and script notices go to a logger that
keeps them in memory (errors and warnings are quoted in a failure's message)
instead of the terminal, and every file a script writes (state files, CSV
output) goes to a temporary folder that is deleted on exit, never into the
working directory.

Conversions at this edge: JSBSim's ``accelerations/a-pilot-{x,y,z}-ft_sec2``
is the specific force at the pilot's eye point in body axes (FRD), ft/s^2,
times 0.3048 to m/s^2; body rates ``velocities/{p,q,r}-rad_sec``, angular
accelerations ``accelerations/{pdot,qdot,rdot}-rad_sec2`` and Euler angles
``attitude/{phi,theta,psi}-rad`` are already SI and FRD (``psi`` is JSBSim's
heading in [0, 2 pi)). The flight phase :attr:`~motionbase.state.AircraftState.on_ground`
is JSBSim's weight on wheels, ``gear/wow`` (true while any landing gear unit touches).
"""

from __future__ import annotations

import difflib
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import jsbsim
import numpy as np

from motionbase.errors import ConfigError, SourceError
from motionbase.state import AircraftState

FT_TO_M = 0.3048

#: JSBSim properties read each step, in AircraftState order.
PROPERTIES = (
    "accelerations/a-pilot-x-ft_sec2",
    "accelerations/a-pilot-y-ft_sec2",
    "accelerations/a-pilot-z-ft_sec2",
    "velocities/p-rad_sec",
    "velocities/q-rad_sec",
    "velocities/r-rad_sec",
    "attitude/phi-rad",
    "attitude/theta-rad",
    "attitude/psi-rad",
    "accelerations/pdot-rad_sec2",
    "accelerations/qdot-rad_sec2",
    "accelerations/rdot-rad_sec2",
)
#: Weight on wheels (any landing gear unit touching the ground), the flight phase
#: (:attr:`AircraftState.on_ground`); an aircraft without it gives no phase.
WOW_PROPERTY = "gear/wow"


class _QuietLogger(jsbsim.FGLogger):
    """Keeps JSBSim's log records in memory instead of printing them."""

    def __init__(self) -> None:
        super().__init__()
        self.problems: list[str] = []
        self._level = jsbsim.LogLevel.BULK
        self._parts: list[str] = []

    def set_level(self, level: jsbsim.LogLevel) -> None:
        self._level = level
        self._parts = []

    def file_location(self, filename: str, line: int) -> None:
        self._parts.append(f"{filename}:{line}: ")

    def message(self, message: str) -> None:
        self._parts.append(message)

    def format(self, format: jsbsim.LogFormat) -> None:  # noqa: A002 - JSBSim's name
        pass

    def flush(self) -> None:
        if self._level >= jsbsim.LogLevel.WARN and self._level != jsbsim.LogLevel.STDOUT:
            text = " ".join("".join(self._parts).split())
            if text:
                self.problems.append(text)
                del self.problems[:-20]
        self._parts = []


def default_root() -> Path:
    """The JSBSim data folder shipped with the ``jsbsim`` package (aircraft, scripts, ...)."""
    return Path(jsbsim.get_default_root_dir())


def available_scripts(root: str | Path | None = None) -> list[str]:
    """Names of the scripts shipped in ``<root>/scripts`` (e.g. ``c1723``)."""
    folder = Path(root or default_root()) / "scripts"
    return sorted(p.stem for p in folder.glob("*.xml"))


def _script_timing(path: Path) -> tuple[float, float, float]:
    """(start, end, dt) in seconds from a script's ``<run>`` element."""
    try:
        run = ET.parse(path).getroot().find("run")
    except ET.ParseError as exc:
        raise SourceError(f"{path}: not a valid JSBSim script: {exc}") from None
    except OSError as exc:  # (no read permission, a failing disk: a traceback once)
        raise SourceError(f"{path}: cannot read the JSBSim script: {exc.strerror or exc}") from None
    if run is None:
        raise SourceError(f"{path}: not a JSBSim script (no <run> element)")
    try:
        start = float(run.get("start", "0"))
        end = float(run.get("end", "nan"))
        dt = float(run.get("dt", "nan"))
    except ValueError:
        raise SourceError(f"{path}: <run> start, end or dt is not a number") from None
    return start, end, dt


class JsbsimSource:
    """Aircraft states from a JSBSim script, headless, quiet, as fast as they are asked for.

    The source never waits: a real-time flight is paced by the pipeline's loop
    (:func:`motionbase.pipeline.run` with ``paced=True``), which asks for the next sample
    when its tick is due.

    Parameters
    ----------
    script : str
        A script shipped with the ``jsbsim`` package, by name (``"c1723"``, see
        :func:`available_scripts`), or a path to a script ``.xml``.
    rate_hz : float, optional
        Output rate, Hz: the script's rate (1/dt; c1723 runs at 120 Hz) or
        that rate divided by a whole number (samples are decimated, the
        simulation keeps its own step). Default: the script's rate.
    duration_s : float, optional
        Simulated time to run, s, at most the script's length. Default: the
        script's end time minus its start time.
    root : str, optional
        JSBSim data folder (aircraft, engine, systems, scripts). Default: the
        one shipped with the ``jsbsim`` package.

    Attributes
    ----------
    rate_hz : float
        Output sample rate, Hz.
    duration_s : float
        Simulated time the source will cover, s.

    Raises
    ------
    SourceError
        Unknown script name (the message says how to list them) or JSBSim
        cannot load it.
    ConfigError
        A rate that does not divide the script's rate, or a bad duration.

    Examples
    --------
    >>> with JsbsimSource("c1723", duration_s=5.0) as src:   # doctest: +SKIP
    ...     states = list(src)                               # 600 states at 120 Hz
    """

    def __init__(
        self,
        script: str = "c1723",
        *,
        rate_hz: float | None = None,
        duration_s: float | None = None,
        root: str | None = None,
    ) -> None:
        self.root = Path(root) if root is not None else default_root()
        self.aircraft: str | None = None
        self.init: str | dict[str, float] | None = None
        self.script_path: Path | None = self._resolve_script(script)
        self.script = script
        start, end, dt = _script_timing(self.script_path)
        if not (math.isfinite(dt) and dt > 0):
            raise SourceError(f"{self.script_path}: <run> has no valid dt")
        if not math.isfinite(end):  # JSBSim refuses to load it, --duration or not
            raise SourceError(
                f"{self.script_path}: <run> has no end time, which JSBSim needs: add "
                'end="SECONDS" to it'
            )
        if not (math.isfinite(start) and end > start):
            raise SourceError(
                f"{self.script_path}: <run> end ({end:g} s) is not after its start "
                f"({start:g} s): nothing to fly"
            )
        self._dt = dt
        self._t_start = start
        self._setup_rate_duration(rate_hz, duration_s, end - start)
        self._init_state()

    @classmethod
    def from_aircraft(
        cls,
        aircraft: str,
        init: str | Mapping[str, float],
        *,
        rate_hz: float = 120.0,
        duration_s: float = 60.0,
        root: str | None = None,
    ) -> JsbsimSource:
        """An aircraft from ``<root>/aircraft`` with initial conditions, no script.

        Parameters
        ----------
        aircraft : str
            Aircraft folder name, e.g. ``"c172x"``.
        init : str or Mapping
            The name of an initialisation file in the aircraft's folder
            (e.g. ``"reset01"``), or JSBSim properties: ``ic/...`` ones are set
            before the initial conditions are applied, the others (e.g.
            ``"propulsion/set-running": -1``, ``"fcs/throttle-cmd-norm": 0.8``)
            right after.
        rate_hz : float
            Simulation and output rate, Hz (JSBSim steps at 1/rate_hz).
        duration_s : float
            Simulated time to run, s.
        root
            As for :class:`JsbsimSource`.
        """
        self = cls.__new__(cls)
        self.root = Path(root) if root is not None else default_root()
        self.script_path = None
        self.script = None
        if not os.path.isdir(self.root / "aircraft" / aircraft):
            known = sorted(p.name for p in (self.root / "aircraft").iterdir() if p.is_dir())
            close = difflib.get_close_matches(aircraft, known, n=3)
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise SourceError(
                f"unknown JSBSim aircraft {aircraft!r}{hint}: the aircraft are the folders "
                f"of {self.root / 'aircraft'}"
            )
        self.aircraft = aircraft
        self.init = init if isinstance(init, str) else {str(k): float(v) for k, v in init.items()}
        if not (isinstance(rate_hz, int | float) and math.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigError(f"JSBSim rate_hz must be > 0 Hz, got {rate_hz!r}")
        self._dt = 1.0 / float(rate_hz)
        self._t_start = 0.0
        self._setup_rate_duration(None, duration_s, math.inf)
        self._init_state()
        return self

    # ------------------------------------------------------------------ set-up
    def _resolve_script(self, script: str) -> Path:
        s = str(script)
        if s.endswith(".xml") or "/" in s or "\\" in s:
            path = Path(s)
            # (os.path's tests: pathlib's raise for a name too long, a traceback once)
            if os.path.isdir(path):
                raise SourceError(f"{path}: a folder, not a JSBSim script (give its .xml file)")
            if not os.path.isfile(path):
                shipped = path.name == s and os.path.isfile(self.root / "scripts" / s)
                hint = f"; JSBSim's own is named {path.stem}, without .xml" if shipped else ""
                raise SourceError(f"{path}: JSBSim script not found (check the path{hint})")
            return path.resolve()
        path = self.root / "scripts" / f"{s}.xml"
        if os.path.isfile(path):
            return path
        names = available_scripts(self.root)
        close = difflib.get_close_matches(s, names, n=3)
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        raise SourceError(
            f"unknown JSBSim script {s!r}{hint}: give a path to a script .xml or the name of a "
            f"file in {self.root / 'scripts'} (motionbase.io.jsbsim_source.available_scripts() "
            "lists them)"
        )

    def _setup_rate_duration(
        self, rate_hz: float | None, duration_s: float | None, length: float
    ) -> None:
        native = 1.0 / self._dt
        if rate_hz is None:
            self._decimation = 1
        else:
            if not (isinstance(rate_hz, int | float) and math.isfinite(rate_hz) and rate_hz > 0):
                raise ConfigError(f"JSBSim rate_hz must be > 0 Hz, got {rate_hz!r}")
            n = round(native / rate_hz)
            if n < 1 or abs(native / n - rate_hz) > 1e-6 * rate_hz:
                choices = ", ".join(f"{native / k:g}" for k in range(1, 7))
                raise ConfigError(
                    f"JSBSim rate_hz={rate_hz:g} Hz does not divide the simulation rate "
                    f"{native:g} Hz: choose {native:g}/n Hz ({choices}, ...)"
                )
            self._decimation = n
        self.rate_hz = native / self._decimation
        if duration_s is None:
            if not math.isfinite(length):
                raise ConfigError("JSBSim script has no end time: give duration_s")
            duration = length
        else:
            if not (
                isinstance(duration_s, int | float) and math.isfinite(duration_s) and duration_s > 0
            ):
                raise ConfigError(f"duration_s must be > 0 s, got {duration_s!r}")
            duration = min(float(duration_s), length)
        #: why the states ran out (:class:`~motionbase.io.base.EndingSource`): "duration"
        #: once ``duration_s`` cut the script short, else empty (the script's end)
        self.ended = ""
        self._cut_short = duration < length
        self.duration_s = float(duration)
        # samples to yield: every `decimation` steps up to the duration (tolerate rounding)
        self._samples = int(math.floor(self.duration_s * self.rate_hz + 1e-6))

    def _init_state(self) -> None:
        self._fdm: Any = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._logger: _QuietLogger | None = None
        self._previous_logger: Any = None

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> JsbsimSource:
        """Load JSBSim, the aircraft and the initial conditions (``__enter__`` calls it)."""
        if self._fdm is not None:
            return self
        self._install_logger()
        self._tmp = tempfile.TemporaryDirectory(prefix="motionbase-jsbsim-")
        try:
            fdm = jsbsim.FGFDMExec(str(self.root), None)
            fdm.set_debug_level(0)
            fdm.set_output_path(self._tmp.name)
            if self.script_path is not None:
                ok = self._call(fdm.load_script, str(self.script_path))
                what = f"script {self.script_path}"
            else:
                ok = self._load_aircraft(fdm)
                what = f"aircraft {self.aircraft!r}"
            if not ok:
                raise SourceError(f"JSBSim could not load {what}{self._problems()}")
            if self.script_path is None:
                for key, value in (self.init or {}).items() if isinstance(self.init, dict) else ():
                    if key.startswith("ic/"):
                        fdm[key] = value
            if not self._call(fdm.run_ic):
                raise SourceError(
                    f"JSBSim could not apply the initial conditions of {what}{self._problems()}"
                )
            if isinstance(self.init, dict):
                for key, value in self.init.items():
                    if not key.startswith("ic/"):
                        fdm[key] = value
            fdm.disable_output()  # the aircraft's own CSV output: not needed, costs time
            pm = fdm.get_property_manager()
            nodes = []
            for name in PROPERTIES:
                node = pm.get_node(name)
                if node is None:
                    raise SourceError(f"JSBSim has no property {name!r} for {what}")
                nodes.append(node)
            wow = pm.get_node(WOW_PROPERTY)
        except BaseException:
            self._fdm = None
            self.close()
            raise
        self._fdm = fdm
        self._nodes = nodes
        self._wow = wow
        return self

    @property
    def output_dir(self) -> Path | None:
        """The temporary folder JSBSim writes its files to while the source is open."""
        return Path(self._tmp.name) if self._tmp is not None else None

    def close(self) -> None:
        """Release JSBSim, delete its temporary folder and restore JSBSim's logger."""
        self._fdm = None
        self._nodes = []
        self._wow = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        if self._previous_logger is not None:
            jsbsim.set_logger(self._previous_logger)
            self._previous_logger = None

    def __enter__(self) -> JsbsimSource:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def _install_logger(self) -> None:
        if self._logger is None:
            self._logger = _QuietLogger()
        current = jsbsim.get_logger()
        if current is not self._logger:
            if self._previous_logger is None:
                self._previous_logger = current
            jsbsim.set_logger(self._logger)

    def _load_aircraft(self, fdm: Any) -> bool:
        fdm.set_dt(self._dt)
        if not self._call(fdm.load_model, self.aircraft):
            return False
        if isinstance(self.init, str):
            return bool(self._call(fdm.load_ic, self.init, True))
        return True

    def _call(self, fn: Any, *args: Any) -> Any:
        try:
            return fn(*args)
        except jsbsim.BaseError as exc:
            raise SourceError(f"JSBSim: {self._said(exc)}") from None

    def _problems(self, said: str = "") -> str:
        """JSBSim's last logged problem, as `` (JSBSim says: ...)``; nothing when none was
        logged or when it is ``said`` already."""
        if self._logger is None or not self._logger.problems:
            return ""
        problem = self._logger.problems[-1]
        return "" if problem == said else f" (JSBSim says: {problem})"

    def _said(self, exc: BaseException) -> str:
        """A JSBSim exception's text on one line (it may end in a newline), with the last
        problem JSBSim logged unless that is the same text."""
        text = " ".join(str(exc).split())
        return f"{text}{self._problems(text)}"

    # ------------------------------------------------------------------ samples
    def __iter__(self) -> Iterator[AircraftState]:
        """Aircraft states at ``rate_hz`` until ``duration_s``; opens the source if needed."""
        own = self._fdm is None
        if own:
            self.open()
        try:
            yield from self._run()
        finally:
            if own:
                self.close()

    def _run(self) -> Iterator[AircraftState]:
        self._install_logger()  # JSBSim's logger is per thread
        fdm = self._fdm
        run = fdm.run
        # the getters of PROPERTIES, in order
        fx, fy, fz, p, q, r, phi, theta, psi, pdot, qdot, rdot = (
            n.get_double_value for n in self._nodes
        )
        sim_time = fdm.get_sim_time
        wow = None if self._wow is None else self._wow.get_double_value
        from_vector = AircraftState.from_vector
        array = np.array
        decimation = self._decimation
        steps = range(decimation)
        self.ended = ""
        for _ in range(self._samples):
            try:
                if decimation == 1:
                    alive = run()
                else:
                    for _ in steps:
                        alive = run()
                        if not alive:
                            break
            except jsbsim.BaseError as exc:
                raise SourceError(f"JSBSim stopped: {self._said(exc)}") from None
            if not alive:
                return
            state = from_vector(
                sim_time(),
                array(
                    (
                        fx() * FT_TO_M,
                        fy() * FT_TO_M,
                        fz() * FT_TO_M,
                        p(),
                        q(),
                        r(),
                        phi(),
                        theta(),
                        psi(),
                        pdot(),
                        qdot(),
                        rdot(),
                    )
                ),
                None if wow is None else wow() > 0.5,
            )
            yield state
        if self._cut_short:
            self.ended = "duration"

    def describe(self) -> dict[str, Any]:
        """Plain-data description of the source for the log's metadata."""
        out: dict[str, Any] = {"kind": "jsbsim"}
        if self.script_path is not None:
            out["script"] = str(self.script)
            out["path"] = str(self.script_path)
        else:
            out["aircraft"] = self.aircraft
            out["init"] = self.init
        out.update(
            rate_hz=self.rate_hz,
            dt_s=self._dt,
            duration_s=self.duration_s,
            root=str(self.root),
            jsbsim_version=jsbsim.__version__,
        )
        return out


__all__ = ["JsbsimSource", "available_scripts", "default_root"]
