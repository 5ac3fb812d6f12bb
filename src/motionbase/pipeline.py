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
3. *Washout* (:class:`~motionbase.washout.ClassicalWashout`) -> pose.
4. *Soft start / stop*: the commanded pose blends from the park pose to the live
   pose over ``soft_start_s`` (and back on stop).
5. *Clamp*: the robot's workspace clamp scales the whole pose toward neutral;
   when it acts while running the washout is told (anti-windup).
6. *Inverse kinematics* -> actuator angles.
7. *Safety* (:mod:`motionbase.safety`): finite, inside the angle limits, within
   the speed and acceleration limits, else the last safe command is held.

Speed: for the 6-RUS, stages 1-7 run in one compiled kernel per tick (the
Python side keeps the health counters, rejections' messages and forward
kinematics after the limiter acted); :meth:`Pipeline.step_reference` runs them
stage by stage (the planar robot's path) and gives bit-identical outputs
(``tests/test_pipeline_fastpath.py``).
"""

from __future__ import annotations

import hashlib
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any, NamedTuple

import numba
import numpy as np

from motionbase import __version__
from motionbase.config import as_float
from motionbase.errors import ConfigError, MotionbaseError, SinkError
from motionbase.pacing import wait_until
from motionbase.platform._rus6_kernels import _inverse_row, _within, clamp_inverse_one
from motionbase.safety import (
    _INPUT_PROBLEMS,
    RATE_LIMITED,
    UNSAFE_TARGET,
    ActuatorLimits,
    InputLimits,
    _input_code,
    _limit_kernel,
    input_problem,
    limit_command,
    smoothstep,
)
from motionbase.state import AircraftState
from motionbase.stopping import StopRequest, install_signal_stop  # noqa: F401 - re-exported
from motionbase.washout.classical import WashoutInputError, _step, _track

# --------------------------------------------------------------------------- config

#: Slowest pipeline rate, Hz: a real-time loop waits at most one period (0.1 s) before it
#: sees a stop, and a recording that claims a slower rate is refused.
MIN_RATE_HZ = 10.0


@dataclass(frozen=True)
class PipelineConfig:
    """Everything that determines the pipeline's numbers (stored in every log).

    Parameters
    ----------
    robot : {"rus6", "rrr3"}
        Which robot the pipeline drives: the 6-RUS platform or, in planar mode,
        the 3-RRR robot.
    geometry : Rus6Geometry or Rrr3Geometry
        The robot's geometry and actuator limits.
    washout : WashoutParams
        Washout filter parameters.
    rate_hz : float
        Pipeline rate, Hz (``MIN_RATE_HZ``, 10 Hz, to 10 kHz).
    soft_start_s : float
        Time to blend from the park pose to the live command, s (and back on stop).
    stale_timeout_s : float
        No sample accepted for longer than this makes the input stale, and a forward
        jump of the source time longer than this restarts the input from level flight, s.
    fade_s : float
        Watchdog fade time of the washout's input to level flight (and back) when the
        input goes stale, s.
    planar_scale_m : float
        Planar mode: metres of robot x/y per metre of washout surge/sway.
    planar_yaw_scale : float
        Planar mode: robot phi per radian of washout yaw.
    input_limits : InputLimits
        Absurd-input bounds for validation.
    """

    robot: str
    geometry: Any
    washout: Any
    rate_hz: float = 120.0
    soft_start_s: float = 2.0
    stale_timeout_s: float = 0.5
    fade_s: float = 1.0
    planar_scale_m: float = 0.1
    planar_yaw_scale: float = 0.5
    input_limits: InputLimits = field(default_factory=InputLimits)

    def __post_init__(self) -> None:
        if self.robot not in ("rus6", "rrr3"):
            raise ConfigError(f"robot must be 'rus6' or 'rrr3', got {self.robot!r}")
        for name in ("rate_hz", "soft_start_s", "stale_timeout_s", "fade_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, (int, float, np.integer, np.floating))
                and np.isfinite(value)
                and value > 0
            ):
                raise ConfigError(f"pipeline: {name} must be > 0, got {value!r}")
        for name in ("planar_scale_m", "planar_yaw_scale"):
            as_float("pipeline", name, getattr(self, name))
        if not isinstance(self.input_limits, InputLimits):
            raise ConfigError(
                f"pipeline: input_limits must be InputLimits, got {self.input_limits!r}"
            )
        if self.rate_hz > 10_000:
            raise ConfigError(f"pipeline: rate_hz {self.rate_hz:g} is above 10 kHz (lower it)")
        if self.rate_hz < MIN_RATE_HZ:
            raise ConfigError(
                f"pipeline: rate_hz {self.rate_hz:g} is below {MIN_RATE_HZ:g} Hz, too slow to "
                "drive a platform or to answer a stop in time (give a faster rate)"
            )

    @property
    def dt(self) -> float:
        """Pipeline time step, s."""
        return 1.0 / self.rate_hz

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for the log's metadata); :meth:`from_dict` rebuilds it exactly."""
        return {
            "robot": self.robot,
            "geometry": self.geometry.to_dict(),
            "washout": self.washout.to_dict(),
            "pipeline": {
                "rate_hz": self.rate_hz,
                "soft_start_s": self.soft_start_s,
                "stale_timeout_s": self.stale_timeout_s,
                "fade_s": self.fade_s,
                "planar_scale_m": self.planar_scale_m,
                "planar_yaw_scale": self.planar_yaw_scale,
                "input_limits": {
                    f.name: getattr(self.input_limits, f.name) for f in fields(InputLimits)
                },
            },
            "version": __version__,
        }

    @classmethod
    def from_dict(
        cls, data: dict[str, Any], source: str = "recorded configuration"
    ) -> PipelineConfig:
        """Rebuild a configuration written by :meth:`to_dict`."""
        from motionbase.platform import Rrr3Geometry, Rus6Geometry
        from motionbase.washout import WashoutParams

        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected a table of settings, got {data!r:.60}")
        robot = data.get("robot")
        if robot not in ("rus6", "rrr3"):
            raise ConfigError(f"{source}: field 'robot': expected 'rus6' or 'rrr3', got {robot!r}")
        pipe = data.get("pipeline", {})
        limits = pipe.get("input_limits", {}) if isinstance(pipe, dict) else None
        if not isinstance(limits, dict):
            raise ConfigError(f"{source}: 'pipeline' and its 'input_limits' must be tables")
        pipe = {k: v for k, v in pipe.items() if k != "input_limits"}
        known = {f.name for f in fields(cls)} - {"robot", "geometry", "washout", "input_limits"}
        unknown = sorted(set(pipe) - known) or sorted(
            set(limits) - {f.name for f in fields(InputLimits)}
        )
        if unknown:
            raise ConfigError(f"{source}: unknown pipeline setting {unknown[0]!r}")
        for key in ("geometry", "washout"):
            if key not in data:
                raise ConfigError(f"{source}: missing field {key!r}")
        geometry_cls = Rus6Geometry if robot == "rus6" else Rrr3Geometry
        try:
            return cls(
                robot=robot,
                geometry=geometry_cls.from_dict(data["geometry"], source=f"{source}: geometry"),
                washout=WashoutParams.from_dict(data["washout"], source=f"{source}: washout"),
                input_limits=InputLimits(**limits),
                **pipe,
            )
        except ConfigError as exc:  # settings and input limits: say where they came from
            msg = str(exc)
            raise ConfigError(msg if msg.startswith(source) else f"{source}: {msg}") from None


# --------------------------------------------------------------------------- robots


class _Robot:
    """What the pipeline needs from a robot, whichever it is."""

    n: int
    limits: ActuatorLimits
    park_angles: np.ndarray
    park_pose: np.ndarray
    neutral_pose: np.ndarray

    def pose_from_washout(self, pose6: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def washout_from_pose(self, pose: np.ndarray, washout_pose: np.ndarray) -> np.ndarray:
        """The washout pose that ``pose`` realises (axes the robot lacks keep ``washout_pose``)."""
        raise NotImplementedError

    def solve(self, pose: np.ndarray) -> tuple[np.ndarray, bool, np.ndarray]:
        """Workspace clamp then inverse kinematics: (reachable pose, clamped, angles)."""
        clamped_pose, clamped = self.clamp(pose)
        return clamped_pose, clamped, self.inverse(clamped_pose)

    def clamp(self, pose: np.ndarray) -> tuple[np.ndarray, bool]:
        raise NotImplementedError

    def inverse(self, pose: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def forward(self, angles: np.ndarray, guess: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def servo(self, angles: np.ndarray) -> np.ndarray | None:
        return None


class _Rus6Robot(_Robot):
    def __init__(self, geometry) -> None:
        from motionbase.platform import Rus6

        self.kin = Rus6(geometry)
        self.n = 6
        lo, hi = self.kin.angle_limits
        self.limits = ActuatorLimits.broadcast(6, lo, hi, geometry.max_speed, geometry.max_accel)
        self.park_angles = np.full(6, float(geometry.park_angle))
        self.neutral_pose = np.zeros(6)
        park = self.kin.forward(self.park_angles, guess=self.neutral_pose)
        if not np.isfinite(park).all():
            raise ConfigError("geometry: park_angle gives no assembled platform (choose another)")
        self.park_pose = np.asarray(park, dtype=float)

    def pose_from_washout(self, pose6):
        return pose6

    def washout_from_pose(self, pose, washout_pose):
        return pose

    def solve(self, pose):
        return self.kin.clamp_inverse(pose)

    def clamp(self, pose):
        p, clamped = self.kin.clamp(pose)
        return np.asarray(p, dtype=float), bool(clamped)

    def inverse(self, pose):
        return np.asarray(self.kin.inverse(pose), dtype=float)

    def forward(self, angles, guess):
        return np.asarray(self.kin.forward(angles, guess=guess), dtype=float)


class _Rrr3Robot(_Robot):
    """Planar mode: surge -> x, sway -> y, yaw -> phi about the home pose."""

    def __init__(self, geometry, scale_m: float, yaw_scale: float) -> None:
        from motionbase.platform import Rrr3

        self.kin = Rrr3(geometry)
        self.n = 3
        # servo ranges as joint-angle intervals (3, 2); angles are expressed inside them
        lo, hi = np.asarray(self.kin.angle_limits, dtype=float).T
        self.limits = ActuatorLimits.broadcast(3, lo, hi, geometry.max_speed, geometry.max_accel)
        self.neutral_pose = np.asarray(self.kin.home, dtype=float)
        self.park_pose = self.neutral_pose
        self.park_angles = self.inverse(self.park_pose)
        if not np.isfinite(self.park_angles).all():
            raise ConfigError(
                "planar geometry: the home pose is not reachable (check the geometry)"
            )
        self.scale = np.array([scale_m, scale_m, yaw_scale])

    def pose_from_washout(self, pose6):
        # planar base frame: x along motor 1 -> motor 2, y toward motor 3 (see DESIGN.md)
        return self.neutral_pose + self.scale * np.array([pose6[0], pose6[1], pose6[5]])

    def washout_from_pose(self, pose, washout_pose):
        # only surge, sway and yaw were clamped: heave, roll and pitch keep their state
        d = (np.asarray(pose) - self.neutral_pose) / self.scale
        out = np.array(washout_pose, dtype=float)
        out[[0, 1, 5]] = d
        return out

    def clamp(self, pose):
        p, clamped = self.kin.clamp(pose)
        return np.asarray(p, dtype=float), bool(clamped)

    def inverse(self, pose):
        # the same angle modulo 2 pi, written inside the servo's interval when it is in it
        angles = np.asarray(self.kin.inverse(pose), dtype=float)
        lo = self.limits.lower
        return lo + np.mod(angles - lo, 2 * np.pi)

    def forward(self, angles, guess):
        return np.asarray(self.kin.forward(angles, guess=guess), dtype=float)

    def servo(self, angles):
        return np.asarray(self.kin.to_servo(angles))


def make_robot(config: PipelineConfig) -> _Robot:
    if config.robot == "rus6":
        return _Rus6Robot(config.geometry)
    return _Rrr3Robot(config.geometry, config.planar_scale_m, config.planar_yaw_scale)


# --------------------------------------------------------------------------- outputs


class PipelineOutput(NamedTuple):
    """Everything one tick produced (what the sinks log and send); immutable.

    Attributes
    ----------
    t : float
        Time, s (source clock).
    state : AircraftState or None
        The sample the source gave this tick, as given (None on park ticks after
        the source ended).
    fresh : bool
        False when the source marked the sample stale.
    accepted : bool
        False when validation rejected the sample (the last valid one was held).
    washout_pose : ndarray, shape (6,)
        Washout output ``[x, y, z, roll, pitch, yaw]`` (m, rad), before the soft start and
        clamping (a watchdog fade acts on its input).
    platform_pose : ndarray, shape (6,) or (3,)
        The pose the actuators realise: 6-RUS pose, or planar ``[x, y, phi]``.
    clamped : bool
        The workspace clamp moved the pose.
    angles : ndarray, shape (6,) or (3,)
        Actuator command, rad (always finite and within limits).
    servo_deg : ndarray of int, shape (3,), or None
        Planar mode: servo command in integer degrees.
    rate_limited : bool
        The safety stage's speed or acceleration limit changed the command.
    held : bool
        The safety stage replaced an unsafe command by the last safe one.
    phase : str
        ``"starting"``, ``"running"``, ``"stopping"`` or ``"parked"``.
    fade : float
        Watchdog fade in [0, 1]: the share of the held sample's deviation from level
        flight given to the washout (1 = the aircraft's motion, 0 = level flight).
    """

    t: float
    state: AircraftState | None
    fresh: bool
    accepted: bool
    washout_pose: np.ndarray
    platform_pose: np.ndarray
    clamped: bool
    angles: np.ndarray
    servo_deg: np.ndarray | None
    rate_limited: bool
    held: bool
    phase: str
    fade: float


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


# --------------------------------------------------------------------------- fused tick

# Pipeline state, one float vector shared by the fused kernel and the Python path.
_S_T, _S_TVALID, _S_PHASE, _S_BLEND, _S_FADE, _S_STALE, _S_ESTOP, _S_HAS_LAST = range(8)
_S_LAST = 8  # held sample: specific force (3), angular velocity (3)
_S_Q, _S_V, _S_WANTED, _S_POSE = 14, 20, 26, 32  # 6 each
_S_TACC = 38  # time of the last accepted sample
_S_VNEW = 39  # scratch: the limiter's new speeds
_NS = 45
_PHASES = ("starting", "running", "stopping", "parked")
_PHASE_CODES = {name: float(k) for k, name in enumerate(_PHASES[:3])}

# Pipeline constants of the fused kernel.
_C_DT, _C_STALE_TIMEOUT, _C_FADE_STEP, _C_BLEND_STEP = 0, 1, 2, 3
_C_MAX_F, _C_MAX_W, _C_MAX_ATT = 4, 5, 6
_C_LEVEL = 7  # level flight: (0, 0, -g, 0, 0, 0)
_C_PARK_POSE, _C_PARK_ANGLES, _C_LO, _C_HI, _C_VMAX, _C_AMAX = 13, 19, 25, 31, 37, 43
_NC = 49

# Status bits the fused kernel returns.
_F_PROBLEM = 0xF  # input problem code (safety._INPUT_PROBLEMS), 0 = accepted
_F_TIME_JUMP = 1 << 4
_F_FADE_START = 1 << 5
_F_CLAMPED = 1 << 6
_F_RATE_LIMITED = 1 << 7
_F_HELD = 1 << 8
_F_WASHOUT_ERROR = 1 << 9
_F_PHASE_SHIFT = 10  # two bits: index into _PHASES


def _dependency_stamp() -> str:
    """Hash of the sources of the kernels the fused tick compiles in.

    numba's on-disk cache keys a function on its own file only; the stamp, a closure
    variable of the fused kernel, is part of its cache key (numba hashes closure
    contents), so a change in the washout, kinematics or safety kernels recompiles it.
    """
    from motionbase import safety
    from motionbase.platform import _rus6_kernels
    from motionbase.washout import classical

    h = hashlib.sha256()
    for module in (classical, _rus6_kernels, safety):
        h.update(open(module.__file__, "rb").read())  # noqa: SIM115 - small files, read once
    return h.hexdigest()


@numba.njit(cache=True, error_model="numpy")
def _smooth(x):  # pragma: no cover - compiled; safety.smoothstep, compiled
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


def _make_rus6_tick(stamp: str):
    # the kernels called are module globals: only the stamp is a closure variable
    @numba.njit(cache=True, error_model="numpy")
    def rus6_tick(cf, st, G, c, s, t, f, w, att, fresh, wpose, pose, q):  # pragma: no cover
        """One 6-RUS tick, exactly :meth:`Pipeline.step_reference` but forward kinematics.

        Validation -> watchdog fade of the washout's input -> washout -> soft start/stop
        -> clamp + inverse (+ anti-windup track) -> safety limiter. Writes the washout
        pose, the clamped pose and the command into ``wpose``, ``pose``, ``q``; updates
        the washout state ``st`` and the pipeline state ``s``; returns the status bits
        (``_F_*``). When the limiter changed the command, ``s``'s pose is left at the
        previous tick's (the caller solves the forward kinematics from it).
        """
        if len(stamp) == 0:  # the stamp only keys the cache
            return -1
        dt = c[_C_DT]
        have_t = s[_S_TVALID] != 0.0
        # 1. validation
        code = _input_code(
            t, s[_S_T] if have_t else -np.inf, f, w, att, c[_C_MAX_F], c[_C_MAX_W], c[_C_MAX_ATT]
        )
        flags = code
        accepted = code == 0
        if accepted:
            if have_t and t - s[_S_T] > c[_C_STALE_TIMEOUT]:
                flags |= _F_TIME_JUMP
                s[_S_FADE] = 0.0  # the input restarts from level flight (no filter reset)
            s[_S_HAS_LAST] = 1.0
            for i in range(3):
                s[_S_LAST + i] = f[i]
                s[_S_LAST + 3 + i] = w[i]
            s[_S_T] = t
            s[_S_TACC] = t
        else:
            s[_S_T] = (s[_S_T] if have_t else 0.0) + dt
        s[_S_TVALID] = 1.0
        # 2. watchdog fade of the washout's input (stale: marked so, or nothing accepted)
        if not fresh or s[_S_T] - s[_S_TACC] > c[_C_STALE_TIMEOUT]:
            if s[_S_STALE] == 0.0:
                flags |= _F_FADE_START
            s[_S_STALE] = 1.0
            x = s[_S_FADE] - c[_C_FADE_STEP]
            fade = x if x > 0.0 else 0.0
        else:
            s[_S_STALE] = 0.0
            x = s[_S_FADE] + c[_C_FADE_STEP]
            fade = x if x < 1.0 else 1.0
        s[_S_FADE] = fade
        # 3. washout on the held sample (level flight before any), faded toward level flight
        if s[_S_HAS_LAST] == 0.0:
            u = c[_C_LEVEL : _C_LEVEL + 6]
        elif fade == 1.0:
            u = s[_S_LAST : _S_LAST + 6]
        else:
            sf = _smooth(fade)
            u = np.empty(6)
            for i in range(6):
                lv = c[_C_LEVEL + i]
                u[i] = lv + sf * (s[_S_LAST + i] - lv)
        if not _step(cf, st, u, wpose):
            return flags | _F_WASHOUT_ERROR
        # 4. soft start / stop
        phase = s[_S_PHASE]
        blend = s[_S_BLEND]
        if phase == 0.0:
            x = blend + c[_C_BLEND_STEP]
            blend = x if x < 1.0 else 1.0
            if blend >= 1.0:
                phase = 1.0
        elif phase == 2.0 and s[_S_ESTOP] == 0.0:
            x = blend - c[_C_BLEND_STEP]
            blend = x if x > 0.0 else 0.0
        s[_S_PHASE] = phase
        s[_S_BLEND] = blend
        b = _smooth(blend)
        target = np.empty(6)
        for i in range(6):
            if b < 1.0:
                p0 = c[_C_PARK_POSE + i]
                target[i] = p0 + b * (wpose[i] - p0)
            else:
                target[i] = wpose[i]
        # 5. clamp (+ anti-windup), 6. inverse kinematics; park by its angles exactly
        wanted = np.empty(6)
        clamped = False
        if phase == 2.0 and b == 0.0:
            for i in range(6):
                pose[i] = c[_C_PARK_POSE + i]
                wanted[i] = c[_C_PARK_ANGLES + i]
        elif _inverse_row(target, G, wanted) == 0 and _within(wanted, G):
            # reachable as it is (what clamp_inverse_one finds first): its angles are solved
            for i in range(6):
                pose[i] = target[i]
        else:
            clamped = clamp_inverse_one(target, G, pose, wanted)
        if clamped:
            flags |= _F_CLAMPED
            if phase == 1.0:  # the target is the washout's pose: tell it (anti-windup)
                for i in range(6):
                    if not np.isfinite(pose[i]):
                        return flags | _F_WASHOUT_ERROR
                _track(st, pose)
        # 7. safety
        status = _limit_kernel(
            s[_S_Q : _S_Q + 6],
            s[_S_V : _S_V + 6],
            s[_S_WANTED : _S_WANTED + 6],
            wanted,
            dt,
            c[_C_LO : _C_LO + 6],
            c[_C_HI : _C_HI + 6],
            c[_C_VMAX : _C_VMAX + 6],
            c[_C_AMAX : _C_AMAX + 6],
            q,
            s[_S_VNEW : _S_VNEW + 6],
        )
        held = (status & 2) != 0
        limited = (status & 1) != 0
        at_park = True
        for i in range(6):
            s[_S_WANTED + i] = q[i] if held else wanted[i]
            s[_S_Q + i] = q[i]
            v = s[_S_VNEW + i]
            s[_S_V + i] = v
            if not (q[i] == c[_C_PARK_ANGLES + i] and v == 0.0):
                at_park = False
            if not (held or limited):
                s[_S_POSE + i] = pose[i]
        if held:
            flags |= _F_HELD
        if limited:
            flags |= _F_RATE_LIMITED
        out_phase = 3 if (phase == 2.0 and blend == 0.0 and at_park) else int(phase)
        return flags | (out_phase << _F_PHASE_SHIFT)

    return rus6_tick


_rus6_tick = _make_rus6_tick(_dependency_stamp())


def _pipeline_constants(config: PipelineConfig, robot: _Robot) -> np.ndarray:
    c = np.zeros(_NC)
    c[_C_DT] = config.dt
    c[_C_STALE_TIMEOUT] = config.stale_timeout_s
    c[_C_FADE_STEP] = config.dt / config.fade_s
    c[_C_BLEND_STEP] = config.dt / config.soft_start_s
    lim = config.input_limits
    c[_C_MAX_F] = lim.max_specific_force
    c[_C_MAX_W] = lim.max_angular_velocity
    c[_C_MAX_ATT] = lim.max_attitude
    c[_C_LEVEL + 2] = -config.washout.gravity
    if robot.n == 6:
        c[_C_PARK_POSE : _C_PARK_POSE + 6] = robot.park_pose
        c[_C_PARK_ANGLES : _C_PARK_ANGLES + 6] = robot.park_angles
        c[_C_LO : _C_LO + 6] = robot.limits.lower
        c[_C_HI : _C_HI + 6] = robot.limits.upper
        c[_C_VMAX : _C_VMAX + 6] = robot.limits.max_speed
        c[_C_AMAX : _C_AMAX + 6] = robot.limits.max_accel
    return c


# --------------------------------------------------------------------------- core


class Pipeline:
    """The functional core: ``step(state) -> PipelineOutput``, no I/O.

    Parameters
    ----------
    config : PipelineConfig
    fast : bool
        6-RUS: run each tick in one compiled kernel (the default). ``False`` runs
        the reference path, stage by stage in Python (:meth:`step_reference`); both
        give bit-identical outputs and share one state, so they can be mixed.
    """

    def __init__(self, config: PipelineConfig, *, fast: bool = True) -> None:
        from motionbase.washout import ClassicalWashout

        self.config = config
        self.dt = config.dt
        self.robot = make_robot(config)
        self.washout = ClassicalWashout(config.washout, self.dt)
        self.health = Health()
        self._level_f = np.array([0.0, 0.0, -config.washout.gravity])
        self._zero3 = np.zeros(3)
        # the whole mutable state in one vector (see _S_*), shared by both paths
        self._s = np.zeros(_NS)
        n = self.robot.n
        self._qs = self._s[_S_Q : _S_Q + n]
        self._vs = self._s[_S_V : _S_V + n]
        self._wanted_s = self._s[_S_WANTED : _S_WANTED + n]
        self._pose_s = self._s[_S_POSE : _S_POSE + len(self.robot.park_pose)]
        self._c = _pipeline_constants(config, self.robot)
        self._fast = bool(fast) and config.robot == "rus6"
        self._G = self.robot.kin._G if config.robot == "rus6" else None
        self.reset()
        self.warm_up()

    # -- state (views of the state vector) ---------------------------------------
    @property
    def _q(self) -> np.ndarray:
        """Last command, rad (the live state: copy it to keep it)."""
        return self._qs

    @_q.setter
    def _q(self, value: np.ndarray) -> None:
        self._qs[:] = value

    @property
    def _v(self) -> np.ndarray:
        """Speed of the last command, rad/s (the live state)."""
        return self._vs

    @_v.setter
    def _v(self, value: np.ndarray) -> None:
        self._vs[:] = value

    @property
    def _wanted(self) -> np.ndarray:
        return self._wanted_s

    @_wanted.setter
    def _wanted(self, value: np.ndarray) -> None:
        self._wanted_s[:] = value

    @property
    def _pose(self) -> np.ndarray:
        return self._pose_s

    @_pose.setter
    def _pose(self, value: np.ndarray) -> None:
        self._pose_s[:] = value

    @property
    def _t(self) -> float | None:
        return float(self._s[_S_T]) if self._s[_S_TVALID] else None

    @_t.setter
    def _t(self, value: float | None) -> None:
        self._s[_S_TVALID] = value is not None
        self._s[_S_T] = 0.0 if value is None else value

    @property
    def _phase(self) -> str:
        return _PHASES[int(self._s[_S_PHASE])]

    @_phase.setter
    def _phase(self, value: str) -> None:
        self._s[_S_PHASE] = _PHASE_CODES[value]

    @property
    def _blend(self) -> float:
        return float(self._s[_S_BLEND])

    @_blend.setter
    def _blend(self, value: float) -> None:
        self._s[_S_BLEND] = value

    @property
    def _fade(self) -> float:
        return float(self._s[_S_FADE])

    @_fade.setter
    def _fade(self, value: float) -> None:
        self._s[_S_FADE] = value

    @property
    def _stale(self) -> bool:
        return bool(self._s[_S_STALE])

    @_stale.setter
    def _stale(self, value: bool) -> None:
        self._s[_S_STALE] = bool(value)

    @property
    def _estop(self) -> bool:
        return bool(self._s[_S_ESTOP])

    @_estop.setter
    def _estop(self, value: bool) -> None:
        self._s[_S_ESTOP] = bool(value)

    def _hold(self, state: AircraftState | None) -> None:
        """Keep ``state``'s specific force and rates as the held sample (None: no sample)."""
        s = self._s
        s[_S_HAS_LAST] = state is not None
        if state is not None:
            s[_S_LAST : _S_LAST + 3] = state.specific_force
            s[_S_LAST + 3 : _S_LAST + 6] = state.angular_velocity

    # -- lifecycle -------------------------------------------------------------
    def reset(self) -> None:
        """Back to parked, filters at rest, counters kept."""
        self.washout.reset()
        self._q = self.robot.park_angles
        self._v = 0.0
        self._wanted = self.robot.park_angles
        self._pose = self.robot.park_pose
        self._hold(None)
        self._t = None
        self._s[_S_TACC] = 0.0
        self._phase = "starting"
        self._blend = 0.0  # 0 = park, 1 = live
        self._fade = 1.0
        self._stale = False
        self._estop = False

    def warm_up(self) -> None:
        """Load every compiled kernel now (numba's on-disk cache), so the first live tick is on
        time; the pipeline is left reset, its counters untouched."""
        counts = self.health.as_dict()
        self.step(AircraftState(0.0, self._level_f, self._zero3))
        self.step(None)
        self.robot.forward(self.robot.park_angles, guess=self.robot.park_pose)
        self.reset()
        for name, value in counts.items():
            setattr(self.health, name, value)

    def stop(self) -> None:
        """Ramp back to park at the soft-start pace: the blend from the live pose to park runs
        back over ``soft_start_s`` (the end of the input, a stop signal: SIGINT, SIGTERM,
        SIGHUP, SIGQUIT; a failing source or sink)."""
        if self._phase in ("starting", "running"):
            self._phase = "stopping"

    def estop(self) -> None:
        """Emergency stop: head for park at once, as fast as the actuators' speed and
        acceleration limits allow (the geometry's ``max_speed`` and ``max_accel``, never
        faster): a second stop signal while stopping, teleop's E-stop key, this call."""
        self.health.estops += 1
        self._estop = True
        self._phase = "stopping"
        self._blend = 0.0

    @property
    def parked(self) -> bool:
        """True once stopped with the actuators at park and at rest."""
        s = self._s
        return (
            s[_S_PHASE] == 2.0
            and s[_S_BLEND] == 0.0
            and bool(np.all(self._qs == self.robot.park_angles))
            and bool(np.all(self._vs == 0.0))
        )

    @property
    def phase(self) -> str:
        return "parked" if self.parked else self._phase

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
        if state is None or not self._fast:
            return self.step_reference(state, fresh)
        h = self.health
        h.samples += 1
        wpose = np.empty(6)
        pose = np.empty(6)
        q = np.empty(6)
        flags = _rus6_tick(
            self.washout._cf,
            self.washout._st,
            self._G,
            self._c,
            self._s,
            state.t,
            state.specific_force,
            state.angular_velocity,
            state.attitude,
            bool(fresh),
            wpose,
            pose,
            q,
        )
        if flags & 0x3FF:  # anything but the phase: the rare paths
            return self._after_rare_tick(state, fresh, flags, wpose, pose, q)
        return PipelineOutput(
            state.t,
            state,
            fresh,
            True,
            wpose,
            pose,
            False,
            q,
            None,
            False,
            False,
            _PHASES[flags >> _F_PHASE_SHIFT],
            float(self._s[_S_FADE]),
        )

    def _after_rare_tick(
        self,
        state: AircraftState,
        fresh: bool,
        flags: int,
        wpose: np.ndarray,
        pose: np.ndarray,
        q: np.ndarray,
    ) -> PipelineOutput:
        """The fused tick's bookkeeping when it did more than the plain path."""
        h = self.health
        if flags & _F_WASHOUT_ERROR:
            raise WashoutInputError(
                "washout input or tracked pose is not finite (reject the sample before the washout)"
            )
        code = flags & _F_PROBLEM
        if code:
            h.rejected_inputs += 1
            h.last_rejection = _INPUT_PROBLEMS[code]
        if flags & _F_TIME_JUMP:
            h.time_jumps += 1
        if flags & _F_FADE_START:
            h.watchdog_fades += 1
        clamped = bool(flags & _F_CLAMPED)
        if clamped:
            h.clamps += 1
        held = bool(flags & _F_HELD)
        rate_limited = bool(flags & _F_RATE_LIMITED)
        if held:
            h.unsafe_commands += 1
        if rate_limited:
            h.rate_limited += 1
        if held or rate_limited:
            # the actuators realise another pose than the one asked: say which
            achieved = self.robot.forward(q, guess=self._pose)
            if np.isfinite(achieved).all():
                pose = achieved
            self._pose = pose
        return PipelineOutput(
            state.t if code == 0 else float(self._s[_S_T]),
            state,
            fresh,
            code == 0,
            wpose,
            pose,
            clamped,
            q,
            None,
            rate_limited,
            held,
            _PHASES[flags >> _F_PHASE_SHIFT],
            float(self._s[_S_FADE]),
        )

    def step_reference(self, state: AircraftState | None, fresh: bool = True) -> PipelineOutput:
        """:meth:`step`, stage by stage in Python (the planar robot's path, and the
        reference the fused 6-RUS kernel is tested against)."""
        cfg = self.config
        dt = self.dt
        h = self.health
        h.samples += 1

        # 1. validation (against the last output time, so ticks stay strictly increasing)
        accepted = state is not None
        if state is not None:
            problem = input_problem(
                state.t,
                state.specific_force,
                state.angular_velocity,
                state.attitude,
                self._t,
                cfg.input_limits,
            )
            if problem is None:
                if self._t is not None and state.t - self._t > cfg.stale_timeout_s:
                    # the source stalled or jumped: the input restarts from level flight
                    # and fades into the new samples (the filters keep the pose continuous)
                    h.time_jumps += 1
                    self._fade = 0.0
                self._hold(state)
            else:
                accepted = False
                h.rejected_inputs += 1
                h.last_rejection = problem
        t = state.t if accepted else (self._t if self._t is not None else 0.0) + dt
        self._t = t
        if accepted:
            self._s[_S_TACC] = t

        # 2. watchdog fade of the washout's input: stale when the source says so or when its
        # samples were all rejected for longer than the stale timeout (a tick without a
        # sample, after the source ended, holds the last one: the park ramp is in charge)
        stale = not fresh or (state is not None and t - self._s[_S_TACC] > cfg.stale_timeout_s)
        if stale and not self._stale:
            h.watchdog_fades += 1
        self._stale = stale
        step_fade = dt / cfg.fade_s
        fade = self._fade
        fade = max(0.0, fade - step_fade) if stale else min(1.0, fade + step_fade)
        self._fade = fade

        # 3. washout on the held sample (level flight before any), faded toward level flight
        if not self._s[_S_HAS_LAST]:
            f, w = self._level_f, self._zero3
        else:
            f, w = self._s[_S_LAST : _S_LAST + 3], self._s[_S_LAST + 3 : _S_LAST + 6]
            if fade != 1.0:
                sf = smoothstep(fade)
                f = self._level_f + sf * (f - self._level_f)
                w = self._zero3 + sf * (w - self._zero3)
        washout_pose = self.washout.step(f, w)
        live6 = washout_pose

        # 4. soft start / stop blend
        step_blend = dt / cfg.soft_start_s
        phase = self._phase
        if phase == "starting":
            self._blend = min(1.0, self._blend + step_blend)
            if self._blend >= 1.0:
                phase = self._phase = "running"
        elif phase == "stopping" and not self._estop:
            self._blend = max(0.0, self._blend - step_blend)
        s = smoothstep(self._blend)
        robot = self.robot
        live = robot.pose_from_washout(live6)
        target = robot.park_pose + s * (live - robot.park_pose) if s < 1.0 else live

        # 5. clamp (+ anti-windup while running), 6. inverse kinematics;
        # park is commanded by its angles exactly
        if phase == "stopping" and s == 0.0:
            pose, clamped, wanted = robot.park_pose, False, robot.park_angles
        else:
            pose, clamped, wanted = robot.solve(target)
        if clamped:
            h.clamps += 1
            if phase == "running":  # the target is the washout's pose (anti-windup)
                self.washout.track(robot.washout_from_pose(pose, washout_pose))

        # 7. safety
        q, v, status = limit_command(self._q, self._v, self._wanted, wanted, dt, robot.limits)
        held = bool(status & UNSAFE_TARGET)
        self._wanted = q if held else wanted
        rate_limited = bool(status & RATE_LIMITED)
        if held:
            h.unsafe_commands += 1
        if rate_limited:
            h.rate_limited += 1
        if held or rate_limited:
            # the actuators realise another pose than the one asked: say which
            achieved = robot.forward(q, guess=self._pose)
            if np.isfinite(achieved).all():
                pose = achieved
        self._q, self._v, self._pose = q, v, pose

        return PipelineOutput(
            t=t,
            state=state,
            fresh=fresh,
            accepted=accepted,
            washout_pose=washout_pose,
            platform_pose=pose,
            clamped=clamped,
            angles=q,
            servo_deg=robot.servo(q),
            rate_limited=rate_limited,
            held=held,
            phase="parked" if phase == "stopping" and self.parked else phase,
            fade=fade,
        )


# --------------------------------------------------------------------------- loop


#: Thread switch interval while :func:`run` runs, s (see its notes).
SWITCH_INTERVAL_S = 2e-4


@numba.njit(cache=True)
def _track_peaks(peak_angle, peak_speed, angles, speeds):  # pragma: no cover - compiled
    """np.maximum(peak, |x|, out=peak) for both, in one call (NaN sticks, as there)."""
    for i in range(angles.shape[0]):
        for peak, x in ((peak_angle, angles[i]), (peak_speed, speeds[i])):
            a = abs(x)
            if peak[i] == peak[i] and not (a <= peak[i]):
                peak[i] = a


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
    peak_angle, peak_speed : ndarray, shape (n,)
        Largest |angle| (rad) and |speed| (rad/s) per actuator in the ``running`` phase
        (zeros when the run never got there).
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
        What ended the run (``"end of source"``, ``"SIGINT"``, ``"sink failure"``, ...).
    """

    samples: int = 0
    running_samples: int = 0
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    clamped: int = 0
    peak_angle: np.ndarray | None = None
    peak_speed: np.ndarray | None = None
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


def _sink_name(sink: Any) -> str:
    """How a sink is named in a message: its URL or file, else its type."""
    for attr in ("label", "path"):
        name = getattr(sink, attr, None)
        if name:
            return str(name)
    return type(sink).__name__


def run(
    pipeline: Pipeline,
    source: Iterable[AircraftState],
    sinks: Sequence[Any] = (),
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
    is its ``__cause__``); a source's other exception unchanged (a bug).

    Parameters
    ----------
    pipeline : Pipeline
    source : iterable of AircraftState
        Already entered (``with source:``). A source may expose ``fresh`` (bool) to
        mark stale holds; ``paces_itself`` (bool), true when it hands its samples over
        in real time itself (a live link, a ``--realtime`` flight); and ``due_time``,
        when its last sample was due (s on :func:`time.monotonic`).
    sinks : sequence
        Objects with ``write(output)``, already entered. Sinks never wait: in a paced
        run only this loop keeps time.
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
    ``SWITCH_INTERVAL_S`` (and restored after): the MCAP writer thread needs the
    GIL for short stretches between its GIL-free calls (compression, checksum,
    file writes), and with Python's default 5 ms it waits up to 5 ms for each one
    behind the busy loop, falls seconds behind in as-fast-as-possible runs and
    queues chunks in memory.
    """
    old = sys.getswitchinterval()
    sys.setswitchinterval(min(old, SWITCH_INTERVAL_S))
    try:
        return _run(
            pipeline,
            source,
            sinks,
            paced=paced,
            busy_wait=busy_wait,
            stop=stop,
            progress=progress,
            max_park_s=max_park_s,
        )
    finally:
        sys.setswitchinterval(old)


def _run(
    pipeline: Pipeline,
    source: Iterable[AircraftState],
    sinks: Sequence[Any],
    *,
    paced: bool,
    busy_wait: bool,
    stop: StopRequest | None,
    progress: Callable[[PipelineOutput], None] | None,
    max_park_s: float,
) -> RunSummary:
    stop = stop if stop is not None else StopRequest()  # (an unset StopRequest is falsy)
    summary = RunSummary(health=pipeline.health)
    robot = pipeline.robot
    health = pipeline.health
    dt = pipeline.dt
    n = robot.n
    run_angle, run_speed = np.zeros(n), np.zeros(n)  # the flight's peaks
    ramp_angle = np.zeros(n)  # (the ramps' angles: not reported, park is known)
    start_speed, stop_speed = np.zeros(n), np.zeros(n)
    ticks = {"starting": 0, "stopping": 0}
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

    def fail(exc: BaseException, what: str, sink: Any = None) -> None:
        nonlocal failure, failed_sink
        if failure is None:
            failure = exc
            failed_sink = sink
            summary.stopped_by = f"{what} failure"
            stop.set(f"{what} failure")

    def pace() -> float:
        """Wait for the next tick's due time on this loop's schedule; return it."""
        nonlocal next_due
        due = clock() if next_due is None else next_due
        wait_until(due, busy=busy_wait, clock=clock)
        now = clock()
        # more than half a period late: the schedule restarts here (never burst to catch up)
        next_due = (now if now - due > 0.5 * dt else due) + dt
        return due

    def emit(out: PipelineOutput, started: float, due: float) -> None:
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
            _track_peaks(run_angle, run_speed, out.angles, speeds)
        else:
            ramp = "starting" if phase == "starting" else "stopping"
            ticks[ramp] += 1
            ramp_speed = start_speed if ramp == "starting" else stop_speed
            _track_peaks(ramp_angle, ramp_speed, out.angles, speeds)
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
                if late > health.worst_overrun_s:
                    health.worst_overrun_s = late
            # what the actuators see: the command within one period of its sample's due time
            late = now - due - dt
            if late > 0.0:
                health.late_commands += 1
                if late > health.worst_late_s:
                    health.worst_late_s = late

    def apply_stop() -> None:
        if pipeline._phase in ("starting", "running"):
            pipeline.estop() if stop.estop else pipeline.stop()
        elif stop.estop and not pipeline._estop:
            pipeline.estop()

    stopping_requested = False
    iterator = iter(source)
    # per-tick lookups done once: the live speed vector, the stop flag, the fresh mark
    speeds = pipeline._v
    stop_raised = stop._event.is_set if isinstance(stop, StopRequest) else stop.__bool__
    has_fresh = hasattr(source, "fresh")
    started = cpu_started = due = 0.0
    step = pipeline.step
    scratch = np.zeros(n)
    _track_peaks(scratch, scratch.copy(), scratch, scratch)  # loaded now, not in the first tick
    # a stop asked before the first tick (while the program loaded): nothing moves, the
    # source is not read; the run is one park tick
    while not (summary.samples == 0 and stop_raised()):
        try:
            state = next(iterator)
        except StopIteration:
            break
        except Exception as exc:  # noqa: BLE001 - the source failed: park on held samples
            fail(exc, "source")
            break
        if paced:
            if loop_paces:
                due = pace()
            started, cpu_started = clock(), cpu_clock()
            if not loop_paces:
                due = getattr(source, "due_time", None)
                if due is None:
                    due = started
                next_due = started + dt  # the park ticks follow on this loop's schedule
        if stop_raised() and (not stopping_requested or (stop.estop and not pipeline._estop)):
            if not stopping_requested:
                summary.stopped_by = stop.reason
            stopping_requested = True
            apply_stop()
        out = step(state, bool(source.fresh) if has_fresh else True)
        emit(out, started, due)
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
            if stop.estop and not pipeline._estop:
                pipeline.estop()
            if paced:
                due = pace()
            started, cpu_started = clock(), cpu_clock()
            if not paced:
                due = started
            emit(pipeline.step(None), started, due)
    if stop.estop and stop.estop_reason and stop.estop_reason != summary.stopped_by:
        summary.stopped_by += f", then an E-stop ({stop.estop_reason})"
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
    summary.peak_angle = run_angle
    summary.peak_speed = run_speed
    summary.start_s = ticks["starting"] * dt
    summary.stop_s = ticks["stopping"] * dt
    summary.start_peak_speed = start_speed
    summary.stop_peak_speed = stop_speed
    summary.angle_limits = (robot.limits.lower, robot.limits.upper)
    summary.max_speed = robot.limits.max_speed
    return summary


def with_overrides(config: PipelineConfig, **changes: Any) -> PipelineConfig:
    """A copy of ``config`` with some fields changed (None values ignored)."""
    return replace(config, **{k: v for k, v in changes.items() if v is not None})
