"""Geometry of a 6-UPS Stewart platform with linear actuators (the common hexapod).

Frames and conventions (DESIGN.md):

* Base axes are FRD (x forward, y right, z down). The base origin is the centre of the base
  joint circle, in the base joint plane; the platform joints sit ``neutral_height`` above it at
  the neutral pose, i.e. at ``z = -neutral_height``. The platform frame's origin is the
  centroid of the platform joints (the centre of their circle).
* Angles in the horizontal plane are measured from +x (forward) toward +y (right).
* The layout is the common one: six joints in three pairs on each circle. The base pairs are
  centred at 0, 120 and 240 deg (one pair at the front, two at the rear corners); the platform
  pairs at 60, 180 and 300 deg (two at the front corners, one at the rear), so each leg runs
  from a base pair to the nearer joint of the neighbouring platform pair. Leg ``k`` (0-based,
  ``c = 120 deg * (k // 2)``, ``s = -1`` for even ``k``, ``+1`` for odd ``k``) joins

  - the base joint at angle ``c + s * base_half_angle`` on the ``base_radius`` circle and
  - the platform joint at angle ``c + s * (60 deg - platform_half_angle)`` on the
    ``platform_radius`` circle.

  The layout is mirror-symmetric about the x-z plane (left to right) and has three-fold
  symmetry about z.

  ::

      seen from above: x forward up the page, y right; base joints *, platform joints o

                    B1 *   * B2
            P1 o                 o P2
         P6 o                       o P3
       B6 *                           * B3
          B5 *      o     o      * B4
                   P5     P4

  Leg ``i`` joins ``Bi`` and ``Pi`` (1-based, as in the drawing).

* An actuator value is a *length*: the distance between the leg's two joint centres, m
  (retracted length plus extension), not the extension alone. Speeds are m/s, accelerations
  m/s^2.

Everything is stored in SI units (m, rad, m/s, m/s^2) as floats and tuples of floats, so the
dataclass is hashable and ``from_dict(g.to_dict()) == g`` exactly.

TOML (see ``presets/stewart6_seat.toml``)::

    kind = "stewart6"
    base_radius = 0.50               # m
    base_half_angle_deg = 12.0       # or base_half_angle (rad)
    platform_radius = 0.35           # m
    platform_half_angle_deg = 12.0   # or platform_half_angle (rad)
    neutral_length = 0.75            # m, or neutral_height (m); one of the two
    length_min = 0.60                # m joint to joint, one number or 6
    length_max = 0.90                # m
    max_speed = 0.3                  # m/s, one number or 6 (required)
    max_accel = 3.0                  # m/s^2, one number or 6 (required)
    park_margin = 0.01               # m above length_min when parked (optional)
    [output]                         # optional: lengths -> drive values
    unit = "range"
    range_lo = 0
    range_hi = 4095

Types are checked strictly: a bool or a string is not a number, per-leg lists must hold
exactly six numbers, and the actuator limits (``length_min``, ``length_max``, ``max_speed``,
``max_accel``) are never defaulted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from motionbase.config import (
    as_float,
    check_file_kind,
    check_keys,
    read_toml,
    resolve_preset_or_path,
    to_float,
    write_toml,
)
from motionbase.errors import ConfigError
from motionbase.platform.conditioning import MIN_LINE_CONDITIONING, line_conditioning
from motionbase.platform.output_map import OutputMapping

__all__ = ["Stewart6Geometry", "N_LEGS", "DEFAULT_PARK_MARGIN"]

N_LEGS = 6
#: Default park position: this far above each actuator's minimum length, m.
DEFAULT_PARK_MARGIN = 0.01

_PAIR_CENTRES = np.radians([0.0, 0.0, 120.0, 120.0, 240.0, 240.0])
_PAIR_SIDE = np.array([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0])
_SIXTY = math.pi / 3.0

_LENGTH_SCALARS = ("base_radius", "platform_radius", "neutral_height")
_ANGLE_SCALARS = ("base_half_angle", "platform_half_angle")
_PER_LEG = {"length_min": "m", "length_max": "m", "max_speed": "m/s", "max_accel": "m/s^2"}
_OUTPUT_KEYS = ("unit", "sign", "range_lo", "range_hi", "span_min", "span_max")
_OUTPUT_KEYS += ("drive_min", "drive_max")


def _is_number(v: Any) -> bool:
    """A real number: int or float (numpy's too), not a bool, not a string."""
    return not isinstance(v, (bool, np.bool_)) and isinstance(
        v, (int, float, np.integer, np.floating)
    )


def _per_leg(source: str, name: str, value: Any, unit: str) -> tuple[float, ...]:
    """One number for every leg or a list of exactly six; strictly numbers, finite, > 0."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if _is_number(value):
        items = [value] * N_LEGS
    elif isinstance(value, (list, tuple)):
        if len(value) != N_LEGS:
            raise ConfigError(
                f"{source}: field {name!r}: expected one number or a list of {N_LEGS}, got a "
                f"list of {len(value)} (fix the list length)"
            )
        items = list(value)
    else:
        raise ConfigError(
            f"{source}: field {name!r}: expected a number or a list of {N_LEGS} numbers "
            f"({unit}), got {value!r}"
        )
    out = []
    for i, v in enumerate(items):
        if not _is_number(v):
            raise ConfigError(
                f"{source}: field {name!r}: leg {i + 1}: expected a number ({unit}), got {v!r}"
            )
        f = to_float(v)
        if not math.isfinite(f) or f <= 0.0:
            raise ConfigError(
                f"{source}: field {name!r}: leg {i + 1} must be a finite number > 0 {unit}, "
                f"got {f:g} (fix the value)"
            )
        out.append(f)
    return tuple(out)


def _half_angle(source: str, name: str, value: Any, *, degrees: bool = False) -> float:
    """A pair's half-separation angle, rad: a number strictly between 0 and 60 deg."""
    v = as_float(source, name, value)
    rad = math.radians(v) if degrees else v
    if not 0.0 < rad < _SIXTY:
        raise ConfigError(
            f"{source}: field {name!r}: must lie between 0 and 60 deg (exclusive), got "
            f"{math.degrees(rad):g} deg (fix the value)"
        )
    return rad


def _leg_layout(base_radius, base_half_angle, platform_radius, platform_half_angle):
    """Base joints (6, 3) in base axes and platform joints (6, 2) in the platform plane."""
    b = _PAIR_CENTRES + _PAIR_SIDE * base_half_angle
    p = _PAIR_CENTRES + _PAIR_SIDE * (_SIXTY - platform_half_angle)
    base = np.stack([base_radius * np.cos(b), base_radius * np.sin(b), np.zeros(N_LEGS)], -1)
    plat = np.stack([platform_radius * np.cos(p), platform_radius * np.sin(p)], -1)
    return base, plat


@dataclass(frozen=True)
class Stewart6Geometry:
    """Dimensions and actuator limits of a 6-UPS Stewart platform (SI units).

    Parameters
    ----------
    base_radius : float
        Radius of the base joint circle, m.
    base_half_angle : float
        Half the angle between the two joints of a base pair, seen from the base centre, rad
        (0 < angle < 60 deg).
    platform_radius : float
        Radius of the platform joint circle, m.
    platform_half_angle : float
        Half the angle between the two joints of a platform pair, rad (0 < angle < 60 deg).
    neutral_height : float
        Height of the platform joint plane above the base joint plane at the neutral pose, m.
    length_min, length_max : tuple of 6 float
        Actuator length limits, joint centre to joint centre, m (retracted and extended).
    max_speed : tuple of 6 float
        Actuator speed limit, m/s.
    max_accel : tuple of 6 float
        Actuator acceleration limit, m/s^2.
    park_margin : float
        The parked actuators stand this far above ``length_min``, m (> 0, default 0.01).
    name : str
        A label (the preset name or the file it came from).
    output : OutputMapping or None
        How actuator lengths become drive values (the TOML ``[output]`` table); None when the
        file has none. Only ``unit = "range"`` applies to lengths (see :meth:`from_dict`).
    """

    base_radius: float
    base_half_angle: float
    platform_radius: float
    platform_half_angle: float
    neutral_height: float
    length_min: tuple[float, ...]
    length_max: tuple[float, ...]
    max_speed: tuple[float, ...]
    max_accel: tuple[float, ...]
    park_margin: float = DEFAULT_PARK_MARGIN
    name: str = "custom"
    output: OutputMapping | None = None

    # ------------------------------------------------------------------ construction
    def __post_init__(self) -> None:
        src = f"stewart6 geometry {self.name!r}"
        if not isinstance(self.name, str):
            raise ConfigError(f"{src}: field 'name': expected a string, got {self.name!r}")
        for f in _LENGTH_SCALARS:
            v = as_float(src, f, getattr(self, f), min_value=0.0, strict_min=True, unit="m")
            object.__setattr__(self, f, v)
        for f in _ANGLE_SCALARS:
            object.__setattr__(self, f, _half_angle(src, f, getattr(self, f)))
        for f, unit in _PER_LEG.items():
            object.__setattr__(self, f, _per_leg(src, f, getattr(self, f), unit))
        lo, hi = np.array(self.length_min), np.array(self.length_max)
        for i in range(N_LEGS):
            if not lo[i] < hi[i]:
                raise ConfigError(
                    f"{src}: fields 'length_min'/'length_max': leg {i + 1} needs min < max, got "
                    f"{lo[i]:g} .. {hi[i]:g} m (swap or fix the limits)"
                )
        with np.errstate(over="ignore", invalid="ignore"):  # (radii of 1e300: said below)
            neutral = self.neutral_lengths
        for i in range(N_LEGS):
            if not lo[i] < neutral[i] < hi[i]:
                raise ConfigError(
                    f"{src}: field 'neutral_height': leg {i + 1} is {neutral[i]:.4f} m long at "
                    f"the neutral pose, not inside its stroke {lo[i]:g} .. {hi[i]:g} m (fix "
                    "neutral_height, neutral_length or the length limits)"
                )
        length = self.line_scale
        c = line_conditioning(self.platform_joints_local, self._neutral_lines(), length)
        if c < MIN_LINE_CONDITIONING:
            side = "platform" if self.platform_radius <= self.base_radius else "base"
            radius = getattr(self, f"{side}_radius")
            # Either the lines meet near one point (the joints of the smaller circle), or they
            # run nearly parallel: each platform joint (nearly) straight above its base joint
            # (the same sideways offset on every leg of this layout).
            offset = float(np.hypot(*self._neutral_lines()[0, :2]))
            if offset < radius:
                raise ConfigError(
                    f"{src}: fields 'base_radius'/'platform_radius' and the half angles: the "
                    f"actuators barely hold the platform at the neutral pose (line conditioning "
                    f"{c:.2g} < {MIN_LINE_CONDITIONING:g}): they stand nearly parallel, each "
                    f"platform joint {offset:.3g} m sideways of its base joint on a {length:g} m "
                    "actuator, and hardly resist the platform's sideways motion or yaw (offset "
                    "the joints: radii or half angles that differ more)"
                )
            raise ConfigError(
                f"{src}: field '{side}_radius': the actuators barely hold the platform's "
                f"rotations at the neutral pose (line conditioning {c:.2g} < "
                f"{MIN_LINE_CONDITIONING:g}, moments over the actuator length {length:g} m): "
                f"the {side} joints (radius {radius:g} m) are too close to one point (spread "
                f"them: a larger {side}_radius)"
            )
        margin = as_float(src, "park_margin", self.park_margin, min_value=0.0, strict_min=True)
        object.__setattr__(self, "park_margin", margin)
        for i in range(N_LEGS):
            if not lo[i] + margin < neutral[i]:
                raise ConfigError(
                    f"{src}: field 'park_margin': leg {i + 1} would park at "
                    f"{lo[i] + margin:.4f} m, not below its neutral length {neutral[i]:.4f} m "
                    "(choose a smaller margin)"
                )
        if self.output is not None:
            if not isinstance(self.output, OutputMapping):
                raise ConfigError(
                    f"{src}: field 'output': expected an OutputMapping, got {self.output!r}"
                )
            if self.output.n != N_LEGS or self.output.unit != "range":
                raise ConfigError(
                    f"{src}: table 'output': expected unit 'range' for {N_LEGS} actuators, got "
                    f"unit {self.output.unit!r} for {self.output.n}"
                )

    # ------------------------------------------------------------------ derived geometry
    def _layout(self) -> tuple[np.ndarray, np.ndarray]:
        return _leg_layout(
            self.base_radius, self.base_half_angle, self.platform_radius, self.platform_half_angle
        )

    def _neutral_lines(self) -> np.ndarray:
        """Each actuator's vector, base joint to platform joint, at the neutral pose, m."""
        return self.platform_origin + self.platform_joints_local - self.base_joints

    @property
    def base_joints(self) -> np.ndarray:
        """Base joint centres ``B_i`` in base axes, m, shape (6, 3) (all at z = 0)."""
        return self._layout()[0]

    @property
    def platform_origin(self) -> np.ndarray:
        """Neutral position of the platform frame origin (the joints' centroid), m, shape (3,)."""
        _, plat = self._layout()
        joints = np.concatenate([plat, np.full((N_LEGS, 1), -self.neutral_height)], axis=1)
        return joints.mean(axis=0)

    @property
    def platform_joints_local(self) -> np.ndarray:
        """Platform joint centres ``q_i`` in the platform frame (origin at their centroid), m,
        shape (6, 3)."""
        _, plat = self._layout()
        joints = np.concatenate([plat, np.full((N_LEGS, 1), -self.neutral_height)], axis=1)
        return joints - joints.mean(axis=0)

    @property
    def neutral_lengths(self) -> np.ndarray:
        """Actuator lengths at the neutral pose, m, shape (6,): ``|O + q_i - B_i|``."""
        return np.linalg.norm(
            self.platform_origin + self.platform_joints_local - self.base_joints, axis=1
        )

    @property
    def line_scale(self) -> float:
        """The length, m, that turns the legs' moments into forces in their line conditioning
        (:mod:`motionbase.platform.conditioning`): the mean actuator length at neutral."""
        return float(np.mean(self.neutral_lengths))

    @property
    def park_lengths(self) -> np.ndarray:
        """Actuator lengths of the parked platform, ``length_min + park_margin``, m, (6,)."""
        return np.array(self.length_min) + self.park_margin

    @staticmethod
    def neutral_height_for_length(
        *,
        base_radius: float,
        base_half_angle: float,
        platform_radius: float,
        platform_half_angle: float,
        length: float,
    ) -> float:
        """The neutral height (m) at which every leg is ``length`` (m) long; NaN if too short.

        The layout is symmetric, so every leg has the same horizontal reach ``d`` and the
        height is ``sqrt(length^2 - d^2)``.
        """
        base, plat = _leg_layout(base_radius, base_half_angle, platform_radius, platform_half_angle)
        d = math.hypot(*(plat[0] - base[0, :2]))  # (no overflow warning for radii of 1e300)
        h2 = length * length - d * d
        return math.sqrt(h2) if h2 > 0.0 else math.nan

    # ------------------------------------------------------------------ (de)serialisation
    def to_dict(self) -> dict[str, Any]:
        """Plain SI data (floats and lists; no degrees); ``from_dict`` rebuilds it exactly."""
        out: dict[str, Any] = {"name": self.name}
        for f in fields(self):
            if f.name in ("name", "output"):
                continue
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        if self.output is not None:
            out["output"] = _output_table(self.output)
        return out

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], source: str = "stewart6 geometry"
    ) -> Stewart6Geometry:
        """Build from plain data, e.g. a parsed TOML file.

        Accepted keys: ``base_radius``, ``platform_radius`` (m); ``base_half_angle``,
        ``platform_half_angle`` (rad) or the same with ``_deg``; ``neutral_height`` (m) or
        ``neutral_length`` (m, every leg's length at neutral: the height follows);
        ``length_min``, ``length_max`` (m, joint to joint), ``max_speed`` (m/s),
        ``max_accel`` (m/s^2), each one number or a list of 6, all four required;
        ``park_margin`` (m, optional, default 0.01); ``name``; ``kind`` (``"stewart6"`` if
        present); ``output``, a table mapping lengths to drive values: ``unit = "range"``
        (the only unit for lengths), ``range_lo``/``range_hi`` (integers), optional ``sign``
        (1, or -1 for a drive that counts from the extended end), ``span_min``/``span_max``
        (the lengths, m, at ``range_lo``/``range_hi``; default the stroke) and
        ``drive_min``/``drive_max`` (drive units, within ``range_lo``..``range_hi``;
        default the stroke's image there).

        Raises
        ------
        ConfigError
            One line naming ``source``, the field and the fix.
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: expected a table of geometry fields, got {data!r}")
        kind = data.get("kind", "stewart6")
        if kind != "stewart6":
            raise ConfigError(
                f"{source}: field 'kind': this is a {kind!r} file, not a 'stewart6' geometry "
                "(give a stewart6 geometry file)"
            )
        check_file_kind(source, data, "stewart6")
        allowed = {"name", "kind", "output", "neutral_length", "park_margin"}
        allowed |= set(_LENGTH_SCALARS) | set(_PER_LEG)
        allowed |= set(_ANGLE_SCALARS) | {f + "_deg" for f in _ANGLE_SCALARS}
        check_keys(source, data, allowed)
        name = data.get("name", Path(source).stem if source.endswith(".toml") else "custom")
        if not isinstance(name, str):
            raise ConfigError(f"{source}: field 'name': expected a string, got {name!r}")
        kw: dict[str, Any] = {"name": name}
        for f in ("base_radius", "platform_radius"):
            if f not in data:
                raise ConfigError(f"{source}: missing field {f!r} (add it, in m)")
            kw[f] = as_float(source, f, data[f], min_value=0.0, strict_min=True, unit="m")
        for f in _ANGLE_SCALARS:
            if f in data and f + "_deg" in data:
                raise ConfigError(f"{source}: give either {f!r} or {f + '_deg'!r}, not both")
            if f + "_deg" in data:
                kw[f] = _half_angle(source, f + "_deg", data[f + "_deg"], degrees=True)
            elif f in data:
                kw[f] = _half_angle(source, f, data[f])
            else:
                raise ConfigError(f"{source}: missing field {f + '_deg'!r} (add it, in degrees)")
        for f, unit in _PER_LEG.items():
            if f not in data:
                raise ConfigError(
                    f"{source}: missing field {f!r} (add it, in {unit}: actuator limits are "
                    "never defaulted)"
                )
            kw[f] = _per_leg(source, f, data[f], unit)
        if "park_margin" in data:
            kw["park_margin"] = data["park_margin"]
        if "neutral_length" in data:
            if "neutral_height" in data:
                raise ConfigError(
                    f"{source}: give either 'neutral_height' or 'neutral_length', not both"
                )
            length = as_float(
                source, "neutral_length", data["neutral_length"], min_value=0.0, strict_min=True
            )
            h = cls.neutral_height_for_length(
                base_radius=kw["base_radius"],
                base_half_angle=kw["base_half_angle"],
                platform_radius=kw["platform_radius"],
                platform_half_angle=kw["platform_half_angle"],
                length=length,
            )
            if not h > 0.0:
                raise ConfigError(
                    f"{source}: field 'neutral_length': {length:g} m cannot span the "
                    "horizontal distance between a base joint and its platform joint "
                    "(give a longer length or other radii)"
                )
            if h == math.inf:  # (its square overflows: it was blamed on neutral_height)
                raise ConfigError(
                    f"{source}: field 'neutral_length': {length:g} m is past any actuator's "
                    "length (fix the value)"
                )
            kw["neutral_height"] = h
        elif "neutral_height" in data:
            kw["neutral_height"] = data["neutral_height"]
        else:
            raise ConfigError(
                f"{source}: missing field 'neutral_height' (add it in m, or give 'neutral_length')"
            )
        if "output" in data:
            kw["output"] = _output_from_table(
                data["output"], kw["length_min"], kw["length_max"], f"{source}: [output]"
            )
        try:
            return cls(**kw)
        except ConfigError as exc:
            msg = str(exc).replace(f"stewart6 geometry {name!r}", source, 1)
            raise ConfigError(msg) from None

    @classmethod
    def from_toml(cls, path: str | Path) -> Stewart6Geometry:
        """Load from a TOML file (fields as in :meth:`from_dict`)."""
        p = Path(path)
        return cls.from_dict(read_toml(p), source=str(p))

    @classmethod
    def preset(cls, name: str) -> Stewart6Geometry:
        """A shipped preset (``"seat"``: ``presets/stewart6_seat.toml``) or a path to a TOML
        file."""
        p = resolve_preset_or_path("stewart6", name)
        return cls.from_dict(read_toml(p), source=p.name if p.parent.name == "presets" else str(p))

    def to_toml(self, path: str | Path) -> None:
        """Save to TOML in SI units; :meth:`from_toml` reloads it bit for bit."""
        write_toml(path, {"kind": "stewart6", **self.to_dict()})


# --------------------------------------------------------------------------- [output]


def _output_from_table(
    table: Any, length_min: tuple[float, ...], length_max: tuple[float, ...], source: str
) -> OutputMapping:
    """The ``[output]`` table (lengths, m) as an :class:`OutputMapping` of unit ``range``.

    The mapping's "motor angle" is ``sign * length`` (gear ratio 1, no offset), so its span is
    the lengths' image under the sign; the table speaks in lengths only.
    """
    if not isinstance(table, Mapping):
        raise ConfigError(f"{source}: expected a table of output fields, got {table!r}")
    known = set(_OUTPUT_KEYS)
    for key in table:
        if key not in known:
            why = (
                "only unit 'range' applies to linear actuators"
                if key in ("zero_offset", "zero_offset_deg", "gear_ratio", "counts_per_rev")
                or key.endswith("_deg")
                else "remove it or fix its spelling"
            )
            raise ConfigError(
                f"{source}: unknown field {key!r}: {why} (known fields: {', '.join(sorted(known))})"
            )
    if "unit" not in table:
        raise ConfigError(f"{source}: missing field 'unit' (add unit = \"range\")")
    if table["unit"] != "range":
        raise ConfigError(
            f"{source}: field 'unit': linear actuators take unit 'range' (an integer range "
            f"across the stroke), got {table['unit']!r}"
        )
    for f in ("range_lo", "range_hi"):
        if f not in table:
            raise ConfigError(f"{source}: missing field {f!r} (add it, an integer)")
        if isinstance(table[f], bool) or not isinstance(table[f], int):
            raise ConfigError(f"{source}: field {f!r}: expected an integer, got {table[f]!r}")
    sign = np.ones(N_LEGS)
    if "sign" in table:
        s = table["sign"]
        items = [s] * N_LEGS if not isinstance(s, (list, tuple)) else list(s)
        if len(items) != N_LEGS or not all(_is_number(v) and v in (1, -1) for v in items):
            raise ConfigError(
                f"{source}: field 'sign': expected 1 or -1, or a list of {N_LEGS} of them, "
                f"got {s!r}"
            )
        sign = np.array(items, dtype=float)
    lo, hi = np.array(length_min), np.array(length_max)
    span = {"span_min": lo, "span_max": hi}  # lengths at range_lo / range_hi
    for f in span:
        if f in table:
            span[f] = np.array(_per_leg(source, f, table[f], "m"))
    span_lo, span_hi = span["span_min"], span["span_max"]
    data: dict[str, Any] = {
        "unit": "range",
        "sign": sign.tolist(),
        "range_lo": table["range_lo"],
        "range_hi": table["range_hi"],
        # the mapping's motor "angle" is sign * length: its span is the image, in order
        "span_min": np.minimum(sign * span_lo, sign * span_hi).tolist(),
        "span_max": np.maximum(sign * span_lo, sign * span_hi).tolist(),
    }
    for f in ("drive_min", "drive_max"):
        if f in table:
            v = table[f]
            items = [v] * N_LEGS if not isinstance(v, (list, tuple)) else list(v)
            if len(items) != N_LEGS or not all(
                _is_number(x) and math.isfinite(to_float(x)) for x in items
            ):
                raise ConfigError(
                    f"{source}: field {f!r}: expected a number or a list of {N_LEGS} numbers "
                    f"(drive units), got {v!r}"
                )
            data[f] = [float(x) for x in items]
    for i in range(N_LEGS):
        if not span_lo[i] < span_hi[i]:
            raise ConfigError(
                f"{source}: fields 'span_min'/'span_max': actuator {i + 1} needs min < max, "
                f"got {span_lo[i]:g} .. {span_hi[i]:g} m (use sign = -1 to reverse a drive)"
            )
    return OutputMapping.from_dict(data, angle_min=lo, angle_max=hi, source=source)


def _output_table(mapping: OutputMapping) -> dict[str, Any]:
    """The ``[output]`` table (lengths, m) of a mapping built by :func:`_output_from_table`."""
    sign = np.array(mapping.sign)
    a, b = sign * np.array(mapping.span_min), sign * np.array(mapping.span_max)
    return {
        "unit": "range",
        "sign": [int(s) for s in mapping.sign],
        "range_lo": mapping.range_lo,
        "range_hi": mapping.range_hi,
        "span_min": np.minimum(a, b).tolist(),
        "span_max": np.maximum(a, b).tolist(),
        "drive_min": list(mapping.drive_min),
        "drive_max": list(mapping.drive_max),
    }
