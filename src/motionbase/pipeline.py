"""The pipeline: source -> validation -> washout -> clamp -> inverse kinematics -> safety -> sinks.

One documented time convention: the pipeline ticks at a fixed rate ``rate_hz``
(``dt = 1 / rate_hz``); each tick consumes one sample from the source (sources
resample to that rate themselves) and produces one :class:`PipelineOutput`, whose
``t`` is the source's time in seconds. After the source ends, or on a stop or an
E-stop, the pipeline keeps ticking on the last held sample until the platform is
parked.

:class:`Pipeline` is the functional core: ``step(state) -> PipelineOutput`` does
no I/O. :func:`run` is the loop that reads a source, writes sinks, paces
real-time runs on the wall clock (never on the samples' own times) and reports
progress.

Stages of one tick
------------------
1. *Validation*: a non-finite or absurd sample, or one whose time does not
   advance, is rejected, counted and replaced by the last valid sample (a hold).
2. *Watchdog fade*: the input is *stale* when the source marks its samples stale
   or when no sample was accepted for longer than ``stale_timeout_s`` (a source
   sending only garbage). While stale, the washout's input fades from the held
   sample toward level flight (``f = (0, 0, -g)``, no rotation) over ``fade_s``;
   when fresh samples return it fades back into them. A forward time jump longer
   than ``stale_timeout_s`` (a replay's gap, a reloaded aircraft) restarts the
   input from level flight and fades it into the new samples.
   The fade acts on the washout's *input*, never on its output pose: the platform
   goes back to neutral (and resumes) through the washout's own filters, the tilt
   within its rate limit, so a fade gives no motion the washout would not give
   for an aircraft easing back to level flight. Scaling the output pose instead
   moved the platform faster than any cue (a tilt removed at 12 deg/s) and, when a
   fade turned back, stepped its speed (a spike the limiter then had to brake);
   the filters keep their state across a jump for the same reason: a reset would
   step the pose.
3. *Cueing*: the cueing plug-in (default: the classical washout,
   :class:`~motionbase.washout.ClassicalWashout`) -> cue pose.
4. *Soft start / stop*: the commanded pose blends from the park pose to the live
   pose over ``soft_start_s`` (and back on stop; a stop during the start brakes the
   blend and turns it within the start's own peak rate and acceleration).
5. *Clamp*: the robot's workspace clamp scales the whole pose toward neutral;
   when it acts while running the washout is told (anti-windup).
6. *Inverse kinematics* -> actuator angles.
7. *Safety* (:mod:`motionbase.safety`): finite, inside the angle limits, within
   the speed and acceleration limits, else the last safe command is held.

Each stage is defined once, in :mod:`motionbase.stages` (validation and fade, soft
start/stop, the limiter and their named state), in the cueing plug-in
(:mod:`motionbase.washout.cueing`) and in the robot plug-in
(:mod:`motionbase.platform.robot`); the tick and the batch path
(:meth:`Pipeline.run_batch`) call the same compiled functions.
"""

from __future__ import annotations

import contextlib
import sys
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from functools import partial
from typing import TYPE_CHECKING, Any, NamedTuple

import numba
import numpy as np

from motionbase import __version__, stages
from motionbase.config import as_float, is_number, to_float
from motionbase.errors import ConfigError, CueingInputError, MotionbaseError, SinkError
from motionbase.pacing import GarbageBetweenTicks, wait_until
from motionbase.physics import STANDARD_GRAVITY
from motionbase.platform.robot import ROBOTS, Robot, robot_spec
from motionbase.safety import INPUT_PROBLEMS, InputLimits
from motionbase.state import PHASES, AircraftState, PipelineOutput  # (the classes re-exported)
from motionbase.stopping import StopRequest, stopped_by
from motionbase.washout.cueing import CUEINGS, Cueing, cueing_spec

if TYPE_CHECKING:  # (io's package loads every adapter: not at run time)
    from motionbase.io.base import Sink, Source

# --------------------------------------------------------------------------- config

#: Slowest pipeline rate, Hz: a real-time loop waits at most one period (0.1 s) before it
#: sees a stop, and a recording that claims a slower rate is refused.
MIN_RATE_HZ = 10.0


def check_rate(rate_hz: Any, where: str = "pipeline") -> None:
    """A ConfigError (saying ``where``) unless a pipeline can tick at ``rate_hz``:
    :data:`MIN_RATE_HZ` to 10 kHz."""
    if not (is_number(rate_hz) and np.isfinite(to_float(rate_hz)) and rate_hz > 0):
        raise ConfigError(f"{where}: rate_hz must be > 0, got {rate_hz!r:.40}")
    if rate_hz > 10_000:
        raise ConfigError(f"{where}: rate_hz {rate_hz:g} is above 10 kHz (lower it)")
    if rate_hz < MIN_RATE_HZ:
        raise ConfigError(
            f"{where}: rate_hz {rate_hz:g} is below {MIN_RATE_HZ:g} Hz, too slow to "
            "drive a platform or to answer a stop in time (give a faster rate)"
        )


