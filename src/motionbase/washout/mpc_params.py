"""Parameters of the model-predictive cueing (``--cueing mpc``), loaded from TOML presets.

A preset file (``src/motionbase/presets/mpc_<name>.toml``) looks like::

    description = "..."                # optional free text
    g = 9.80665                        # m/s^2, optional
    mode = "real-time"                 # optional: what the set was tuned for, "real-time"
                                       # or "preview" (offline runs with --preview)

    [horizon]
    steps = 15                         # prediction steps (the first is one tick long)
    step_s = 0.1                       # length of the others, s

    [weights]                          # of the quadratic cost, per second of horizon
    specific_force = [1.0, 1.0, 1.0]   # perceived specific-force error x, y, z, per (m/s^2)^2
    angular_velocity = [400, 400, 400] # perceived rate error roll, pitch, yaw, per (rad/s)^2
    position = [1, 1, 1, 10, 10, 1]    # pose (roll, pitch: the rotational part, not the tilt)
    velocity = [0.1, 0.1, 0.1, 0.1, 0.1, 0.1]
    acceleration = [0.01, 0.01, 0.01, 0.01, 0.01, 0.01]
    jerk = [1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4]
    tilt = [0.1, 0.0, 0.01, 1e-4]      # the tilt's angle, rate, acceleration, jerk
    false_cue = 0.0                    # optional: perceived platform motion past the
                                       # threshold where the aircraft's is not, per unit^2

    [tilt]                             # perception thresholds, hard constraints on the tilt
    rate_limit_deg_s = 3.0             # each one number, or [roll, pitch]
    accel_limit_deg_s2 = 8.0
    angle_limit_deg = 15.0

    [limits]                           # the platform's, from the robot (limits_from_robot)
    position_lower_m = [-0.27, -0.28, -0.17]
    position_upper_m = [0.32, 0.28, 0.10]
    angle_lower_deg = [-17, -15.8, -44]
    angle_upper_deg = [17, 27, 44]
    velocity_m_s = [0.4, 0.4, 0.3]
    angular_velocity_deg_s = [40, 40, 60]
    acceleration_m_s2 = [4, 4, 4]
    angular_acceleration_deg_s2 = [300, 300, 300]

    [reference]                        # optional: what the MPC tracks (defaults: as flown)
    specific_force_gain = [1.0, 1.0, 1.0]
    specific_force_limit = [3.0, 3.0, 1.0]        # m/s^2, on f - (0, 0, -g)
    angular_velocity_gain = [1.0, 1.0, 1.0]
    angular_velocity_limit_deg_s = [30, 30, 30]
    decay_s = 0.0                      # real-time mode: the sample decays over the horizon
                                       # with this time constant, s (0: held)

    [robot]                            # optional: with a robot bound (the pipeline binds it)
    actuator_margin = 0.02             # share of each actuator's range kept free
    speed_share = 0.9                  # share of each actuator's speed limit the plan may use
    accel_share = 0.9                  # and of its acceleration limit (also the braking one)
    steps = 7                          # prediction steps whose actuators are constrained
    speed_steps = 2                    # of which the first ones constrain the speeds and
                                       # accelerations too
    violation_weight = 1e5             # soft constraints: cost per (actuator unit)^2

    [solver]
    max_iter = 400                     # OSQP iteration budget per tick
    time_limit_ms = 4.0                # OSQP time budget per tick (0: none)
    eps_abs = 1e-4
    eps_rel = 1e-4
    blend_s = 0.5                      # blend to and from the fallback, s
    fallback = "tuned_ceart"           # washout preset, or TOML path (relative: to this file)

``fallback`` may also be a table of washout parameters (``[solver.fallback]``, the layout of
a washout file): a recording stores the values so (:meth:`MpcParams.self_contained`).

Every table is required but for ``[reference]`` (gains 1, no limits), ``[robot]``, ``[solver]``
(defaults as above), ``description``, ``g`` and ``mode``. The dataclass fields mirror the
file one to one, so ``from_dict(p.to_dict()) == p``.
The pose box, speed and acceleration limits of ``[limits]`` are the robot's, written by
:func:`limits_from_robot` when the preset is made for a platform (the ``ceart`` and
``seat`` presets' headers say how); they hold with or without a robot. When the pipeline
binds its robot (:meth:`~motionbase.washout.cueing.Cueing.bind_robot`) the actuators are
constrained too (``[robot]``), and a box past the robot's reach is warned of
(:func:`motionbase.washout.mpc.check_reach`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from motionbase.config import (
    as_array,
    as_float,
    check_keys,
    read_toml,
    resolve_preset_or_path,
    write_toml,
)
from motionbase.errors import ConfigError
from motionbase.washout.params import STANDARD_GRAVITY, WashoutParams, tilt_pair

__all__ = ["MpcParams", "limits_from_robot"]

Vec3 = tuple[float, float, float]
Vec6 = tuple[float, float, float, float, float, float]

#: The most prediction steps: the QP's matrices grow with the square of them (2000 steps
#: asked for 29 GB), and 100 steps of 0.1 s are a 10 s horizon, far more than a cue needs.
MAX_STEPS = 100

#: The range of a prediction step, s: a tick of the fastest pipeline (10 kHz) to a minute.
#: Far outside it the QP's matrices are not factorisable in double precision (OSQP's set-up
#: failed, with a traceback, at 1e-100 s and at 1e30 s).
STEP_RANGE_S = (1e-4, 60.0)

#: The most iterations OSQP takes (its C library's 32-bit integer); more was a traceback.
MAX_ITER = 2**31 - 1

#: (section, key, field name, length (0: scalar), strictly positive, integer)
_SCHEMA: tuple[tuple[str, str, str, int, bool, bool], ...] = (
    ("horizon", "steps", "steps", 0, True, True),
    ("horizon", "step_s", "step_s", 0, True, False),
    ("weights", "specific_force", "w_specific_force", 3, False, False),
    ("weights", "angular_velocity", "w_angular_velocity", 3, False, False),
    ("weights", "position", "w_position", 6, False, False),
    ("weights", "velocity", "w_velocity", 6, False, False),
    ("weights", "acceleration", "w_acceleration", 6, False, False),
    ("weights", "jerk", "w_jerk", 6, False, False),
    ("weights", "tilt", "w_tilt", 4, False, False),
    ("weights", "false_cue", "w_false_cue", 0, False, False),
    ("tilt", "rate_limit_deg_s", "tilt_rate_limit_deg_s", 2, True, False),
    ("tilt", "accel_limit_deg_s2", "tilt_accel_limit_deg_s2", 2, True, False),
    ("tilt", "angle_limit_deg", "tilt_angle_limit_deg", 2, False, False),
    ("limits", "position_lower_m", "position_lower_m", 3, False, False),
    ("limits", "position_upper_m", "position_upper_m", 3, True, False),
    ("limits", "angle_lower_deg", "angle_lower_deg", 3, False, False),
    ("limits", "angle_upper_deg", "angle_upper_deg", 3, True, False),
    ("limits", "velocity_m_s", "velocity_m_s", 3, True, False),
    ("limits", "angular_velocity_deg_s", "angular_velocity_deg_s", 3, True, False),
    ("limits", "acceleration_m_s2", "acceleration_m_s2", 3, True, False),
    ("limits", "angular_acceleration_deg_s2", "angular_acceleration_deg_s2", 3, True, False),
    ("reference", "specific_force_gain", "specific_force_gain", 3, False, False),
    ("reference", "specific_force_limit", "specific_force_limit", 3, True, False),
    ("reference", "angular_velocity_gain", "angular_velocity_gain", 3, False, False),
    ("reference", "angular_velocity_limit_deg_s", "angular_velocity_limit_deg_s", 3, True, False),
    ("reference", "decay_s", "reference_decay_s", 0, False, False),
    ("robot", "actuator_margin", "actuator_margin", 0, False, False),
    ("robot", "speed_share", "speed_share", 0, True, False),
    ("robot", "accel_share", "accel_share", 0, True, False),
    ("robot", "steps", "robot_steps", 0, True, True),
    ("robot", "violation_weight", "violation_weight", 0, True, False),
    ("robot", "speed_steps", "robot_speed_steps", 0, True, True),
    ("solver", "max_iter", "max_iter", 0, True, True),
    ("solver", "time_limit_ms", "time_limit_ms", 0, False, False),
    ("solver", "eps_abs", "eps_abs", 0, True, False),
    ("solver", "eps_rel", "eps_rel", 0, False, False),
    ("solver", "blend_s", "blend_s", 0, True, False),
)
#: The optional fields and their values when left out, per section; every other field of
#: ``_SCHEMA`` is required (a section whose fields are all optional may be left out whole).
_DEFAULTS: dict[str, dict[str, Any]] = {
    "weights": {"false_cue": 0.0},
    "reference": {
        "specific_force_gain": [1.0, 1.0, 1.0],
        "specific_force_limit": [1000.0, 1000.0, 1000.0],
        "angular_velocity_gain": [1.0, 1.0, 1.0],
        "angular_velocity_limit_deg_s": [1000.0, 1000.0, 1000.0],
        "decay_s": 0.0,
    },
    "robot": {
        "actuator_margin": 0.02,
        "speed_share": 0.9,
        "accel_share": 0.9,
        "steps": 7,
        "speed_steps": 2,
        "violation_weight": 1e5,
    },
    "solver": {
        "max_iter": 400,
        "time_limit_ms": 4.0,
        "eps_abs": 1e-4,
        "eps_rel": 1e-4,
        "blend_s": 0.5,
        "fallback": "tuned_ceart",
    },
}
_SECTIONS = ("horizon", "weights", "tilt", "limits", "reference", "robot", "solver")
_TOP = ("description", "g", "mode", *_SECTIONS)
#: What a set can be made for (``mode``): a live run, or an offline one that sees the future.
MODES = ("real-time", "preview")


@dataclass(frozen=True)
class MpcParams:
    """Every number of the model-predictive cueing (:mod:`motionbase.washout.mpc`).

    Attributes
    ----------
    steps : int
        Prediction steps N (>= 2): the first lasts one tick (the pipeline's ``dt``), the
        others ``step_s``; the horizon is ``dt + (N - 1) step_s``.
    step_s : float
        Length of the prediction steps after the first, s.
    w_specific_force, w_angular_velocity : (3,) float
        Cost weights of the perceived specific-force error (per (m/s^2)^2 s) and of the
        perceived angular-velocity error (per (rad/s)^2 s), x y z / roll pitch yaw.
    w_position, w_velocity, w_acceleration, w_jerk : (6,) float
        Cost weights of the pose (m or rad; for roll and pitch the rotational part, the
        tilt apart), its rate, its acceleration and the jerk (change of the acceleration),
        per axis x, y, z, roll, pitch, yaw.
    w_tilt : (4,) float
        Cost weights of the tilt angle, rate, acceleration and jerk (roll and pitch alike).
    w_false_cue : float
        Cost weight of false cues (0: none, the default): at each step and axis, the
        perceived platform specific force (m/s^2) or rate (rad/s) beyond the perception
        threshold where the aircraft's perceived one is below it or of the other sign, per
        unit^2 s (soft constraints with a slack each; see :mod:`motionbase.washout.mpc`).
    tilt_rate_limit_deg_s, tilt_accel_limit_deg_s2, tilt_angle_limit_deg : (2,) float
        Hard limits of the tilt (the perception thresholds of rotation) per tilt axis
        (roll, pitch), deg/s, deg/s^2, deg. The file may give one number for both.
    position_lower_m, position_upper_m : (3,) float
        Pose box, m (lower < 0 < upper).
    angle_lower_deg, angle_upper_deg : (3,) float
        Pose box, deg (lower < 0 < upper).
    velocity_m_s, angular_velocity_deg_s : (3,) float
        Largest pose rates, m/s and deg/s (Euler angle rates).
    acceleration_m_s2, angular_acceleration_deg_s2 : (3,) float
        Largest pose accelerations, m/s^2 and deg/s^2.
    specific_force_gain, specific_force_limit : (3,) float
        The reference the MPC tracks is the aircraft's specific-force deviation from level
        flight, limited to ``+-limit`` (m/s^2) and times the gain, per axis: a force no
        platform can render (a 4 g pull-up) would otherwise hold the platform at its
        limit for a gain too small to feel.
    angular_velocity_gain, angular_velocity_limit_deg_s : (3,) float
        The same for the body rates (deg/s).
    reference_decay_s : float
        Real-time mode: how the MPC predicts the reference over its horizon. 0 (the
        default): the current sample, held. Otherwise the current sample decaying toward
        level flight, ``d(tau) = d(0) exp(-tau / reference_decay_s)`` for a step ``tau``
        seconds ahead (s): a transient (a doublet, a gust) is not planned for as if it
        lasted the whole horizon. Preview mode uses the recorded future instead.
    actuator_margin : float
        With a robot bound (:meth:`~motionbase.washout.mpc.MpcCueing.bind_robot`): the
        share of each actuator's range kept free of the linearised constraint, in [0, 0.5).
    speed_share, accel_share : float
        The share of each actuator's speed and acceleration limits the plan may use, in
        (0, 1] (the rest covers what the linearisation leaves out); the actuators' stopping
        distances are those at ``accel_share`` of their acceleration limits.
    robot_steps, robot_speed_steps : int
        How many prediction steps constrain the actuator positions (the first ones, then
        spread to the last) and, of those, how many the speeds and accelerations too.
    violation_weight : float
        The actuator constraints are soft (so the problem stays feasible when the state is
        already past a re-linearised limit): cost of a violation, per (rad or m)^2, per
        constrained step.
    max_iter : int
        OSQP iterations per tick at most.
    time_limit_ms : float
        OSQP time per tick at most, ms (0: no limit).
    eps_abs, eps_rel : float
        OSQP tolerances.
    blend_s : float
        Pace of the blend from the MPC's pose to the fallback's and back, s: a full blend
        from rest takes ``1.25 blend_s`` (its pace ramps up over ``blend_s / 2``).
    fallback : str or WashoutParams
        The classical washout run alongside, for ticks the solver fails or is late: a
        preset name or a TOML path (read from a file, a relative path is relative to that
        file's folder, and kept as an absolute path, so that a copy written elsewhere still
        works), or the parameters themselves (a recording holds them:
        :meth:`self_contained`).
    g : float
        Gravity, m/s^2.
    description : str
    mode : str
        What the set was tuned for: ``"real-time"`` (the default), or ``"preview"``, for
        offline runs that see the reference's future (``fly --preview``,
        ``replay --preview``; ``tune --preview`` writes it). A preview set flown without
        the preview plans on the current sample alone, as the real-time mode does, with
        weights not tuned for that: :meth:`motionbase.washout.mpc.MpcCueing.made_for_preview`
        lets a command warn.
    """

    steps: int
    step_s: float
    w_specific_force: Vec3
    w_angular_velocity: Vec3
    w_position: Vec6
    w_velocity: Vec6
    w_acceleration: Vec6
    w_jerk: Vec6
    w_tilt: tuple[float, float, float, float]
    tilt_rate_limit_deg_s: tuple[float, float]
    tilt_accel_limit_deg_s2: tuple[float, float]
    tilt_angle_limit_deg: tuple[float, float]
    position_lower_m: Vec3
    position_upper_m: Vec3
    angle_lower_deg: Vec3
    angle_upper_deg: Vec3
    velocity_m_s: Vec3
    angular_velocity_deg_s: Vec3
    acceleration_m_s2: Vec3
    angular_acceleration_deg_s2: Vec3
    w_false_cue: float = 0.0
    specific_force_gain: Vec3 = (1.0, 1.0, 1.0)
    specific_force_limit: Vec3 = (1000.0, 1000.0, 1000.0)
    angular_velocity_gain: Vec3 = (1.0, 1.0, 1.0)
    angular_velocity_limit_deg_s: Vec3 = (1000.0, 1000.0, 1000.0)
    reference_decay_s: float = 0.0
    actuator_margin: float = 0.02
    speed_share: float = 0.9
    accel_share: float = 0.9
    robot_steps: int = 7
    robot_speed_steps: int = 2
    violation_weight: float = 1e5
    max_iter: int = 400
    time_limit_ms: float = 4.0
    eps_abs: float = 1e-4
    eps_rel: float = 1e-4
    blend_s: float = 0.5
    fallback: str | WashoutParams = "tuned_ceart"
    g: float = STANDARD_GRAVITY
    description: str = ""
    mode: str = "real-time"

    def __post_init__(self) -> None:
        validated = _validate(self.to_dict(), "MpcParams")
        for key, value in validated.items():
            object.__setattr__(self, key, value)

    # --- the fallback washout -------------------------------------------------------------

    @property
    def fallback_washout(self) -> WashoutParams:
        """The fallback washout's parameters (loaded when :attr:`fallback` names them)."""
        if isinstance(self.fallback, WashoutParams):
            return self.fallback
        return WashoutParams.load(self.fallback)

    @property
    def fallback_name(self) -> str:
        """The fallback washout as a message names it: its preset or file, or, for values
        (a recording's), ``"recorded with the run"`` and their description."""
        if isinstance(self.fallback, str):
            return self.fallback
        about = self.fallback.description
        return "recorded with the run" + (f" ({about})" if about else "")

    def self_contained(self) -> MpcParams:
        """The same parameters with the fallback washout's values in place of its name, so
        that :meth:`to_dict` holds every number the cueing uses: what a recording stores
        (:meth:`motionbase.pipeline.PipelineConfig.to_dict`), which then replays the same
        when the preset or file it named has changed or gone."""
        if isinstance(self.fallback, WashoutParams):
            return self
        return replace(self, fallback=self.fallback_washout)

    # --- SI views -------------------------------------------------------------------------

    @property
    def gravity(self) -> float:
        """Gravity, m/s^2."""
        return self.g

    @property
    def pose_lower(self) -> np.ndarray:
        """Pose box lower bounds ``[x, y, z, roll, pitch, yaw]``, m and rad, shape (6,)."""
        return np.concatenate([self.position_lower_m, np.radians(self.angle_lower_deg)])

    @property
    def pose_upper(self) -> np.ndarray:
        """Pose box upper bounds, m and rad, shape (6,)."""
        return np.concatenate([self.position_upper_m, np.radians(self.angle_upper_deg)])

    @property
    def velocity_limit(self) -> np.ndarray:
        """Largest pose rates, m/s and rad/s, shape (6,)."""
        return np.concatenate([self.velocity_m_s, np.radians(self.angular_velocity_deg_s)])

    @property
    def acceleration_limit(self) -> np.ndarray:
        """Largest pose accelerations, m/s^2 and rad/s^2, shape (6,)."""
        return np.concatenate(
            [self.acceleration_m_s2, np.radians(self.angular_acceleration_deg_s2)]
        )

    @property
    def tilt_limits(self) -> np.ndarray:
        """Tilt angle, rate and acceleration limits (rows), rad, rad/s, rad/s^2, per tilt
        axis roll, pitch (columns), shape (3, 2)."""
        return np.radians(
            [self.tilt_angle_limit_deg, self.tilt_rate_limit_deg_s, self.tilt_accel_limit_deg_s2]
        )

    # --- construction ---------------------------------------------------------------------

    @classmethod
    def load(cls, name_or_path: str | Path) -> MpcParams:
        """A preset name (``"ceart"``: ``presets/mpc_ceart.toml``) or a TOML path."""
        return cls.from_toml(resolve_preset_or_path("mpc", name_or_path))

    @classmethod
    def from_toml(cls, path: str | Path) -> MpcParams:
        """Read an MPC TOML file (format in the module docstring)."""
        return cls.from_dict(read_toml(path), source=str(path))

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "mpc parameters") -> MpcParams:
        """Build from the nested mapping :meth:`to_dict` returns (or a parsed TOML file).

        Raises
        ------
        ConfigError
            On a missing, unknown, non-numeric or unphysical value, naming ``source``, the
            field and the fix.
        """
        if not isinstance(d, dict):
            raise ConfigError(f"{source}: expected a table of MPC parameters, got {d!r}")
        if "scaling" in d or "translational" in d:
            raise ConfigError(
                f"{source}: this is a classical washout file; give it with --cueing classical "
                "(an MPC file has [horizon], [weights], [tilt], [limits])"
            )
        check_keys(source, d, _TOP, required=("horizon", "weights", "tilt", "limits"))
        d = {k: (dict(v) if isinstance(v, dict) else v) for k, v in d.items()}
        d.setdefault("solver", {})
        d.setdefault("reference", {})
        d.setdefault("robot", {})
        for section in _SECTIONS:
            if not isinstance(d[section], dict):
                raise ConfigError(f"{source}: [{section}] must be a table, got {d[section]!r}")
            defaults = _DEFAULTS.get(section, {})
            keys = [k for s, k, *_ in _SCHEMA if s == section]
            keys += [k for k in defaults if k not in keys]  # (the solver's fallback)
            required = [k for k in keys if k not in defaults]
            check_keys(f"{source} [{section}]", d[section], keys, required=required)
            for key, value in defaults.items():
                d[section].setdefault(key, value)
        d.setdefault("g", STANDARD_GRAVITY)
        d.setdefault("description", "")
        d.setdefault("mode", "real-time")
        return cls(**_validate(d, source))

    def to_dict(self) -> dict[str, Any]:
        """Nested plain mapping (the TOML layout); :meth:`from_dict` rebuilds it exactly.
        A tilt limit equal for roll and pitch is one number."""
        out: dict[str, Any] = {"description": self.description, "g": self.g}
        if self.mode != "real-time":  # the default stays out of the file
            out["mode"] = self.mode
        for section, key, name, length, *_ in _SCHEMA:
            value = getattr(self, name)
            if section == "tilt" and value[0] == value[1]:
                value, length = value[0], 0
            out.setdefault(section, {})[key] = list(value) if length else value
        fallback = self.fallback
        out["solver"]["fallback"] = fallback if isinstance(fallback, str) else fallback.to_dict()
        return out

    def to_toml(self, path: str | Path) -> None:
        """Write the parameters as a TOML file that :meth:`from_toml` reads back."""
        write_toml(path, self.to_dict())


