"""Geometry of the planar 3-RRR robot: dimensions, working modes, servo mapping, safety limits.

Read from and written to TOML (layout of ``presets/rrr3_udesc.toml``) with strict validation:
unknown or missing fields, wrong types and impossible values raise :class:`ConfigError`, naming
the file and the field. Frames and conventions: see :mod:`motionbase.platform.rrr3`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from motionbase.config import (
    as_float,
    check_file_kind,
    check_keys,
    read_toml,
    resolve_preset_or_path,
    write_toml,
)
from motionbase.errors import ConfigError
from motionbase.platform import _rrr3_kernels as _k

__all__ = ["Rrr3Geometry"]

_SQRT3 = math.sqrt(3.0)

_TOP_KEYS = ("name", "base_side", "crank", "rod", "platform_side", "modes", "servo", "safety")
_SERVO_KEYS = ("zero_deg", "direction", "min_deg", "max_deg")
_SAFETY_KEYS = ("max_speed", "max_accel", "type1_margin", "type2_margin")


def _triple(source: str, name: str, value: Any, *, kind: type) -> tuple:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ConfigError(f"{source}: field {name!r}: expected a list of 3 values, got {value!r}")
    out = []
    for v in value:
        if kind is int:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise ConfigError(f"{source}: field {name!r}: expected integers, got {v!r}")
            out.append(int(v))
        else:
            out.append(as_float(source, name, v))
    return tuple(out)


@dataclass(frozen=True)
class Rrr3Geometry:
    """Dimensions, servo mapping, working modes and safety limits of a planar 3-RRR robot.

    Parameters
    ----------
    base_side : float
        ``L``, side of the equilateral base triangle of motor axes, m.
    crank : float
        ``a``, crank length ``A_i B_i`` (servo horn), m.
    rod : float
        ``b``, rod length ``B_i C_i``, m.
    platform_side : float
        ``h``, side of the equilateral platform triangle ``C_1 C_2 C_3``, m.
    modes : tuple of 3 int
        Working mode per chain, +1 or -1: the sign of the root in the tangent half-angle
        solution (``theta_i = atan2(yc, xc) + mode_i * delta_i``).
    servo_zero_deg : tuple of 3 float
        Joint angle ``theta_i`` (deg, base frame) at which servo ``i`` reads 0, from -360
        to 360.
    servo_direction : tuple of 3 int
        +1 when servo degrees grow with ``theta_i`` (counter-clockwise), -1 otherwise.
    servo_min_deg, servo_max_deg : tuple of 3 int
        Allowed command range per servo, integer degrees within 0..180.
    max_speed : float
        Joint speed limit, rad/s (Futaba S3003: 0.23 s/60 deg at 4.8 V, about 4.5 rad/s).
    max_accel : float
        Joint acceleration limit, rad/s^2 (a conservative 20 by default).
    type1_margin : float
        Minimum of ``|u_i x n_i| / (a b)`` (sine of the crank-rod angle), dimensionless.
    type2_margin : float
        Minimum of ``|det(Jx)| / (b^3 h / sqrt(3))``, dimensionless.
    name : str
        A label stored with the geometry (the preset's name).
    """

    base_side: float = 0.26
    crank: float = 0.04445
    rod: float = 0.0889
    platform_side: float = 0.08573
    modes: tuple[int, int, int] = (1, -1, -1)
    servo_zero_deg: tuple[float, float, float] = (0.0, 0.0, 135.0)
    servo_direction: tuple[int, int, int] = (1, 1, 1)
    servo_min_deg: tuple[int, int, int] = (0, 0, 0)
    servo_max_deg: tuple[int, int, int] = (180, 180, 180)
    max_speed: float = 4.5
    max_accel: float = 20.0
    type1_margin: float = 0.1
    type2_margin: float = 0.05
    name: str = field(default="custom")

    def __post_init__(self) -> None:
        src = f"rrr3 geometry {self.name!r}"
        for nm in ("base_side", "crank", "rod", "platform_side", "max_speed", "max_accel"):
            object.__setattr__(
                self, nm, as_float(src, nm, getattr(self, nm), min_value=0.0, strict_min=True)
            )
        for nm in ("type1_margin", "type2_margin"):
            v = as_float(src, nm, getattr(self, nm), min_value=0.0)
            if v >= 1.0:
                raise ConfigError(f"{src}: field {nm!r}: must be < 1 (dimensionless), got {v:g}")
            object.__setattr__(self, nm, v)
        modes = _triple(src, "modes", self.modes, kind=int)
        if any(m not in (1, -1) for m in modes):
            raise ConfigError(f"{src}: field 'modes': each mode must be +1 or -1, got {modes}")
        object.__setattr__(self, "modes", modes)
        direction = _triple(src, "servo.direction", self.servo_direction, kind=int)
        if any(d not in (1, -1) for d in direction):
            raise ConfigError(
                f"{src}: field 'servo.direction': each must be +1 or -1, got {direction}"
            )
        object.__setattr__(self, "servo_direction", direction)
        zero = _triple(src, "servo.zero_deg", self.servo_zero_deg, kind=float)
        for i, z in enumerate(zero):
            # (a zero of many turns is the same mapping in exact arithmetic, but the joint
            # angles measured from it lose their precision: 1e300 froze servo 1's command)
            if not -360.0 <= z <= 360.0:
                raise ConfigError(
                    f"{src}: field 'servo.zero_deg': servo {i + 1}'s zero must be from -360 to "
                    f"360 deg, got {z:g} (take whole turns off it)"
                )
        object.__setattr__(self, "servo_zero_deg", zero)
        lo = _triple(src, "servo.min_deg", self.servo_min_deg, kind=int)
        hi = _triple(src, "servo.max_deg", self.servo_max_deg, kind=int)
        for i in range(3):
            if not 0 <= lo[i] < hi[i] <= 180:
                raise ConfigError(
                    f"{src}: servo {i + 1}: need 0 <= min_deg < max_deg <= 180, "
                    f"got {lo[i]}..{hi[i]} (fix servo.min_deg / servo.max_deg)"
                )
        object.__setattr__(self, "servo_min_deg", lo)
        object.__setattr__(self, "servo_max_deg", hi)
        if self.crank + self.rod <= self.platform_side / _SQRT3:
            raise ConfigError(f"{src}: crank + rod too short to reach the platform joints")
        if not isinstance(self.name, str):
            raise ConfigError(f"{src}: field 'name': expected a string")

    # -- presets and files --------------------------------------------------------------
    @classmethod
    def preset(cls, name: str = "udesc") -> Rrr3Geometry:
        """A shipped preset (``udesc``: the thesis's robot) or a path to a TOML file."""
        return cls.from_toml(resolve_preset_or_path("rrr3", name))

    @classmethod
    def from_toml(cls, path: str | Path) -> Rrr3Geometry:
        """Read a geometry from TOML (layout of ``presets/rrr3_udesc.toml``)."""
        return cls.from_dict(read_toml(path), source=str(path))

    def to_toml(self, path: str | Path) -> None:
        """Write the geometry to TOML; :meth:`from_toml` reads it back equal."""
        write_toml(path, self.to_dict())

    def to_dict(self) -> dict[str, Any]:
        """Plain nested data (TOML/JSON friendly); :meth:`from_dict` inverts it exactly."""
        d = asdict(self)
        return {
            "name": d["name"],
            "base_side": d["base_side"],
            "crank": d["crank"],
            "rod": d["rod"],
            "platform_side": d["platform_side"],
            "modes": list(d["modes"]),
            "servo": {
                "zero_deg": list(d["servo_zero_deg"]),
                "direction": list(d["servo_direction"]),
                "min_deg": list(d["servo_min_deg"]),
                "max_deg": list(d["servo_max_deg"]),
            },
            "safety": {
                "max_speed": d["max_speed"],
                "max_accel": d["max_accel"],
                "type1_margin": d["type1_margin"],
                "type2_margin": d["type2_margin"],
            },
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "rrr3 geometry") -> Rrr3Geometry:
        """Build from :meth:`to_dict`'s layout; unknown or missing fields are ConfigErrors."""
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected a table, got {type(data).__name__}")
        check_file_kind(source, data, "rrr3")
        check_keys(source, data, _TOP_KEYS, required=_TOP_KEYS[1:])
        servo, safety = data["servo"], data["safety"]
        if not isinstance(servo, dict) or not isinstance(safety, dict):
            raise ConfigError(f"{source}: 'servo' and 'safety' must be tables")
        check_keys(f"{source} [servo]", servo, _SERVO_KEYS, required=_SERVO_KEYS)
        check_keys(f"{source} [safety]", safety, _SAFETY_KEYS, required=_SAFETY_KEYS)
        try:
            geometry = cls._from_tables(data, servo, safety)
            from motionbase.platform.rrr3 import Rrr3  # (it imports this module)

            Rrr3(geometry)  # a home pose it cannot take, said here, where the file is known
            return geometry
        except ConfigError as exc:  # name the file rather than the geometry's inner name
            msg, prefix = str(exc), f"rrr3 geometry {data.get('name', 'custom')!r}"
            if source != "rrr3 geometry" and msg.startswith(prefix):
                raise ConfigError(source + msg[len(prefix) :]) from None
            raise

    @classmethod
    def _from_tables(cls, data: dict, servo: dict, safety: dict) -> Rrr3Geometry:
        return cls(
            name=data.get("name", "custom"),
            base_side=data["base_side"],
            crank=data["crank"],
            rod=data["rod"],
            platform_side=data["platform_side"],
            modes=data["modes"],
            servo_zero_deg=servo["zero_deg"],
            servo_direction=servo["direction"],
            servo_min_deg=servo["min_deg"],
            servo_max_deg=servo["max_deg"],
            max_speed=safety["max_speed"],
            max_accel=safety["max_accel"],
            type1_margin=safety["type1_margin"],
            type2_margin=safety["type2_margin"],
        )

    # -- derived quantities ---------------------------------------------------------------
    @property
    def base_points(self) -> np.ndarray:
        """Motor axes ``A_i`` in the base frame, shape (3, 2), m."""
        L = self.base_side
        return np.array([[0.0, 0.0], [L, 0.0], [L / 2, L * _SQRT3 / 2]])

    @property
    def platform_points(self) -> np.ndarray:
        """Platform joints ``C_i`` in the platform frame (origin at the centroid), (3, 2), m."""
        h = self.platform_side
        return np.array(
            [[-h / 2, -h / (2 * _SQRT3)], [h / 2, -h / (2 * _SQRT3)], [0.0, h / _SQRT3]]
        )

    @property
    def home(self) -> np.ndarray:
        """Home pose ``[L/2, L sqrt(3)/6, 0]``: the base triangle's centre, zero orientation."""
        L = self.base_side
        return np.array([L / 2, L * _SQRT3 / 6, 0.0])

    def packed(self) -> np.ndarray:
        """Parameters packed for the compiled kernels (internal layout of ``_rrr3_kernels``)."""
        return _k.pack_geometry(
            self.base_points,
            self.platform_points,
            self.crank,
            self.rod,
            self.modes,
            self.servo_zero_deg,
            self.servo_direction,
            self.servo_min_deg,
            self.servo_max_deg,
            self.type1_margin,
            self.type2_margin,
            self.platform_side / _SQRT3,
        )
