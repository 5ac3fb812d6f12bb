"""Parameters of the classical washout, loaded from and saved to TOML presets.

A preset file (``src/motionbase/presets/washout_<name>.toml``) looks like::

    description = "..."          # optional free text
    g = 9.80665                  # m/s^2, optional (standard gravity)
    method = "tustin"            # optional: "tustin" (pre-warped) or "zoh"

    [scaling]                    # per axis x, y, z (FRD)
    specific_force_gain = [0.5, 0.5, 0.4]
    specific_force_limit = [4.9, 4.9, 4.9]       # m/s^2, on f - (0, 0, -g)
    angular_velocity_gain = [0.5, 0.5, 0.5]
    angular_velocity_limit_deg_s = [30, 30, 30]  # deg/s, on the body rates

    [translational]              # s/((s^2 + 2 zeta wn s + wn^2)(s + wb)), per axis
    wn = [1.0, 1.0, 1.2]         # rad/s
    zeta = [1.0, 1.0, 1.0]
    wb = [0.3, 0.3, 0.3]         # rad/s
    accel_limit = [2.0, 0, 0]    # optional: the cue's largest acceleration, m/s^2 (0: off)
    velocity_limit = [0.4, 0, 0] # optional: the cue's largest velocity, m/s (0: off)

    [tilt]                       # wn^2/(s^2 + 2 zeta wn s + wn^2) on f_x, f_y
    wn = 2.0                     # rad/s
    zeta = 1.0
    rate_limit_deg_s = 3.0       # one number for roll and pitch, or [roll, pitch]
    angle_limit_deg = [6.0, 8.0] # [roll, pitch]: roll tilt renders f_y, pitch tilt f_x
    accel_limit_deg_s2 = 8.0     # optional (default 8 deg/s^2)

    [rotational]                 # s/(s^2 + 2 zeta wn s + wn^2) on Euler rates, per axis
    wn = [1.0, 0.8, 1.0]         # rad/s
    zeta = [1.0, 1.0, 1.0]

    [input]                      # optional: wn^2/(s + wn)^2 on every input channel
    lowpass_wn = 8.0             # rad/s; 0 (or no [input] table) turns it off

    [profile]                    # optional: flight-phase profiles
    blend_s = 3.0                # s (>= 0.5), the smoothstep blend when the phase changes
    [profile.ground.scaling]     # on the ground: these values override the ones above
    specific_force_gain = [0.7, 0.7, 0.6]
    [profile.air.tilt]           # in the air
    angle_limit_deg = 6.0

The dataclass fields mirror the file one to one (angles stay in degrees where the
name says ``_deg``), so ``from_dict(p.to_dict()) == p`` exactly; the SI values the
filter uses are the properties ``angular_velocity_limit``, ``tilt_rate_limit``,
``tilt_angle_limit`` and ``tilt_accel_limit`` (radians).

The tilt's three limits (``rate_limit_deg_s``, ``angle_limit_deg``, ``accel_limit_deg_s2``)
are each one number for both tilt axes or a pair ``[roll, pitch]``: the roll tilt renders
sustained sway (``f_y``), the pitch tilt sustained surge (``f_x``), and a platform's roll and
pitch reach, or the rotation a builder accepts about each axis, often differ. The fields are
always pairs; :meth:`WashoutParams.to_dict` writes one number when both are equal.

``tilt.accel_limit_deg_s2`` may be left out (files written before it existed): it then
takes :data:`DEFAULT_TILT_ACCEL_LIMIT_DEG_S2`. The ``[input]`` table may be left out too
(no input low-pass, as before it existed), and so may ``translational.accel_limit`` and
``translational.velocity_limit`` (the translational cue's own limits, per axis; 0 turns an
axis's limit off, the default: see :mod:`motionbase.washout.classical`, "Cue limiter").

Flight-phase profiles
---------------------
``[profile.ground]`` and ``[profile.air]`` (:data:`PROFILES`) each hold any of the tables
above (``scaling``, ``translational``, ``tilt``, ``rotational``, ``input``), full or partial:
the values they give replace the file's own for that flight phase
(:meth:`WashoutParams.for_profile`). A missing profile runs the file's own values. The
cueing switches between them by the source's flight phase
(:attr:`motionbase.state.AircraftState.on_ground`) with a smoothstep blend of
``[profile] blend_s`` seconds, at least :data:`MIN_PROFILE_BLEND_S`
(:mod:`motionbase.washout.profiles`); until the source gives a phase, the file's own values
run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from motionbase.config import (
    as_array,
    as_float,
    check_file_kind,
    check_keys,
    preset_path,
    read_toml,
    resolve_preset_or_path,
    write_toml,
)
from motionbase.errors import ConfigError
from motionbase.physics import STANDARD_GRAVITY
from motionbase.washout.filters import METHODS

#: Tilt acceleration limit when a file does not give one, deg/s^2. With the 3 deg/s rate
#: limit the tilt rate builds up in 0.375 s and glides onto the angle limit with that time
#: constant (braking starts about 1.1 deg before it); the linear tilt path needs at most
#: ~5.6 deg/s^2 for a 0.5 m/s^2 cue at 10 rad/s, so small cues are not distorted.
DEFAULT_TILT_ACCEL_LIMIT_DEG_S2 = 8.0

Vec3 = tuple[float, float, float]
#: A tilt limit per tilt axis: (roll, pitch).
Vec2 = tuple[float, float]

_SECTIONS: dict[str, tuple[str, ...]] = {
    "scaling": (
        "specific_force_gain",
        "specific_force_limit",
        "angular_velocity_gain",
        "angular_velocity_limit_deg_s",
    ),
    "translational": ("wn", "zeta", "wb", "accel_limit", "velocity_limit"),
    "tilt": ("wn", "zeta", "rate_limit_deg_s", "angle_limit_deg", "accel_limit_deg_s2"),
    "rotational": ("wn", "zeta"),
    "input": ("lowpass_wn",),
}
_TOP = ("description", "g", "method")
#: Keys that may be left out of a file, per section, with their default.
_OPTIONAL: dict[str, dict[str, float]] = {
    "tilt": {"accel_limit_deg_s2": DEFAULT_TILT_ACCEL_LIMIT_DEG_S2},
    "translational": {"accel_limit": 0.0, "velocity_limit": 0.0},
    "input": {"lowpass_wn": 0.0},
}
#: Tables that may be left out of a file (all their keys then take their defaults).
_OPTIONAL_SECTIONS = ("input",)
#: Optional per-axis keys, off (0) by default, written only when set.
_OFF_VECTORS: dict[str, tuple[str, ...]] = {"translational": ("accel_limit", "velocity_limit")}
#: Keys that hold one value per tilt axis (roll, pitch); the file may give one number.
_TILT_PAIRS = ("rate_limit_deg_s", "angle_limit_deg", "accel_limit_deg_s2")
#: The flight-phase profiles a file may hold (``[profile.<name>]``).
PROFILES = ("ground", "air")
#: Blend time between profiles when a file does not give one, s.
DEFAULT_PROFILE_BLEND_S = 3.0
#: The shortest blend, s: a switch at once steps the cue by the profiles' difference (on a
#: bouncing landing, every tick), far beyond any cue or actuator limit.
MIN_PROFILE_BLEND_S = 0.5

_TOP_OPTIONAL = ("profile",)


@dataclass(frozen=True)
class WashoutParams:
    """Every number of the classical washout (Reid & Nahon), per axis x, y, z (FRD).

    Attributes
    ----------
    specific_force_gain : (3,) float
        K_f, dimensionless, >= 0, applied to the specific force's deviation from
        level flight ``f - (0, 0, -g)``.
    specific_force_limit : (3,) float
        Saturation of that deviation before the gain, m/s^2, > 0.
    angular_velocity_gain : (3,) float
        K_w, dimensionless, >= 0, on the body rates (p, q, r).
    angular_velocity_limit_deg_s : (3,) float
        Saturation of the body rates before the gain, deg/s, > 0.
    translational_wn, translational_zeta, translational_wb : (3,) float
        Third-order high-pass per axis: natural frequency (rad/s, > 0), damping (> 0)
        and first-order break (rad/s, > 0).
    tilt_wn, tilt_zeta : float
        Tilt-coordination low-pass: natural frequency (rad/s, > 0), damping (> 0).
    tilt_rate_limit_deg_s : (2,) float
        Largest tilt rate per tilt axis (roll, pitch), deg/s, > 0 (keep it below the
        canals' ~3 deg/s threshold). One number is taken for both axes.
    tilt_angle_limit_deg : (2,) float
        Largest tilt angle per tilt axis (roll, pitch), deg, in [0, 90); 0 disables tilt
        coordination about that axis (roll: sway, pitch: surge).
    rotational_wn, rotational_zeta : (3,) float
        Second-order high-pass on the Euler rates per axis (roll, pitch, yaw).
    tilt_accel_limit_deg_s2 : (2,) float
        Largest change of the tilt rate per tilt axis (roll, pitch), deg/s^2, > 0: the
        tilt rate builds up and dies down smoothly, and the tilt brakes before its angle
        limit instead of stopping dead on it.
    input_lowpass_wn : float
        Natural frequency of the critically damped second-order low-pass on every input
        channel, rad/s, >= 0; 0 turns it off (for sources that hold sparse samples, such as
        MAVLink telemetry at a few Hz).
    translational_accel_limit, translational_velocity_limit : (3,) float
        Largest acceleration (m/s^2) and velocity (m/s) of the translational cue per axis
        x, y, z, >= 0; 0 turns that axis's limit off (the default).
    profile_blend_s : float
        Blend time between flight-phase profiles, s, >= 0.
    profiles : tuple of (name, overrides)
        The flight-phase profiles: per name (:data:`PROFILES`), the values it overrides as
        ``((section, key, value), ...)`` (values as in the file: a number or a 3-tuple).
        Empty without profiles. :meth:`for_profile` gives a profile's parameters.
    g : float
        Gravity, m/s^2, > 0.
    method : str
        Discretisation, ``"tustin"`` (pre-warped at each block's wn) or ``"zoh"``.
    description : str
        Free text.
    """

    specific_force_gain: Vec3
    specific_force_limit: Vec3
    angular_velocity_gain: Vec3
    angular_velocity_limit_deg_s: Vec3
    translational_wn: Vec3
    translational_zeta: Vec3
    translational_wb: Vec3
    tilt_wn: float
    tilt_zeta: float
    tilt_rate_limit_deg_s: Vec2
    tilt_angle_limit_deg: Vec2
    rotational_wn: Vec3
    rotational_zeta: Vec3
    tilt_accel_limit_deg_s2: Vec2 = (DEFAULT_TILT_ACCEL_LIMIT_DEG_S2,) * 2
    input_lowpass_wn: float = 0.0
    translational_accel_limit: Vec3 = (0.0, 0.0, 0.0)
    translational_velocity_limit: Vec3 = (0.0, 0.0, 0.0)
    g: float = STANDARD_GRAVITY
    method: str = "tustin"
    description: str = ""
    profile_blend_s: float = DEFAULT_PROFILE_BLEND_S
    profiles: tuple = ()

    def __post_init__(self) -> None:
        # Validate (and normalise to floats) even when built directly in Python.
        d = self.to_dict()
        d.pop("profile", None)
        validated = _validate(d, "WashoutParams")
        for key, value in validated.items():
            object.__setattr__(self, key, value)
        object.__setattr__(
            self,
            "profile_blend_s",
            as_float(
                "WashoutParams",
                "profile.blend_s",
                self.profile_blend_s,
                min_value=MIN_PROFILE_BLEND_S,
                unit="s",
            ),
        )
        profiles = _profile_tables(
            "WashoutParams", {name: _unflatten(items) for name, items in self.profiles}
        )
        object.__setattr__(self, "profiles", profiles)
        for name in self.profile_names:
            self.for_profile(name)  # each profile must be valid on its own

    # --- flight-phase profiles -------------------------------------------------------------

    @property
    def profile_names(self) -> tuple[str, ...]:
        """The profiles this file defines, in :data:`PROFILES` order (empty without any)."""
        return tuple(name for name, _ in self.profiles)

    def for_profile(self, name: str | None) -> WashoutParams:
        """The parameters of profile ``name``: these values with the profile's overrides,
        and no profiles of their own (``self`` when ``name`` is None or not defined here).

        Raises
        ------
        ConfigError
            When the overrides make a value invalid (the message names the profile).
        """
        items = dict(self.profiles).get(name) if name is not None else None
        if items is None:
            return self if not self.profiles else replace(self, profiles=())
        return _resolve_profile(self.to_dict(), items, f"WashoutParams [profile.{name}]")

    def with_profile(self, name: str, values: WashoutParams) -> WashoutParams:
        """These parameters with profile ``name`` overriding just what makes
        :meth:`for_profile` of it give ``values``' washout values (the values it already
        overrode stay overrides); the file's own values and the other profiles are kept.

        Parameters
        ----------
        name : str
            One of :data:`PROFILES` (``"ground"``, ``"air"``).
        values : WashoutParams
            The profile's parameters (their own profiles, ``g``, ``method`` and
            description are not used).

        Raises
        ------
        ConfigError
            An unknown profile name.
        """
        if name not in PROFILES:
            raise ConfigError(f"profile {name!r} is unknown: a file may hold {', '.join(PROFILES)}")
        overridden = {(s, k) for s, k, _ in dict(self.profiles).get(name, ())}
        items = []
        for section, keys in _SECTIONS.items():
            for key in keys:
                field_name = _field(section, key)
                value = getattr(values, field_name)
                if (section, key) in overridden or value != getattr(self, field_name):
                    items.append((section, key, value))
        tables = {**dict(self.profiles), name: tuple(items)}
        return replace(self, profiles=tuple((n, tables[n]) for n in PROFILES if n in tables))

    # --- SI views -------------------------------------------------------------------------

    @property
    def angular_velocity_limit(self) -> np.ndarray:
        """Saturation of the body rates, rad/s, shape (3,)."""
        return np.deg2rad(np.asarray(self.angular_velocity_limit_deg_s, dtype=float))

    @property
    def gravity(self) -> float:
        """Gravity, m/s^2 (the field ``g``, under a longer name)."""
        return self.g

    @property
    def tilt_rate_limit(self) -> np.ndarray:
        """Largest tilt rate (roll, pitch), rad/s, shape (2,)."""
        return np.radians(self.tilt_rate_limit_deg_s)

    @property
    def tilt_angle_limit(self) -> np.ndarray:
        """Largest tilt angle (roll, pitch), rad, shape (2,)."""
        return np.radians(self.tilt_angle_limit_deg)

    @property
    def tilt_accel_limit(self) -> np.ndarray:
        """Largest tilt acceleration (roll, pitch), rad/s^2, shape (2,)."""
        return np.radians(self.tilt_accel_limit_deg_s2)

    # --- construction ---------------------------------------------------------------------

    @classmethod
    def preset(cls, name: str) -> WashoutParams:
        """A preset shipped with the package: ``"default"`` or ``"gentle"``."""
        return cls.from_toml(preset_path("washout", name))

    @classmethod
    def load(cls, name_or_path: str | Path) -> WashoutParams:
        """A preset name or a path to a TOML file."""
        return cls.from_toml(resolve_preset_or_path("washout", name_or_path))

    @classmethod
    def from_toml(cls, path: str | Path) -> WashoutParams:
        """Read a washout TOML file (format in the module docstring)."""
        return cls.from_dict(read_toml(path), source=str(path))

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "washout parameters") -> WashoutParams:
        """Build from the nested mapping :meth:`to_dict` returns (or a parsed TOML file).

        Raises
        ------
        ConfigError
            On a missing, unknown, non-numeric or unphysical value; the message names
            ``source``, the field and the fix.
        """
        if not isinstance(d, dict):
            raise ConfigError(f"{source}: expected a table of washout parameters, got {d!r}")
        check_file_kind(source, d, "washout")
        required = tuple(k for k in _SECTIONS if k not in _OPTIONAL_SECTIONS)
        check_keys(source, d, (*_TOP, *_TOP_OPTIONAL, *_SECTIONS), required=required)
        flat: dict[str, Any] = {}
        for section, keys in _SECTIONS.items():
            table = d.get(section, {})
            if not isinstance(table, dict):
                raise ConfigError(f"{source}: [{section}] must be a table, got {table!r}")
            optional = _OPTIONAL.get(section, {})
            required = tuple(k for k in keys if k not in optional)
            check_keys(f"{source} [{section}]", table, keys, required=required)
            for key in keys:
                flat[_field(section, key)] = table.get(key, optional.get(key))
        flat["g"] = d.get("g", STANDARD_GRAVITY)
        flat["method"] = d.get("method", "tustin")
        flat["description"] = d.get("description", "")
        values = _validate(_nest(flat), source)
        profile = d.get("profile", {})
        if not isinstance(profile, dict):
            raise ConfigError(f"{source}: [profile] must be a table, got {profile!r}")
        check_keys(f"{source} [profile]", profile, ("blend_s", *PROFILES))
        blend_s = as_float(
            source,
            "profile.blend_s",
            profile.get("blend_s", DEFAULT_PROFILE_BLEND_S),
            min_value=MIN_PROFILE_BLEND_S,
            unit="s",
        )
        tables = {name: profile[name] for name in profile if name != "blend_s"}
        profiles = _profile_tables(source, tables)
        base = _nest(values | {"description": values["description"]})
        for name, items in profiles:  # name the file when a profile's value is wrong
            _resolve_profile(base, items, f"{source} [profile.{name}]")
        return cls(**values, profile_blend_s=blend_s, profiles=profiles)

    def to_dict(self) -> dict[str, Any]:
        """Nested plain mapping (the TOML layout); :meth:`from_dict` rebuilds it exactly.

        The optional per-axis cue limits and the ``[profile]`` table appear only when set; a
        tilt limit equal for roll and pitch is one number."""
        flat = {name: getattr(self, name) for name in self.__dataclass_fields__}
        out = _nest(flat)
        for section, keys in _OFF_VECTORS.items():
            for key in keys:
                if not any(out[section][key]):
                    del out[section][key]
        for key in _TILT_PAIRS:
            value = out["tilt"][key]  # (a number before validation, when built directly)
            if isinstance(value, list) and len(value) == 2 and value[0] == value[1]:
                out["tilt"][key] = value[0]
        if self.profiles or self.profile_blend_s != DEFAULT_PROFILE_BLEND_S:
            profile: dict[str, Any] = {"blend_s": self.profile_blend_s}
            for name, items in self.profiles:
                profile[name] = _unflatten(items)
            out["profile"] = profile
        return out

    def to_toml(self, path: str | Path) -> None:
        """Write the parameters as a TOML file that :meth:`from_toml` reads back."""
        write_toml(path, self.to_dict())


# --- helpers -------------------------------------------------------------------------------


def _field(section: str, key: str) -> str:
    return key if section == "scaling" else f"{section}_{key}"


def _resolve_profile(base: dict[str, Any], items: tuple, source: str) -> WashoutParams:
    """The parameters of the nested mapping ``base`` with a profile's overrides applied."""
    d = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items() if k != "profile"}
    for section, key, value in items:
        d[section][key] = list(value) if isinstance(value, tuple) else value
    return WashoutParams.from_dict(d, source=source)