def _validate(d: dict[str, Any], source: str) -> dict[str, Any]:
    """Check the nested mapping; return the field values (tuples of floats, floats, ints)."""
    out: dict[str, Any] = {}
    for section, key, name, length, positive, integer in _SCHEMA:
        where = f"{section}.{key}"
        value = d[section][key]
        if integer:
            whole = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
            if not whole or (value < 1 and name != "steps"):  # (steps: its range, below)
                raise ConfigError(
                    f"{source}: field {where!r}: expected a whole number >= 1, got {value!r}"
                )
            out[name] = int(value)
            continue
        if length:
            if section == "tilt":
                arr = tilt_pair(source, where, value)
            else:
                arr = as_array(source, where, value, length)
            if name.endswith("lower_m") or name.endswith("lower_deg"):
                if not (arr < 0).all():
                    raise ConfigError(
                        f"{source}: field {where!r}: lower bounds must be < 0, got {arr.tolist()}"
                    )
            else:
                for v in arr:
                    as_float(source, where, float(v), min_value=0.0, strict_min=positive)
            out[name] = tuple(float(v) for v in arr)
        else:
            out[name] = as_float(source, where, value, min_value=0.0, strict_min=positive)
    if not 2 <= out["steps"] <= MAX_STEPS:  # (too few, or too many: longer steps do)
        raise ConfigError(
            f"{source}: field 'horizon.steps': must be from 2 to {MAX_STEPS}, got {out['steps']}"
            + (" (for a longer horizon, lengthen horizon.step_s)" if out["steps"] > 2 else "")
        )
    if out["max_iter"] > MAX_ITER:
        raise ConfigError(
            f"{source}: field 'solver.max_iter': must be at most {MAX_ITER} (OSQP counts its "
            f"iterations in a 32-bit integer), got {out['max_iter']} (fix the value)"
        )
    lo_s, hi_s = STEP_RANGE_S
    if not lo_s <= out["step_s"] <= hi_s:
        raise ConfigError(
            f"{source}: field 'horizon.step_s': must be from {lo_s:g} to {hi_s:g} s, got "
            f"{out['step_s']:g} (fix the value)"
        )
    if out["actuator_margin"] >= 0.5:
        raise ConfigError(
            f"{source}: field 'robot.actuator_margin': a share of the actuator range, must be "
            f"< 0.5, got {out['actuator_margin']}"
        )
    for share in ("speed_share", "accel_share"):
        if out[share] > 1.0:
            raise ConfigError(
                f"{source}: field 'robot.{share}': must be in (0, 1], got {out[share]}"
            )
    if max(out["tilt_angle_limit_deg"]) >= 90.0:
        raise ConfigError(f"{source}: field 'tilt.angle_limit_deg': must be < 90 deg")
    fallback = d["solver"]["fallback"]
    if isinstance(fallback, WashoutParams):
        fallback = fallback.to_dict()
    if isinstance(fallback, dict):  # the values themselves (a recording's)
        out["fallback"] = WashoutParams.from_dict(fallback, source=f"{source}: solver.fallback")
        fallback = ""
    elif not isinstance(fallback, str) or not fallback:
        raise ConfigError(
            f"{source}: field 'solver.fallback': expected a washout preset name, a .toml path "
            f"or a table of washout parameters, got {fallback!r}"
        )
    here = Path(source)
    if (fallback.endswith(".toml") or "/" in fallback) and here.is_file():
        fallback = str((here.parent / fallback).resolve())  # relative to the file, not cwd
    if fallback:
        try:  # a preset name or a file: load it now, so that a wrong one names this field
            WashoutParams.load(fallback)
        except ConfigError as exc:
            raise ConfigError(f"{source}: field 'solver.fallback': {exc}") from None
        out["fallback"] = fallback
    out["g"] = as_float(source, "g", d["g"], min_value=0.0, strict_min=True, unit="m/s^2")
    if not isinstance(d["description"], str):
        raise ConfigError(f"{source}: field 'description': expected text, got {d['description']!r}")
    out["description"] = d["description"]
    mode = d.get("mode", "real-time")
    if mode not in MODES:
        raise ConfigError(
            f"{source}: field 'mode': expected one of {', '.join(map(repr, MODES))}, got {mode!r}"
        )
    out["mode"] = mode
    return out