@dataclass(frozen=True)
class PipelineConfig:
    """Everything that determines the pipeline's numbers (stored in every log).

    Parameters
    ----------
    robot : str
        The robot plug-in's name (:data:`motionbase.platform.robot.ROBOTS`: ``"rus6"``,
        ``"stewart6"``, or ``"rrr3"`` for planar mode).
    geometry : object
        The robot's geometry and actuator limits (its geometry class).
    cueing_params : object
        The cueing's parameters (for ``"classical"``: :class:`WashoutParams`).
    cueing : str
        The cueing plug-in's name (:data:`motionbase.washout.cueing.CUEINGS`).
    rate_hz : float
        Pipeline rate, Hz (``MIN_RATE_HZ``, 10 Hz, to 10 kHz).
    soft_start_s : float
        Time to blend from the park pose to the live command, s (and back on stop).
    stale_timeout_s : float
        No sample accepted for longer than this makes the input stale, and a forward
        jump of the source time longer than this restarts the input from level flight, s.
    fade_s : float
        Watchdog fade time of the cueing's input to level flight (and back) when the
        input goes stale, s.
    planar_scale_m : float
        Planar robots: metres of robot x/-y per metre of cue surge/sway (y is left).
    planar_yaw_scale : float
        Planar robots: robot -phi per radian of cue yaw (phi counter-clockwise).
    input_limits : InputLimits
        Absurd-input bounds for validation.
    """

    robot: str
    geometry: Any
    cueing_params: Any
    cueing: str = "classical"
    rate_hz: float = 120.0
    soft_start_s: float = 2.0
    stale_timeout_s: float = 0.5
    fade_s: float = 1.0
    planar_scale_m: float = 0.1
    planar_yaw_scale: float = 0.5
    input_limits: InputLimits = field(default_factory=InputLimits)

    def __post_init__(self) -> None:
        robot_spec(self.robot)
        cueing_spec(self.cueing)
        for name in ("rate_hz", "soft_start_s", "stale_timeout_s", "fade_s"):
            value = getattr(self, name)
            if not (is_number(value) and np.isfinite(to_float(value)) and value > 0):
                raise ConfigError(f"pipeline: {name} must be > 0, got {value!r:.40}")
        for name in ("planar_scale_m", "planar_yaw_scale"):
            as_float("pipeline", name, getattr(self, name))
        if not isinstance(self.input_limits, InputLimits):
            raise ConfigError(
                f"pipeline: input_limits must be InputLimits, got {self.input_limits!r}"
            )
        check_rate(self.rate_hz)

    @property
    def dt(self) -> float:
        """Pipeline time step, s."""
        return 1.0 / self.rate_hz

    @property
    def planar(self) -> bool:
        """The robot renders surge, sway and yaw only."""
        return robot_spec(self.robot).planar

    def make_robot(self) -> Robot:
        """The robot plug-in this configuration drives."""
        planar = {"scale_m": self.planar_scale_m, "yaw_scale": self.planar_yaw_scale}
        return robot_spec(self.robot).make(self.geometry, **(planar if self.planar else {}))

    def make_cueing(self) -> Cueing:
        """The cueing plug-in this configuration runs, at the pipeline's rate."""
        return cueing_spec(self.cueing).make(self.cueing_params, self.dt)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for the log's metadata); :meth:`from_dict` rebuilds a configuration
        that computes the same numbers. Cueing parameters that name another set (an MPC's
        fallback washout) are stored with its values (their ``self_contained()``, where
        they have one), so that a recording never depends on a file or preset."""
        params = self.cueing_params
        if hasattr(params, "self_contained"):
            params = params.self_contained()
        return {
            "robot": self.robot,
            "geometry": self.geometry.to_dict(),
            "cueing": self.cueing,
            "cueing_params": params.to_dict(),
            "pipeline": {
                **{name: getattr(self, name) for name in _SETTINGS},
                "input_limits": asdict(self.input_limits),
            },
            "version": __version__,
        }

    @staticmethod
    def cueing_params_key(data: dict[str, Any]) -> str:
        """Where :meth:`to_dict`'s plain data holds the cueing's parameters:
        ``"cueing_params"``, or ``"washout"`` in logs from before the cueing plug-ins."""
        return "cueing_params" if "cueing_params" in data or "washout" not in data else "washout"

    @classmethod
    def from_dict(
        cls, data: dict[str, Any], source: str = "recorded configuration"
    ) -> PipelineConfig:
        """Rebuild a configuration written by :meth:`to_dict` (logs before the cueing
        plug-ins stored the classical washout's parameters as ``washout``)."""
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected a table of settings, got {data!r:.60}")
        robot = data.get("robot")
        if robot not in ROBOTS:
            plugin = (
                " (a robot plug-in's? register it, ROBOTS[name] = RobotSpec(...), before "
                "running motionbase)"
                if isinstance(robot, str)
                else ""
            )
            raise ConfigError(
                f"{source}: field 'robot': expected one of {', '.join(sorted(ROBOTS))}, "
                f"got {robot!r}{plugin}"
            )
        cueing = data.get("cueing", "classical")
        if cueing not in CUEINGS:
            raise ConfigError(
                f"{source}: field 'cueing': {cueing!r} is not a known cueing "
                f"({', '.join(sorted(CUEINGS))}); register its plug-in first"
            )
        params_key = cls.cueing_params_key(data)
        pipe = data.get("pipeline", {})
        limits = pipe.get("input_limits", {}) if isinstance(pipe, dict) else None
        if not isinstance(limits, dict):
            raise ConfigError(f"{source}: 'pipeline' and its 'input_limits' must be tables")
        pipe = {k: v for k, v in pipe.items() if k != "input_limits"}
        unknown = sorted(set(pipe) - set(_SETTINGS)) or sorted(
            set(limits) - {f.name for f in fields(InputLimits)}
        )
        if unknown:
            raise ConfigError(f"{source}: unknown pipeline setting {unknown[0]!r}")
        for key in ("geometry", params_key):
            if key not in data:
                raise ConfigError(f"{source}: missing field {key!r}")
        try:
            return cls(
                robot=robot,
                geometry=robot_spec(robot).geometry_type.from_dict(
                    data["geometry"], source=f"{source}: geometry"
                ),
                cueing=cueing,
                cueing_params=cueing_spec(cueing).params_type.from_dict(
                    data[params_key], source=f"{source}: {params_key}"
                ),
                input_limits=InputLimits(**limits),
                **pipe,
            )
        except ConfigError as exc:  # settings and input limits: say where they came from
            msg = str(exc)
            raise ConfigError(msg if msg.startswith(source) else f"{source}: {msg}") from None


#: The pipeline's own settings, in order: the float fields of :class:`PipelineConfig`, stored
#: under ``pipeline`` in its :meth:`~PipelineConfig.to_dict` (with ``input_limits``).
_SETTINGS = tuple(f.name for f in fields(PipelineConfig) if f.type in ("float", float))


# --------------------------------------------------------------------------- outputs


@dataclass
class Health:
    """Counts of everything the safety layers did (logged as ``/health``).

    The loop's timing (real-time runs only, see :func:`run`): ``overruns`` counts
    ticks processed later than one period after the source handed them over,
    ``worst_overrun_s`` is the largest lateness (s), and ``overruns_off_cpu`` counts
    the late ticks in which the loop's thread ran for less than one period: it was
    waiting, not computing (for a CPU taken by another process, the OS or a virtual
    machine's host; for the interpreter lock, held by another thread such as the
    log's writer; or for blocking I/O). The others were late computing: the work
    of the tick itself was too much for the period.

    ``late_commands`` counts the commands that reached the sinks more than one period
    after their sample was due (what an actuator sees: a late wake-up counts too, not
    only a slow tick), and ``worst_late_s`` is the largest excess over that period
    (s). The due time is the loop's own schedule when the loop paces the ticks, the
    source's ``due_time`` when the source paces itself, else the hand-over.
    """

    samples: int = 0
    rejected_inputs: int = 0
    clamps: int = 0
    rate_limited: int = 0
    unsafe_commands: int = 0
    watchdog_fades: int = 0
    time_jumps: int = 0
    estops: int = 0
    overruns: int = 0
    overruns_off_cpu: int = 0
    worst_overrun_s: float = 0.0
    late_commands: int = 0
    worst_late_s: float = 0.0
    last_rejection: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def count(self, flags: int) -> None:
        """Add one tick's status bits (:mod:`motionbase.stages`)."""
        code = flags & stages.PROBLEM
        if code:
            self.rejected_inputs += 1
            self.last_rejection = INPUT_PROBLEMS[code]
        self.time_jumps += bool(flags & stages.TIME_JUMP)
        self.watchdog_fades += bool(flags & stages.FADE_START)
        self.clamps += bool(flags & stages.CLAMPED)
        self.unsafe_commands += bool(flags & stages.HELD)
        self.rate_limited += bool(flags & stages.RATE_LIMITED)


class BatchResult(NamedTuple):
    """What :meth:`Pipeline.run_batch` computed, one row per tick.

    Attributes
    ----------
    cue_poses : ndarray, shape (N, 6)
        The cueing's poses (m, rad).
    poses : ndarray, shape (N, m)
        Robot poses the commands realise (where ``limited`` is set, by forward
        kinematics).
    commands : ndarray, shape (N, n)
        Actuator commands sent, in the robot's unit.
    flags : ndarray of int64, shape (N,)
        Status bits (:mod:`motionbase.stages`).
    """

    cue_poses: np.ndarray
    poses: np.ndarray
    commands: np.ndarray
    flags: np.ndarray

    @property
    def accepted(self) -> np.ndarray:
        return (self.flags & stages.PROBLEM) == 0

    @property
    def clamped(self) -> np.ndarray:
        return (self.flags & stages.CLAMPED) != 0

    @property
    def limited(self) -> np.ndarray:
        """The limiter changed the command (rate limited or held)."""
        return (self.flags & (stages.RATE_LIMITED | stages.HELD)) != 0

    @property
    def phases(self) -> np.ndarray:
        return self.flags >> stages.PHASE_SHIFT


# --------------------------------------------------------------------------- core


class PipelineCore(ABC):
    """What :func:`run` drives: :class:`Pipeline` (aircraft states) and
    :class:`motionbase.commanding.CommandPipeline` (robot poses or actuator positions).
    Both keep their state in the record :attr:`state` (:data:`~motionbase.stages.STATE`),
    tick every :attr:`dt` seconds and say when they are :attr:`parked`.
    """

    robot: Robot
    health: Health
    params: np.ndarray
    state: np.ndarray
    dt: float

    @abstractmethod
    def step(self, sample: Any, fresh: bool = True) -> PipelineOutput:
        """One tick with the source's sample (None: none, e.g. after its end); ``fresh``
        False when the source marks it a stale hold."""

    def stop(self) -> None:
        """Head for park at the soft-start pace (the end of the input, a stop signal: SIGINT,
        SIGTERM, SIGHUP, SIGQUIT, SIGTSTP when it drives motors; a failing source or sink):
        the phase becomes stopping (for :class:`Pipeline`, the blend from the live pose to
        park runs back over ``soft_start_s``)."""
        s = self.state[0]
        if s["phase"] in (stages.STARTING, stages.RUNNING):
            s["phase"] = stages.STOPPING

    def warm_up(self) -> None:
        """Load every compiled kernel now (numba's on-disk cache), so the first live tick is on
        time; the pipeline is left reset, its counters untouched."""
        health, self.health = self.health, Health()  # the warm-up ticks count elsewhere
        self._warm_ticks()
        scratch = np.zeros(self.robot.n)
        _track_run(scratch, scratch.copy(), scratch.copy(), scratch, scratch)  # run()'s summary
        self.parked  # noqa: B018 - loads the check that the loop makes at the end of a run
        self.reset()
        self.health = health

    def park_step(self) -> PipelineOutput:
        """A tick toward park for after :meth:`step` raised: here an E-stop and a tick
        without input; a pipeline whose step calls a plug-in overrides it to call none."""
        self.estop()
        return self.step(None)

    @abstractmethod
    def _warm_ticks(self) -> None:
        """A few ticks that call every compiled kernel (:meth:`warm_up` resets after them)."""

    @abstractmethod
    def reset(self) -> None:
        """Back to parked, at rest; counters kept."""

    @property
    def parked(self) -> bool:
        """Stopped with the actuators at park and at rest, where the run may end."""
        return bool(stages.at_park(self.params, self.state))

    def estop(self) -> None:
        """Emergency stop: head for park at once, as fast as the actuators' speed and
        acceleration limits allow (the geometry's ``max_speed`` and ``max_accel``, never
        faster): a second stop signal while stopping, teleop's E-stop key, this call."""
        self.health.estops += 1
        s = self.state[0]
        s["estop"] = True
        s["phase"] = stages.STOPPING
        s["blend"] = 0.0

    @property
    def estopped(self) -> bool:
        """An E-stop was asked since the last reset."""
        return bool(self.state[0]["estop"])

    @property
    def phase(self) -> str:
        """``"starting"``, ``"running"``, ``"stopping"`` or ``"parked"``."""
        return "parked" if self.parked else PHASES[int(self.state[0]["phase"])]

    @property
    def command(self) -> np.ndarray:
        """The last actuator command (a copy), in the robot's unit."""
        return self.state[0]["q"][: self.robot.n].copy()

    @property
    def speed(self) -> np.ndarray:
        """The last command's speed (a live view: read it, do not keep it)."""
        return self.state[0]["v"][: self.robot.n]


class Pipeline(PipelineCore):
    """The functional core: ``step(state) -> PipelineOutput``, no I/O.

    Parameters
    ----------
    config : PipelineConfig
    cueing : Cueing, optional
        A cueing object to run instead of the one ``config`` names (tests of a plug-in
        not in the registry).

    Notes
    -----
    The stages are the functions of :mod:`motionbase.stages`, the cueing plug-in
    (:attr:`cueing`) and the robot plug-in (:attr:`robot`); the state is the record
    :attr:`state` (:data:`~motionbase.stages.STATE`) plus the cueing's own.
    """

    def __init__(self, config: PipelineConfig, *, cueing: Cueing | None = None) -> None:
        self.config = config
        self.dt = config.dt
        self.robot = config.make_robot()
        self.cueing = cueing if cueing is not None else config.make_cueing()
        self.cueing.bind_robot(self.robot)
        self.health = Health()
        self.params = stages.new_params(
            self.robot,
            dt=config.dt,
            soft_start_s=config.soft_start_s,
            stale_timeout_s=config.stale_timeout_s,
            fade_s=config.fade_s,
            input_limits=config.input_limits,
        )
        self.state = np.zeros(1, dtype=stages.STATE)  # (reset below)
        self._m = m = len(self.robot.park_pose)  # the size of a robot pose
        self._solve = stages.kernel_list(self.robot.solve_kernel, stages.SOLVE_LIST)
        # (the pipeline's own writable copy: numba binds the stages to a writable array, and
        # a plug-in may hand over a read-only one, or a list)
        self._G = np.array(self.robot.kernel_params, dtype=np.float64, order="C")
        self._u = np.empty(6)
        self._target = np.empty(6)
        self._cue_out = np.empty(6)
        self._wanted = np.empty(self.robot.n)
        self._zero3 = np.zeros(3)
        self._zero3.flags.writeable = False  # as a sample's fields (AircraftState)
        # the stages, compiled for these buffers' types (a sample's fields are read-only
        # float vectors of 3, checked by AircraftState), and live views of the state record
        z, u, P, S = self._zero3, self._u, self.params, self.state
        self._input_stage = stages.bind(stages.input_stage, P, S, True, 0.0, z, z, z, True, u)
        self._after_cueing = stages.bind(
            stages.after_cueing, P, S, self._solve, self._G, u, u, u, u, u, u
        )
        self._t, self._fade, self._pose = S["t"], S["fade"], S["pose"][0, :m]
        # a cueing with a compiled step: that step on its live vectors, as the batch path
        # runs it (the same as its advance), bound like the stages; else its advance
        cueing, kernel = self.cueing, self.cueing.step_kernel
        if kernel is None:
            self._cue_step = lambda _p, _s, u, out: cueing.advance(u, out)
        else:
            self._cue_step = stages.bind(kernel, cueing.kernel_params, cueing.kernel_state, u, u)
        #: The last tick's status bits (:mod:`motionbase.stages`).
        self.flags = 0
        self.reset()
        self.warm_up()

    # -- lifecycle -------------------------------------------------------------
    def reset(self) -> None:
        """Back to parked, filters at rest, counters kept."""
        self.cueing.reset()
        stages.reset_state(self.state, self.params)
        self._last_cue = np.array(self.params[0]["park_cue"])  # (what park_step holds)

    def _warm_ticks(self) -> None:
        level = np.array([0.0, 0.0, -STANDARD_GRAVITY])
        self.step(AircraftState(0.0, level, self._zero3))
        self.step(None)
        # as a rate-limited tick calls it (writable arrays: numba compiles per array kind)
        self.robot.forward(np.array(self.robot.park_angles), guess=np.array(self.robot.park_pose))

    # -- one tick --------------------------------------------------------------
    def step(self, state: AircraftState | None, fresh: bool = True) -> PipelineOutput:
        """Advance one tick with the source's sample (None: hold the last one).

        Parameters
        ----------
        state : AircraftState or None
            This tick's sample, or None on ticks after the source ended.
        fresh : bool
            False when the source says the sample is a stale hold.
        """
        self.health.samples += 1
        P, S, u, z = self.params, self.state, self._u, self._zero3
        if state is None:
            flags = self._input_stage(P, S, False, 0.0, z, z, z, bool(fresh), u)
        else:
            f, w, att = state.specific_force, state.angular_velocity, state.attitude
            flags = self._input_stage(P, S, True, state.t, f, w, att, bool(fresh), u)
            if state.on_ground is not None and not flags & stages.PROBLEM:  # accepted: its
                self.cueing.set_flight_phase(state.on_ground)  # phase, for profiled cueings
        cue = np.empty(6)
        cueing = self.cueing
        if not self._cue_step(cueing.kernel_params, cueing.kernel_state, u, cue):
            raise CueingInputError(
                f"{self.cueing.name} cueing: non-finite input {u} (reject the sample first)"
            )
        self._last_cue = cue
        return self._robot_side(state, fresh, flags, cue, self.cueing.status)

    def park_step(self) -> PipelineOutput:
        """A tick toward park that calls no cueing, for after :meth:`step` raised (a
        cueing plug-in's bug): the last cue pose is held and the blend runs back to park
        at the soft-start pace (at the actuators' limits after an E-stop)."""
        self.stop()
        self.health.samples += 1
        P, S, u, z = self.params, self.state, self._u, self._zero3
        flags = self._input_stage(P, S, False, 0.0, z, z, z, False, u)
        return self._robot_side(None, False, flags, self._last_cue, None)

    def _robot_side(
        self,
        state: AircraftState | None,
        fresh: bool,
        flags: int,
        cue: np.ndarray,
        cue_status: dict[str, Any] | None,
    ) -> PipelineOutput:
        """The tick after the cueing: blend, clamp, inverse kinematics, limiter, output."""
        pose = np.empty(self._m)
        q = np.empty(self.robot.n)
        flags |= self._after_cueing(
            self.params, self.state, self._solve, self._G, cue, self._target, self._cue_out,
            pose, self._wanted, q,
        )  # fmt: skip
        self.flags = flags
        if flags & stages.RUNNING_CLAMP:
            self.cueing.track(self._cue_out)  # anti-windup: the pose the platform got
        if flags & stages.RARE:
            self.health.count(flags)
            if flags & (stages.HELD | stages.RATE_LIMITED) and not flags & stages.PATH:
                # the actuators realise another pose than the one asked: say which
                achieved = self.robot.forward(q, guess=self._pose)
                if not np.isnan(achieved[0]):  # (a row of NaN: Newton did not converge)
                    pose = achieved
        return PipelineOutput(
            float(self._t[0]),
            state,
            fresh,
            state is not None and not flags & stages.PROBLEM,
            cue,
            pose,
            bool(flags & stages.CLAMPED),
            q,
            self.robot.servo(q),
            bool(flags & stages.RATE_LIMITED),
            bool(flags & stages.HELD),
            PHASES[flags >> stages.PHASE_SHIFT],
            float(self._fade[0]),
            cue_status,
        )

    # -- a whole flight ----------------------------------------------------------
    def run_batch(
        self,
        t: np.ndarray,
        f: np.ndarray,
        w: np.ndarray,
        att: np.ndarray | None = None,
        fresh: np.ndarray | None = None,
        on_ground: np.ndarray | None = None,
    ) -> BatchResult:
        """Run a whole flight's samples through every stage at once (no log, no loop).

        The same stages as :meth:`step`, from the pipeline's current state (which it
        leaves where the flight ends), ticks counted in :attr:`health`: ``run_batch``
        over a flight equals :meth:`step` over its samples, bit for bit, but for the
        achieved pose after the limiter acted (solved by forward kinematics from the
        pose asked, not the last tick's: equal to the solver's tolerance). With a cueing
        that has compiled kernels the loop is compiled; otherwise it calls :meth:`step`.

        Parameters
        ----------
        t : ndarray, shape (N,)
            Sample times, s (one per tick).
        f, w, att : ndarray, shape (N, 3)
            Specific force (m/s^2), body rates (rad/s), attitude (rad; zeros if None).
        fresh : ndarray of bool, shape (N,), optional
            False where the source marked the sample a stale hold (all fresh if None).
        on_ground : ndarray of float, shape (N,), optional
            The flight phase (1 on the ground, 0 in the air, NaN unknown), for a cueing
            without compiled kernels (a cueing with kernels takes no phase).

        Raises
        ------
        CueingInputError
            The cueing met a non-finite input (validation rejects those first, so only a
            cueing's own failure).
        """
        # (writable, C-ordered copies where needed: the compiled loop's signature)
        t = np.require(t, float, ["C", "W"])
        N = len(t)
        f = np.require(f, float, ["C", "W"]).reshape(N, 3)
        w = np.require(w, float, ["C", "W"]).reshape(N, 3)
        att = np.zeros((N, 3)) if att is None else np.require(att, float, ["C", "W"])
        fresh = np.ones(N, dtype=bool) if fresh is None else np.require(fresh, bool, ["C", "W"])
        out = BatchResult(
            np.empty((N, 6)),
            np.empty((N, self._m)),
            np.empty((N, self.robot.n)),
            np.zeros(N, dtype=np.int64),
        )
        cueing = self.cueing
        if cueing.step_kernel is None:
            for k in range(N):
                g = None if on_ground is None or on_ground[k] != on_ground[k] else on_ground[k]
                state = AircraftState(t[k], f[k], w[k], att[k], on_ground=g)
                o = self.step(state, bool(fresh[k]))
                out.cue_poses[k] = o.washout_pose
                out.poses[k] = o.platform_pose
                out.commands[k] = o.angles
                out.flags[k] = self.flags
            return out
        done = stages.run_batch(
            self.params,
            self.state,
            stages.kernel_list(cueing.step_kernel, stages.STEP_LIST),
            stages.kernel_list(cueing.track_kernel, stages.TRACK_LIST),
            cueing.kernel_params,
            cueing.kernel_state,
            self._solve,
            self._G,
            t,
            f,
            w,
            att,
            fresh,
            *out,
        )
        self.health.samples += done
        ran = out.flags[: done + (done < N)]
        for bits in ran[(ran & stages.RARE) != 0]:
            self.health.count(int(bits))
        limited = np.flatnonzero(out.limited[:done] & (out.flags[:done] & stages.PATH == 0))
        if len(limited):  # the pose the limited commands realise, as the tick reports it
            achieved = self.robot.forward(out.commands[limited], guess=out.poses[limited])
            ok = np.isfinite(achieved).all(axis=1)
            out.poses[limited[ok]] = achieved[ok]
        if done < N:
            raise CueingInputError(
                f"{cueing.name} cueing: non-finite input at sample {done} (t = {t[done]:.6g} s)"
            )
        return out


# --------------------------------------------------------------------------- loop


#: Thread switch interval while :func:`run` runs, s (see its notes).
SWITCH_INTERVAL_S = 2e-4


@numba.njit(cache=True)
def _track_run(low, high, peak_speed, angles, speeds):  # pragma: no cover - compiled
    """np.minimum(low, q, out=low), np.maximum(high, q, out=high) and
    np.maximum(peak_speed, |v|, out=peak_speed), in one call (NaN sticks, as there)."""
    for i in range(angles.shape[0]):
        x, a = angles[i], abs(speeds[i])
        if low[i] == low[i] and not (x >= low[i]):
            low[i] = x
        if high[i] == high[i] and not (x <= high[i]):
            high[i] = x
        if peak_speed[i] == peak_speed[i] and not (a <= peak_speed[i]):
            peak_speed[i] = a


@dataclass
class RunSummary:
    """What a run did, for the end-of-run report.

    The peaks describe the flight (the ``running`` phase: full motion after the soft
    start); the ramps from park and back to park are reported apart (``start_*``,
    ``stop_*``), so that the park angle and the ramps' speed do not hide the flight's.

    Attributes
    ----------
    samples : int
        Ticks processed (including the start and park ramps).
    running_samples : int
        Ticks in the ``running`` phase.
    sim_time_s, wall_time_s : float
        Simulated (source) and wall-clock duration, s.
    clamped_share : float
        Share of ticks whose pose the workspace clamp moved.
    peak_speed : ndarray, shape (n,)
        Largest |speed| (rad/s, or m/s) per actuator in the ``running`` phase (zeros when
        the run never got there).
    peak_angle : ndarray, shape (n,)
        Largest |position| per actuator in the ``running`` phase, from ``angle_range``
        (zeros when the run never got there).
    angle_range : tuple of ndarray
        (lowest, highest) actuator position per actuator in the ``running`` phase, in the
        robot's unit (rad or m; inf and -inf when the run never got there): what the summary
        sets against the limits, since |position| says nothing of a limit below neutral (a
        linear actuator's stroke, or crank limits not centred on 0).
    start_s, stop_s : float
        Length of the soft start (``starting`` ticks) and of the way back to park
        (``stopping`` and ``parked`` ticks), s of pipeline time.
    start_peak_speed, stop_peak_speed : ndarray, shape (n,)
        Largest |speed| per actuator during the soft start and during the way back to
        park, rad/s.
    angle_limits : tuple of ndarray
        (lower, upper), rad.
    max_speed : ndarray, shape (n,)
        Speed limits, rad/s.
    health : Health
    stopped_by : str
        What ended the run (``"end of source"``, ``"duration"``, ``"SIGINT"``, ``"sink
        failure"``, ...; a source's :attr:`~motionbase.io.base.EndingSource.ended`).
    """

    samples: int = 0
    running_samples: int = 0
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    clamped: int = 0
    peak_speed: np.ndarray | None = None
    angle_range: tuple[np.ndarray, np.ndarray] | None = None
    start_s: float = 0.0
    stop_s: float = 0.0
    start_peak_speed: np.ndarray | None = None
    stop_peak_speed: np.ndarray | None = None
    angle_limits: tuple[np.ndarray, np.ndarray] | None = None
    max_speed: np.ndarray | None = None
    health: Health | None = None
    stopped_by: str = "end of source"

    @property
    def clamped_share(self) -> float:
        return self.clamped / self.samples if self.samples else 0.0

    @property
    def peak_angle(self) -> np.ndarray | None:
        if self.angle_range is None:
            return None
        low, high = self.angle_range
        if not self.running_samples:
            return np.zeros_like(low)
        return np.maximum(high, -low)  # (NaN stays NaN)


def _sink_name(sink: Any) -> str:
    """How a sink is named in a message: its URL or file, else its type."""
    return str(getattr(sink, "label", None) or getattr(sink, "path", None) or type(sink).__name__)


def run(
    pipeline: PipelineCore,
    source: Source | Iterable[Any],
    sinks: Sequence[Sink] = (),
    *,
    paced: bool = False,
    busy_wait: bool = False,
    stop: StopRequest | None = None,
    progress: Callable[[PipelineOutput], None] | None = None,
    max_park_s: float = 30.0,
) -> RunSummary:
    """Drive ``pipeline`` from ``source`` into ``sinks`` until the source ends or a stop.

    After the source ends (or a stop is requested) the pipeline keeps ticking on
    the last sample until the platform is parked (at most ``max_park_s``). A stop
    raised before the first tick moves nothing: the run is one park tick.

    Faults: when the source raises, or a sink's ``write`` raises, the run stops
    (the failed sink is dropped), ramps to park on held samples through the
    remaining sinks, and then reports the failure: a
    :class:`~motionbase.errors.MotionbaseError` with "the platform was parked" added
    to its message; a sink's other exception as a
    :class:`~motionbase.errors.SinkError` naming the sink (one line; the original
    is its ``__cause__``); a source's other exception unchanged (a bug). When the
    pipeline's own step raises (a plug-in's bug), in flight or on the ramp to park itself
    (a bug that shows on held samples only), the ramp to park calls no plug-in
    (:meth:`PipelineCore.park_step`: the last cue pose held), and the exception then
    propagates in the same way.

    Parameters
    ----------
    pipeline : PipelineCore
        A :class:`Pipeline`, or a :class:`motionbase.commanding.CommandPipeline` (teleop,
        the wiring check), whose source yields commands instead of aircraft states.
    source : Source, or an iterable of what ``pipeline.step`` takes
        Already entered (``with source:``). A source may mark stale holds (``fresh``,
        :class:`~motionbase.io.base.StaleMarkingSource`) and hand its samples over in
        real time itself (``paces_itself`` and ``due_time``,
        :class:`~motionbase.io.base.SelfPacedSource`); a plain iterable is always fresh
        and paced by this loop.
    sinks : sequence of Sink
        Sinks (:class:`~motionbase.io.base.Sink`), already entered. They never wait:
        in a paced run only this loop keeps time.
    paced : bool
        Real-time run. Time comes from the wall clock, never from the samples' own
        times (a jump or a gap in them is the validation stage's business): unless the
        source paces itself, this loop paces the ticks at the pipeline's rate, tick
        ``k`` due at ``t0 + k * dt`` on :func:`time.monotonic`; when a tick starts
        more than half a period late the schedule restarts from it, so the loop never
        bursts to catch up (no two ticks closer than half a period). The park ticks
        after the source ends are paced the same way. Timing is counted in
        ``pipeline.health`` (see :class:`Health`): a tick must be processed (pipeline
        step and every sink) within one ``dt`` of its hand-over (``overruns``,
        ``overruns_off_cpu``, ``worst_overrun_s``), and its command must reach the
        sinks within one ``dt`` of its sample's due time (``late_commands``,
        ``worst_late_s``; the due time is this loop's schedule, the source's
        ``due_time``, or else the hand-over). A source that stalls is the watchdog's
        business, not an overrun.
    busy_wait : bool
        Paced runs: this loop waits for its ticks by busy-waiting instead of sleeping
        (:func:`motionbase.pacing.wait_until`); a source that paces itself has its own
        ``busy_wait``.
    stop : StopRequest, optional
        Raised to stop (ramp to park at the soft-start pace) or E-stop (``stop.estop``:
        park at once within the speed and acceleration limits).
    progress : callable, optional
        Called with every output; if it raises (a closed terminal), it is dropped and
        the run goes on.

    Notes
    -----
    While it runs, the interpreter's thread switch interval is lowered to
    ``SWITCH_INTERVAL_S`` (and restored after): the threads beside the loop (a live
    source's receiver, the motor outputs' sender) need the GIL for short stretches,
    and with Python's default 5 ms each would wait up to 5 ms behind the busy loop.
    (The MCAP log, whose writer thread this was set for first, is written by a
    process of its own since issue 14.) A paced run collects cyclic garbage after each tick's
    commands are out, never inside a tick
    (:class:`~motionbase.pacing.GarbageBetweenTicks`).
    """
    with contextlib.ExitStack() as restore:  # (the switch interval and the collector as they were)
        restore.callback(sys.setswitchinterval, sys.getswitchinterval())
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        after_tick = restore.enter_context(GarbageBetweenTicks()).after_tick if paced else None
        stop = stop if stop is not None else StopRequest()  # (an unset StopRequest is falsy)
        summary = RunSummary(health=pipeline.health)
        robot = pipeline.robot
        health = pipeline.health
        dt = pipeline.dt
        n = robot.n
        run_speed = np.zeros(n)  # the flight's peak speeds
        run_low, run_high = np.full(n, np.inf), np.full(n, -np.inf)  # and range used
        ramp_low, ramp_high = np.zeros(n), np.zeros(n)  # (not reported: park is known)
        ramp_speed = {"starting": np.zeros(n), "stopping": np.zeros(n)}  # the ramps' peak speeds
        ticks = dict.fromkeys(ramp_speed, 0)  # and lengths
        wall0 = time.perf_counter()
        t_first: float | None = None
        t_last = 0.0
        active = list(sinks)
        failure: BaseException | None = None  # the first source or sink failure
        failed_sink: Any = None
        clock = time.monotonic  # the loop's clock (due times are on it)
        cpu_clock = time.thread_time  # the loop thread's CPU time (tells waiting from computing)
        loop_paces = paced and not getattr(source, "paces_itself", False)
        next_due: float | None = None  # paced by this loop: when the next tick is due
        started = cpu_started = due = 0.0  # the paced tick in progress (see pace)

        def fail(exc: BaseException, what: str, sink: Any = None) -> None:
            nonlocal failure, failed_sink
            if failure is None:
                failure = exc
                failed_sink = sink
                summary.stopped_by = f"{what} failure"
                stop.set(f"{what} failure")

        def pace(own_schedule: bool) -> None:
            """Start a paced tick: wait for its due time on this loop's schedule, or (a source
            that paces itself) take the source's due time; note when the tick started."""
            nonlocal next_due, started, cpu_started, due
            if own_schedule:
                due = clock() if next_due is None else next_due
                wait_until(due, busy=busy_wait, clock=clock)
            started, cpu_started = clock(), cpu_clock()
            if own_schedule:
                # more than half a period late: the schedule restarts here (never burst to catch up)
                next_due = (started if started - due > 0.5 * dt else due) + dt
            else:
                source_due = getattr(source, "due_time", None)
                due = started if source_due is None else source_due
                next_due = started + dt  # the park ticks follow on this loop's schedule

        def emit(out: PipelineOutput) -> None:
            nonlocal t_first, t_last, progress
            for sink in tuple(active):
                try:
                    sink.write(out)
                except Exception as exc:  # noqa: BLE001 - drop the sink, park on the others
                    active.remove(sink)
                    fail(exc, "sink", sink)
            if progress is not None:
                try:
                    progress(out)
                except Exception:  # noqa: BLE001 - a display (a closed terminal): drop it
                    progress = None
            summary.samples += 1
            summary.clamped += out.clamped
            phase = out.phase
            if phase == "running":
                summary.running_samples += 1
                _track_run(run_low, run_high, run_speed, out.angles, speeds)
            else:
                ramp = "starting" if phase == "starting" else "stopping"
                ticks[ramp] += 1
                _track_run(ramp_low, ramp_high, ramp_speed[ramp], out.angles, speeds)
            if t_first is None:
                t_first = out.t
            t_last = out.t
            if paced:
                now = clock()
                # a tick is due when the source hands it over and must be done within one period
                late = now - started - dt
                if late > 0.0:
                    health.overruns += 1
                    if cpu_clock() - cpu_started < dt:
                        health.overruns_off_cpu += 1  # the thread was waiting, not computing
                    health.worst_overrun_s = max(health.worst_overrun_s, late)
                # what the actuators see: the command within one period of its sample's due time
                late = now - due - dt
                if late > 0.0:
                    health.late_commands += 1
                    health.worst_late_s = max(health.worst_late_s, late)
                after_tick()  # (the garbage collector, a paced run's: the command is out)

        stopping_requested = False
        park_tick = partial(pipeline.step, None)  # the ticks after the flight
        iterator = iter(source)
        # per-tick lookups done once: the live speed vector, the stop flag, the fresh mark
        speeds = pipeline.speed
        stop_raised = stop.is_set if isinstance(stop, StopRequest) else stop.__bool__
        has_fresh = hasattr(source, "fresh")
        step = pipeline.step
        # a stop asked before the first tick (while the program loaded): nothing moves, the
        # source is not read; the run is one park tick
        while not (summary.samples == 0 and stop_raised()):
            try:
                state = next(iterator)
            except StopIteration:
                if not (stopping_requested or stop_raised()):  # a stop or failure says more
                    summary.stopped_by = getattr(source, "ended", "") or summary.stopped_by
                break
            except Exception as exc:  # noqa: BLE001 - the source failed: park on held samples
                fail(exc, "source")
                break
            if paced:
                pace(loop_paces)
            if stop_raised() and not stopping_requested:
                summary.stopped_by = stop.reason
                stopping_requested = True
                pipeline.stop()  # (the phase to stopping: from starting or running only)
            if stopping_requested and stop.estop and not pipeline.estopped:
                pipeline.estop()
            try:
                out = step(state, bool(source.fresh) if has_fresh else True)
            except Exception as exc:  # noqa: BLE001 - a plug-in's bug: park without it
                fail(exc, "pipeline")
                park_tick = pipeline.park_step
                break
            emit(out)
            if out.phase == "parked":
                break
        # park ramp on held samples
        if not pipeline.parked:
            if not stopping_requested:
                if stop:
                    summary.stopped_by = stop.reason
                pipeline.stop()
            for _ in range(int(max_park_s / dt)):
                if pipeline.parked and summary.samples:  # (one park tick at least: drives, log)
                    break
                if stop.estop and not pipeline.estopped:
                    pipeline.estop()
                if paced:
                    pace(True)
                try:
                    out = park_tick()
                except Exception as exc:  # noqa: BLE001 - a plug-in's bug on the way back
                    if park_tick == pipeline.park_step:
                        raise  # (the tick without the plug-in: nothing else parks)
                    fail(exc, "pipeline")  # park without it, as after a bug in flight
                    park_tick = pipeline.park_step
                    continue
                emit(out)
        summary.stopped_by = stopped_by(summary.stopped_by, stop)  # (then an E-stop, if any)
        if failure is not None:
            # parked first; then the failure in one line (a source's bug propagates as is)
            if isinstance(failure, MotionbaseError):
                try:
                    again = type(failure)(f"{failure} (the platform was parked)")
                except TypeError:
                    again = MotionbaseError(f"{failure} (the platform was parked)")
                raise again from failure
            if failed_sink is not None:
                what = f"{type(failure).__name__}: {failure}".replace("\n", " ")
                raise SinkError(
                    f"sink {_sink_name(failed_sink)} failed ({what}); the platform was parked"
                ) from failure
            raise failure
        summary.wall_time_s = time.perf_counter() - wall0
        summary.sim_time_s = (t_last - t_first) if t_first is not None else 0.0
        summary.peak_speed = run_speed
        summary.angle_range = (run_low, run_high)
        summary.start_s = ticks["starting"] * dt
        summary.stop_s = ticks["stopping"] * dt
        summary.start_peak_speed = ramp_speed["starting"]
        summary.stop_peak_speed = ramp_speed["stopping"]
        summary.angle_limits = (robot.limits.lower, robot.limits.upper)
        summary.max_speed = robot.limits.max_speed
        return summary


def with_overrides(config: PipelineConfig, **changes: Any) -> PipelineConfig:
    """A copy of ``config`` with some fields changed (None values ignored)."""
    return replace(config, **{k: v for k, v in changes.items() if v is not None})