def _unflatten(items: tuple) -> dict[str, dict[str, Any]]:
    """``((section, key, value), ...)`` -> ``{section: {key: value}}`` (lists for vectors)."""
    out: dict[str, dict[str, Any]] = {}
    for section, key, value in items:
        out.setdefault(section, {})[key] = list(value) if isinstance(value, tuple) else value
    return out


def _profile_tables(source: str, tables: dict[str, Any]) -> tuple:
    """Check the ``[profile.<name>]`` tables; return them as hashable, ordered overrides."""
    out = []
    for name in tables:
        if name not in PROFILES:
            raise ConfigError(
                f"{source}: unknown profile {name!r} (a file may hold [profile.ground] and "
                "[profile.air])"
            )
    for name in PROFILES:
        if name not in tables:
            continue
        where = f"{source} [profile.{name}]"
        table = tables[name]
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: must be a table of washout tables, got {table!r}")
        check_keys(where, table, _SECTIONS)
        items = []
        for section, keys in _SECTIONS.items():
            sub = table.get(section, {})
            if not isinstance(sub, dict):
                raise ConfigError(f"{where} [{section}]: must be a table, got {sub!r}")
            check_keys(f"{where} [{section}]", sub, keys)
            for key in keys:
                if key not in sub:
                    continue
                value = sub[key]
                if isinstance(value, (list, tuple, np.ndarray)):
                    field = f"{section}.{key}"  # (``name`` is the profile's)
                    if _length(section, key) == 2:
                        arr = tilt_pair(where, field, value)
                    else:
                        arr = as_array(where, field, value, 3)
                    value = tuple(arr.tolist())
                else:
                    value = as_float(where, f"{section}.{key}", value)
                items.append((section, key, value))
        out.append((name, tuple(items)))
    return tuple(out)