def limits_from_robot(
    robot: Any, margin: float = 0.9, rate_margin: float = 0.5
) -> dict[str, list[float]]:
    """The ``[limits]`` table of an MPC preset for a 6-DOF robot.

    The pose box is the robot's single-axis reach
    (:func:`motionbase.platform.rus6_workspace.single_axis_envelope`) times ``margin``. The
    pose rate and acceleration limits follow from the actuators' speed and acceleration
    limits through the inverse kinematics' Jacobian at neutral ``J = dq/dpose``: per pose
    axis, ``rate_margin * min_j(limit_j / |J_ji|)`` (with the default 0.5, two axes at
    their limits together stay within the actuators' at neutral; the pipeline's safety
    stage limits the actuators whatever the pose asks).

    Parameters
    ----------
    robot : Robot
        A 6-DOF robot plug-in (``inverse``, ``reachable``, ``limits``).
    margin : float
        Share of the single-axis reach the MPC may use, in (0, 1].
    rate_margin : float
        Share of the actuator speed and acceleration limits one pose axis may use.

    Returns
    -------
    dict
        The ``[limits]`` keys (m, deg, m/s, deg/s, m/s^2, deg/s^2).
    """
    from motionbase.platform.rus6_workspace import single_axis_envelope

    env = single_axis_envelope(robot, tol=1e-6)
    lower = np.array([-a.negative for a in env]) * margin
    upper = np.array([a.positive for a in env]) * margin
    _, J = robot.actuator_jacobian(np.zeros(6))  # at the zero cue pose: neutral
    aJ = np.abs(J)
    vel = rate_margin * np.min(np.asarray(robot.limits.max_speed)[:, None] / aJ, axis=0)
    acc = rate_margin * np.min(np.asarray(robot.limits.max_accel)[:, None] / aJ, axis=0)

    def r(v: np.ndarray, deg: bool) -> list[float]:
        return [float(f"{(math.degrees(x) if deg else x):.4g}") for x in v]

    return {
        "position_lower_m": r(lower[:3], False),
        "position_upper_m": r(upper[:3], False),
        "angle_lower_deg": r(lower[3:], True),
        "angle_upper_deg": r(upper[3:], True),
        "velocity_m_s": r(vel[:3], False),
        "angular_velocity_deg_s": r(vel[3:], True),
        "acceleration_m_s2": r(acc[:3], False),
        "angular_acceleration_deg_s2": r(acc[3:], True),
    }