def tilt_pair(source: str, name: str, value: Any) -> np.ndarray:
    """A tilt limit of a cueing file: one number or ``[roll, pitch]``, as an array (2,)
    (:func:`~motionbase.config.as_array`'s checks; its error says what the two are)."""
    try:
        return as_array(source, name, value, 2)
    except ConfigError as err:
        raise ConfigError(f"{err}; a tilt limit is one number or [roll, pitch]") from None


def _length(section: str, key: str) -> int:
    """How many values a vector key holds: 2 for the tilt's limits (roll, pitch), else 3."""
    return 2 if section == "tilt" and key in _TILT_PAIRS else 3


def _nest(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {
        "description": str(flat["description"]),
        "g": flat["g"],
        "method": flat["method"],
    }
    for section, keys in _SECTIONS.items():
        table = {}
        for key in keys:
            value = flat[_field(section, key)]
            table[key] = list(value) if isinstance(value, (tuple, list, np.ndarray)) else value
        out[section] = table
    return out


def _validate(d: dict[str, Any], source: str) -> dict[str, Any]:
    """Check the nested mapping; return flat field values (tuples of floats, floats)."""

    def vec(section: str, key: str, *, strict: bool, unit: str = "") -> tuple[float, ...]:
        """Per axis: x, y, z; the tilt's limits: roll, pitch (one number: all axes)."""
        name = f"{section}.{key}"
        value = d[section].get(key, 0.0)
        if _length(section, key) == 2:
            arr = tilt_pair(source, name, value)
        else:
            arr = as_array(source, name, value, 3)
        for v in arr:
            as_float(source, name, float(v), min_value=0.0, strict_min=strict, unit=unit)
        return tuple(float(v) for v in arr)

    def num(section: str, key: str, *, strict: bool, unit: str = "") -> float:
        return as_float(
            source, f"{section}.{key}", d[section][key], min_value=0.0, strict_min=strict, unit=unit
        )

    out: dict[str, Any] = {
        "specific_force_gain": vec("scaling", "specific_force_gain", strict=False),
        "specific_force_limit": vec("scaling", "specific_force_limit", strict=True, unit="m/s^2"),
        "angular_velocity_gain": vec("scaling", "angular_velocity_gain", strict=False),
        "angular_velocity_limit_deg_s": vec(
            "scaling", "angular_velocity_limit_deg_s", strict=True, unit="deg/s"
        ),
        "translational_wn": vec("translational", "wn", strict=True, unit="rad/s"),
        "translational_zeta": vec("translational", "zeta", strict=True),
        "translational_wb": vec("translational", "wb", strict=True, unit="rad/s"),
        "tilt_wn": num("tilt", "wn", strict=True, unit="rad/s"),
        "tilt_zeta": num("tilt", "zeta", strict=True),
        "tilt_rate_limit_deg_s": vec("tilt", "rate_limit_deg_s", strict=True, unit="deg/s"),
        "tilt_angle_limit_deg": vec("tilt", "angle_limit_deg", strict=False, unit="deg"),
        "tilt_accel_limit_deg_s2": vec("tilt", "accel_limit_deg_s2", strict=True, unit="deg/s^2"),
        "input_lowpass_wn": num("input", "lowpass_wn", strict=False, unit="rad/s"),
        "rotational_wn": vec("rotational", "wn", strict=True, unit="rad/s"),
        "rotational_zeta": vec("rotational", "zeta", strict=True),
        "translational_accel_limit": vec(
            "translational", "accel_limit", strict=False, unit="m/s^2"
        ),
        "translational_velocity_limit": vec(
            "translational", "velocity_limit", strict=False, unit="m/s"
        ),
        "g": as_float(source, "g", d["g"], min_value=0.0, strict_min=True, unit="m/s^2"),
    }
    if max(out["tilt_angle_limit_deg"]) >= 90.0:
        raise ConfigError(
            f"{source}: field 'tilt.angle_limit_deg': must be < 90 deg, "
            f"got {max(out['tilt_angle_limit_deg']):g} (fix the value)"
        )
    method = d["method"]
    if method not in METHODS:
        raise ConfigError(
            f"{source}: field 'method': must be one of {', '.join(METHODS)}, got {method!r}"
        )
    out["method"] = method
    description = d["description"]
    if not isinstance(description, str):
        raise ConfigError(f"{source}: field 'description': expected text, got {description!r}")
    out["description"] = description
    return out
