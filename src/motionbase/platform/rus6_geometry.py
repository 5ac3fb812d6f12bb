"""Geometry of a 6-RUS rotary parallel platform, in the thesis's parameters (ch. 8).

Frames and conventions (see DESIGN.md):

* Base axes are FRD (x forward, y right, z down). The base origin is the centre of the crank
  pivot plane; the platform joints sit ``neutral_height`` above it at the neutral pose, i.e. at
  ``z = -neutral_height``.
* Leg ``i`` (0-based ``k = i - 1``) has its crank pivot at (thesis eqs. 8.1-8.5)
  ``A = rb (cos chi_a, sin chi_a, 0) + m (-sin chi_a, cos chi_a, 0)`` with ``m = (-1)^(i-1) d``
  and its platform joint (eqs. 8.6-8.10) at ``C = rp (cos chi_j, sin chi_j) + n (-sin chi_j,
  cos chi_j)`` with ``n = (-1)^(i-1) e``. Angles are in the horizontal plane, from +x toward +y.
* ``beta`` is the direction of the crank at crank angle 0 (crank horizontal), measured from +x
  toward +y; it is also the angle between the motor axis and the y axis (the thesis's beta).
* A crank angle is 0 with the crank horizontal and grows as the crank tip rises toward the
  platform: ``tip = A + r (cos(theta) c + sin(theta) up)`` with ``c = (cos beta, sin beta, 0)``
  and ``up = (0, 0, -1)``.

Everything is stored in SI units (m, rad, rad/s, rad/s^2) as tuples of floats, so the dataclass
is hashable and ``from_dict(g.to_dict()) == g`` exactly.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np

from motionbase.config import (
    as_array,
    as_float,
    check_file_kind,
    check_keys,
    read_toml,
    resolve_preset_or_path,
    write_toml,
)
from motionbase.errors import ConfigError
from motionbase.platform.conditioning import MIN_LINE_CONDITIONING, line_conditioning
from motionbase.platform.output_map import OutputMapping

__all__ = ["Rus6Geometry", "N_LEGS"]

N_LEGS = 6
_SIGNS = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])  # (-1)^(i-1), i = 1..6
_PARK_MARGIN = math.radians(5.0)

# Per-leg array fields that may be given in degrees in TOML as ``<name>_deg``.
_ANGLE_ARRAYS = ("chi_a", "chi_j", "beta", "angle_min", "angle_max")
_LENGTH_ARRAYS = ("crank", "rod")
_SCALARS = ("rb", "rp", "d", "e", "neutral_height")
_RATE_ARRAYS = {"max_speed": "deg_s", "max_accel": "deg_s2"}


def _leg_arrays(rb, d, chi_a, rp, e, chi_j, beta):
    ca, sa = np.cos(chi_a), np.sin(chi_a)
    m = _SIGNS * d
    pivots = np.stack([rb * ca - m * sa, rb * sa + m * ca, np.zeros(N_LEGS)], axis=-1)
    cj, sj = np.cos(chi_j), np.sin(chi_j)
    n = _SIGNS * e
    joints_xy = np.stack([rp * cj - n * sj, rp * sj + n * cj], axis=-1)
    cdir = np.stack([np.cos(beta), np.sin(beta), np.zeros(N_LEGS)], axis=-1)
    return pivots, joints_xy, cdir


@dataclass(frozen=True)
class Rus6Geometry:
    """Dimensions and actuator limits of a 6-RUS rotary platform (SI units).

    Parameters
    ----------
    rb : float
        Base radius: distance from the base centre to the centre of each crank pivot pair, m.
    d : float
        Half spacing of a crank pivot pair, m (thesis eq. 8.3).
    rp : float
        Platform radius: distance from the platform centre to each joint pair's centre, m.
    e : float
        Half spacing of a platform joint pair, m (thesis eq. 8.8).
    chi_a : tuple of 6 float
        Angle of each leg's pivot pair centre in the base xy plane, rad (legs of a pair repeat it).
    chi_j : tuple of 6 float
        Angle of each leg's platform joint pair centre, rad.
    beta : tuple of 6 float
        Crank direction at crank angle 0 (horizontal), rad from +x toward +y.
    crank : tuple of 6 float
        Crank length r_i (pivot to crank tip), m.
    rod : tuple of 6 float
        Rod length R_i (crank tip to platform joint), m.
    neutral_height : float
        Height of the platform joint plane above the crank pivot plane at the neutral pose, m.
    angle_min, angle_max : tuple of 6 float
        Crank angle limits, rad.
    max_speed : tuple of 6 float
        Crank speed limit, rad/s (required: a limit that moves motors is never guessed).
    max_accel : tuple of 6 float
        Crank acceleration limit, rad/s^2 (required).
    park_angle : float
        Crank angle of the parked platform (every crank), rad. Default: the lowest pure-heave
        pose within the crank limits with a 5-degree margin, ``max(angle_min) + 5 deg``. It
        must give a pure-heave pose within every leg's limits.
    name : str
        A label (the preset name or the file it came from).
    output : OutputMapping or None
        How crank angles become motor-drive values (the TOML ``[output]`` table): mirrored
        motors, zero offsets, gear ratios, drive units. None when the file has none.
    """

    rb: float
    d: float
    rp: float
    e: float
    chi_a: tuple[float, ...]
    chi_j: tuple[float, ...]
    beta: tuple[float, ...]
    crank: tuple[float, ...]
    rod: tuple[float, ...]
    neutral_height: float
    angle_min: tuple[float, ...]
    angle_max: tuple[float, ...]
    max_speed: tuple[float, ...]
    max_accel: tuple[float, ...]
    park_angle: float | None = None
    name: str = "custom"
    output: OutputMapping | None = None

    # ------------------------------------------------------------------ construction
    def __post_init__(self) -> None:
        src = f"rus6 geometry {self.name!r}"
        for f in _SCALARS:
            strict = f not in ("d", "e")
            v = as_float(src, f, getattr(self, f), min_value=0.0, strict_min=strict, unit="m")
            object.__setattr__(self, f, v)
        arrays = _ANGLE_ARRAYS + _LENGTH_ARRAYS + tuple(_RATE_ARRAYS)
        for f in arrays:
            arr = as_array(src, f, getattr(self, f), N_LEGS)
            object.__setattr__(self, f, tuple(float(x) for x in arr))
        for f in _LENGTH_ARRAYS:
            for i, v in enumerate(getattr(self, f)):
                if v <= 0:
                    raise ConfigError(
                        f"{src}: field {f!r}: leg {i + 1} must be > 0 m, got {v:g} (fix the value)"
                    )
        for f, unit in (("max_speed", "rad/s"), ("max_accel", "rad/s^2")):
            for i, v in enumerate(getattr(self, f)):
                if v <= 0:
                    raise ConfigError(
                        f"{src}: field {f!r}: leg {i + 1} must be > 0 {unit}, got {v:g} "
                        "(fix the value)"
                    )
        lo, hi = np.array(self.angle_min), np.array(self.angle_max)
        for i in range(N_LEGS):
            if not (-math.pi < lo[i] < hi[i] < math.pi):
                raise ConfigError(
                    f"{src}: fields 'angle_min'/'angle_max': leg {i + 1} needs "
                    f"-180 < min < max < 180 deg, got {math.degrees(lo[i]):g} .. "
                    f"{math.degrees(hi[i]):g} deg (fix the limits)"
                )
        self._check_rods(src)
        neutral = self.neutral_angle
        for i in range(N_LEGS):
            if not lo[i] <= neutral[i] <= hi[i]:
                raise ConfigError(
                    f"{src}: field 'neutral_height': leg {i + 1} crank angle at neutral is "
                    f"{math.degrees(neutral[i]):.2f} deg, outside its limits "
                    f"{math.degrees(lo[i]):g} .. {math.degrees(hi[i]):g} deg "
                    "(fix neutral_height or the limits)"
                )
        self._check_lines(src, neutral)
        if self.park_angle is None:
            object.__setattr__(self, "park_angle", float(np.max(lo)) + _PARK_MARGIN)
        else:
            object.__setattr__(self, "park_angle", as_float(src, "park_angle", self.park_angle))
        self._check_park(src)
        if self.output is not None:
            if not isinstance(self.output, OutputMapping):
                raise ConfigError(
                    f"{src}: field 'output': expected an OutputMapping, got {self.output!r}"
                )
            if self.output.n != N_LEGS:
                raise ConfigError(f"{src}: table 'output': expected 6 motors, got {self.output.n}")
            if self.output.unit in ("mm", "m"):
                raise ConfigError(
                    f"{src}: table 'output': field 'unit': {self.output.unit!r} is for linear "
                    "actuators, and a crank turns (use deg, rad, counts or range)"
                )

    def _check_rods(self, src: str) -> None:
        """Each rod must bridge the gap between its crank tip circle and its neutral joint."""
        pivots, joints, _, cdir = self._neutral_points()
        r = np.array(self.crank)
        for i in range(N_LEGS):
            rel = joints[i] - pivots[i]
            # Components of the pivot->joint vector in the crank plane (c, up) and across it.
            a = rel @ cdir[i]
            b = -rel[2]
            off = rel - a * cdir[i] - np.array([0.0, 0.0, -b])
            rho = math.hypot(a, b)
            with np.errstate(over="ignore"):  # (joint circles of 1e300 m: inf, said below)
                across = float(np.linalg.norm(off))
            dmin = math.hypot(abs(rho - r[i]), across)
            dmax = math.hypot(rho + r[i], across)
            rod = self.rod[i]
            if rod < dmin:
                raise ConfigError(
                    f"{src}: field 'rod': leg {i + 1} rod {rod:g} m is too short to reach its "
                    f"platform joint at the neutral pose (needs >= {dmin:.6g} m)"
                )
            if rod > dmax:
                raise ConfigError(
                    f"{src}: field 'rod': leg {i + 1} rod {rod:g} m is too long to meet its "
                    f"platform joint at the neutral pose (needs <= {dmax:.6g} m)"
                )

    def _check_lines(self, src: str, neutral: np.ndarray) -> None:
        """The rods must hold the platform's rotations (see :mod:`.conditioning`)."""
        pivots, joints, centroid, cdir = self._neutral_points()
        r = np.array(self.crank)[:, None]
        up = np.array([0.0, 0.0, -1.0])
        tips = pivots + r * (np.cos(neutral)[:, None] * cdir + np.sin(neutral)[:, None] * up)
        length = float(np.mean(self.rod))
        c = line_conditioning(joints - centroid, joints - tips, length)
        if c < MIN_LINE_CONDITIONING:
            raise ConfigError(
                f"{src}: fields 'rp'/'e': the rods barely hold the platform's rotations at "
                f"the neutral pose (line conditioning {c:.2g} < {MIN_LINE_CONDITIONING:g}, "
                f"moments over the rod length {length:g} m): the platform joints "
                f"(rp = {self.rp:g} m, e = {self.e:g} m) are too close to one point or the "
                "rods' lines nearly meet (spread the joints: a larger rp or e, or fix the "
                "layout angles)"
            )

    def _check_park(self, src: str) -> None:
        park = np.full(N_LEGS, self.park_angle)
        lo, hi = np.array(self.angle_min), np.array(self.angle_max)
        for i in range(N_LEGS):
            if not lo[i] <= park[i] <= hi[i]:
                raise ConfigError(
                    f"{src}: field 'park_angle': leg {i + 1} park angle "
                    f"{math.degrees(park[i]):g} deg is outside its limits "
                    f"{math.degrees(lo[i]):g} .. {math.degrees(hi[i]):g} deg"
                )
        z = self.heave_for_angles(park)
        if not np.isfinite(z).all():
            bad = int(np.flatnonzero(~np.isfinite(z))[0])
            raise ConfigError(
                f"{src}: field 'park_angle': leg {bad + 1} cannot reach any pure-heave pose at "
                f"{math.degrees(park[bad]):g} deg (choose an angle nearer neutral)"
            )
        if np.ptp(z) > 1e-6:
            raise ConfigError(
                f"{src}: field 'park_angle': equal cranks at {math.degrees(self.park_angle):g} "
                f"deg give no pure-heave pose on this asymmetric platform (legs disagree by "
                f"{np.ptp(z) * 1e3:.3f} mm)"
            )
        # The inverse kinematics must give the park angle back for the park pose: past the
        # lowest pure-heave pose the cranks hold the platform in the other assembly, which
        # the inverse kinematics never commands (limits looser than the geometry allows put
        # the default park there: the start then swung the cranks through the lowest pose
        # at full speed, and parked the platform above neutral).
        back = self.angles_for_heave(float(np.mean(z)))
        if not np.allclose(back, park, rtol=0.0, atol=1e-6):
            neutral = float(np.max(self.neutral_angle))
            grid = np.linspace(float(np.max(lo)), neutral, 2001)
            heave = np.array([np.mean(self.heave_for_angles(np.full(N_LEGS, a))) for a in grid])
            lowest = math.degrees(grid[int(np.nanargmax(heave))])
            raise ConfigError(
                f"{src}: field 'park_angle': at {math.degrees(self.park_angle):g} deg the "
                f"cranks are past the lowest pure-heave pose (at about {lowest:.1f} deg), in "
                "an assembly the inverse kinematics never commands (give a park_angle_deg "
                "above it and below the neutral angle, or raise angle_min_deg above it)"
            )

    # ------------------------------------------------------------------ derived geometry
    def _neutral_points(self):
        pivots, joints_xy, cdir = _leg_arrays(
            self.rb,
            self.d,
            np.array(self.chi_a),
            self.rp,
            self.e,
            np.array(self.chi_j),
            np.array(self.beta),
        )
        joints = np.concatenate([joints_xy, np.full((N_LEGS, 1), -self.neutral_height)], axis=1)
        centroid = joints.mean(axis=0)
        return pivots, joints, centroid, cdir

    @property
    def pivots(self) -> np.ndarray:
        """Crank pivots ``A_i`` in base axes, m, shape (6, 3)."""
        return self._neutral_points()[0]

    @property
    def crank_directions(self) -> np.ndarray:
        """Unit crank direction at crank angle 0 (horizontal), base axes, shape (6, 3)."""
        return self._neutral_points()[3]

    @property
    def platform_origin(self) -> np.ndarray:
        """Neutral position of the platform frame origin (the joints' centroid), m, shape (3,)."""
        return self._neutral_points()[2]

    @property
    def platform_joints_local(self) -> np.ndarray:
        """Platform joints in the platform frame (origin at their centroid), m, shape (6, 3)."""
        _, joints, centroid, _ = self._neutral_points()
        return joints - centroid

    @property
    def neutral_angle(self) -> np.ndarray:
        """Crank angles at the neutral pose, rad, shape (6,) (0 when cranks are horizontal)."""
        return self.angles_for_heave(0.0)

    def angles_for_heave(self, z: float) -> np.ndarray:
        """Crank angles of the pure-heave pose ``[0, 0, z, 0, 0, 0]`` (z down, m), shape (6,).

        The same closed form as :meth:`motionbase.platform.Rus6.inverse`, in plain numpy; NaN
        for a leg that cannot reach.
        """
        pivots, joints, _, cdir = self._neutral_points()
        rel = joints + np.array([0.0, 0.0, z]) - pivots
        r, rod = np.array(self.crank), np.array(self.rod)
        u = 2 * r * np.einsum("ij,ij->i", rel, cdir)
        v = -2 * r * rel[:, 2]
        w = rod**2 - np.einsum("ij,ij->i", rel, rel) - r**2
        disc = u * u + v * v - w * w
        q = np.sqrt(np.where(disc >= 0, disc, np.nan))
        return np.arctan2(-v * w - u * q, -u * w + v * q)

    def heave_for_angles(self, angles: np.ndarray) -> np.ndarray:
        """Per leg, the heave z (m, down) at which the leg closes with its crank at ``angles``.

        The root nearest the neutral pose; NaN if none. For a symmetric platform all six agree.
        """
        pivots, joints, _, cdir = self._neutral_points()
        r, rod = np.array(self.crank), np.array(self.rod)
        ang = np.asarray(angles, dtype=float)
        tips = pivots + r[:, None] * (
            np.cos(ang)[:, None] * cdir + np.sin(ang)[:, None] * np.array([0.0, 0.0, -1.0])
        )
        dxy = joints[:, :2] - tips[:, :2]
        h2 = rod**2 - np.einsum("ij,ij->i", dxy, dxy)
        dz = np.sqrt(np.where(h2 >= 0, h2, np.nan))
        # joint z + heave - tip z = -dz (joint above tip)
        return tips[:, 2] - dz - joints[:, 2]

    @classmethod
    def neutral_height_for_angle(
        cls, *, rb, d, rp, e, chi_a, chi_j, beta, crank, rod, angle: float
    ) -> np.ndarray:
        """Per leg, the neutral height (m) that puts the crank at ``angle`` (rad) at neutral."""
        pivots, joints_xy, cdir = _leg_arrays(
            rb,
            d,
            np.asarray(chi_a, float),
            rp,
            e,
            np.asarray(chi_j, float),
            np.asarray(beta, float),
        )
        r = np.broadcast_to(np.asarray(crank, float), (N_LEGS,))
        rod = np.broadcast_to(np.asarray(rod, float), (N_LEGS,))
        tips = pivots + r[:, None] * (
            math.cos(angle) * cdir + math.sin(angle) * np.array([0.0, 0.0, -1.0])
        )
        dxy = joints_xy - tips[:, :2]
        h2 = rod**2 - np.einsum("ij,ij->i", dxy, dxy)
        return -tips[:, 2] + np.sqrt(np.where(h2 >= 0, h2, np.nan))

    # ------------------------------------------------------------------ (de)serialisation
    def to_dict(self) -> dict[str, Any]:
        """Plain SI data (floats and lists; no degrees), ``from_dict`` rebuilds it exactly."""
        out: dict[str, Any] = {"name": self.name}
        for f in fields(self):
            if f.name == "name":
                continue
            v = getattr(self, f.name)
            if f.name == "output":
                if v is not None:
                    out["output"] = v.to_dict()
                continue
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "rus6 geometry") -> Rus6Geometry:
        """Build from plain data: SI fields, or angle fields in degrees named ``<field>_deg``.

        Accepted keys: ``rb, d, rp, e, crank, rod, neutral_height`` (m);
        ``chi_a, chi_j, beta, angle_min, angle_max`` (rad, per leg) and ``park_angle`` (rad,
        one value) or the same with ``_deg``; ``max_speed`` (rad/s) or ``max_speed_deg_s``;
        ``max_accel`` (rad/s^2) or ``max_accel_deg_s2``; ``neutral_angle_deg`` instead of
        ``neutral_height`` (the height is then derived so the cranks sit at that angle at
        neutral); ``name``; ``kind`` (must be ``"rus6"`` if present); ``output``, a table of
        the motor-drive mapping (see :class:`~motionbase.platform.output_map.OutputMapping`).
        Per-leg fields take 6 numbers or one number for all legs. The angle limits,
        ``max_speed`` and ``max_accel`` are required (limits that move motors are never
        defaulted); numbers must be numbers (a bool or a string is an error).
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: expected a table of geometry fields, got {data!r}")
        check_file_kind(source, data, "rus6")
        allowed = {"name", "kind", "neutral_angle_deg", "output"}
        allowed |= set(_SCALARS) | set(_LENGTH_ARRAYS)
        for f in _ANGLE_ARRAYS + ("park_angle",):
            allowed |= {f, f + "_deg"}
        for f, suffix in _RATE_ARRAYS.items():
            allowed |= {f, f"{f}_{suffix}"}
        check_keys(source, data, allowed)
        if "kind" in data and data["kind"] != "rus6":
            raise ConfigError(f"{source}: field 'kind': expected 'rus6', got {data['kind']!r}")
        kw: dict[str, Any] = {}
        name = data.get("name", Path(source).stem if source.endswith(".toml") else "custom")
        if not isinstance(name, str):
            raise ConfigError(f"{source}: field 'name': expected a string, got {name!r}")
        kw["name"] = name
        for f in _SCALARS + _LENGTH_ARRAYS:
            if f in data:
                kw[f] = data[f]
        for f in _ANGLE_ARRAYS:
            kw_val = _pick(source, data, f, f + "_deg", lambda a: np.radians(a))
            if kw_val is not None:
                kw[f] = kw_val
        for f, suffix in _RATE_ARRAYS.items():
            kw_val = _pick(source, data, f, f"{f}_{suffix}", lambda a: np.radians(a))
            if kw_val is not None:
                kw[f] = kw_val
        if "park_angle" in data and "park_angle_deg" in data:
            raise ConfigError(f"{source}: give either 'park_angle' or 'park_angle_deg', not both")
        if "park_angle_deg" in data:
            kw["park_angle"] = math.radians(
                as_float(source, "park_angle_deg", data["park_angle_deg"])
            )
        elif "park_angle" in data:
            kw["park_angle"] = data["park_angle"]
        required = (
            "rb",
            "d",
            "rp",
            "e",
            "chi_a",
            "chi_j",
            "beta",
            "crank",
            "rod",
            "angle_min",
            "angle_max",
        )
        for f in required:
            if f not in kw:
                raise ConfigError(f"{source}: missing field {f!r} (add it)")
        for f, suffix in _RATE_ARRAYS.items():
            if f not in kw:
                unit = "rad/s" if f == "max_speed" else "rad/s^2"
                raise ConfigError(
                    f"{source}: missing field {f!r} (or '{f}_{suffix}'): the crank "
                    f"{'speed' if f == 'max_speed' else 'acceleration'} limit in {unit}, which "
                    "is never guessed (add your drives' limit)"
                )
        for f in _LENGTH_ARRAYS + _ANGLE_ARRAYS + tuple(_RATE_ARRAYS):
            if f in kw:
                kw[f] = as_array(source, f, kw[f], N_LEGS)
        if "neutral_angle_deg" in data:
            if "neutral_height" in data:
                raise ConfigError(
                    f"{source}: give either 'neutral_height' or 'neutral_angle_deg', not both"
                )
            ang = math.radians(as_float(source, "neutral_angle_deg", data["neutral_angle_deg"]))
            for i, (lo, hi) in enumerate(zip(kw["angle_min"], kw["angle_max"], strict=True)):
                # (the constructor names bad limits). On a limit is refused too: the angle
                # the height gives back differs by a rounding, which fell outside and was
                # blamed on neutral_height, a field the file did not have.
                if lo < hi and not lo < ang < hi:
                    where = "outside" if not lo <= ang <= hi else "on one of"
                    raise ConfigError(
                        f"{source}: field 'neutral_angle_deg': {math.degrees(ang):g} deg is "
                        f"{where} leg {i + 1}'s limits {math.degrees(lo):g} .. "
                        f"{math.degrees(hi):g} deg (fix the angle or the limits: neutral lies "
                        "between them)"
                    )
            geo = {
                k: kw[k] for k in ("rb", "d", "rp", "e", "chi_a", "chi_j", "beta", "crank", "rod")
            }
            for k in ("rb", "d", "rp", "e"):
                geo[k] = as_float(source, k, geo[k], min_value=0.0)
            for k in _LENGTH_ARRAYS:  # (the same check as the constructor's, which comes later)
                for i, v in enumerate(np.broadcast_to(geo[k], (N_LEGS,))):
                    if not v > 0:
                        raise ConfigError(
                            f"{source}: field {k!r}: leg {i + 1} must be > 0 m, got {v:g} "
                            "(fix the value)"
                        )
            with np.errstate(over="ignore", invalid="ignore"):
                h = cls.neutral_height_for_angle(**geo, angle=ang)
            if not np.isfinite(h).all():
                i = int(np.flatnonzero(~np.isfinite(h))[0])
                how = "too short to reach" if np.isnan(h[i]) else "too long for"
                rod_i = float(np.broadcast_to(geo["rod"], (N_LEGS,))[i])
                raise ConfigError(
                    f"{source}: field 'rod': leg {i + 1} rod {rod_i:g} m is "
                    f"{how} the platform with the cranks at neutral_angle_deg = "
                    f"{math.degrees(ang):g} (fix the rod, the crank or the joint circles)"
                )
            if np.ptp(h) > 1e-9:
                raise ConfigError(
                    f"{source}: field 'neutral_angle_deg': the legs need different neutral "
                    f"heights ({np.min(h):.4f} .. {np.max(h):.4f} m); give 'neutral_height'"
                )
            kw["neutral_height"] = float(np.mean(h))
        elif "neutral_height" not in kw:
            raise ConfigError(
                f"{source}: missing field 'neutral_height' (or give 'neutral_angle_deg')"
            )
        if "output" in data:
            kw["output"] = OutputMapping.from_dict(
                data["output"],
                angle_min=kw["angle_min"],
                angle_max=kw["angle_max"],
                source=f"{source}: [output]",
            )
        try:
            geometry = cls(**kw)
        except ConfigError as exc:
            msg = str(exc).replace(f"rus6 geometry {name!r}", source, 1)
            if "neutral_angle_deg" in data:  # the height is derived: name what the file gave
                msg = msg.replace("neutral_height", "neutral_angle_deg")
            raise ConfigError(msg) from None
        if "neutral_angle_deg" in data:
            # The height that closes the legs at this angle closes them at a second one too;
            # the inverse kinematics commands the other one when the angle is past the lowest
            # pure-heave pose (or outside -180..180 deg, where it wraps).
            got = geometry.neutral_angle
            if not np.allclose(got, ang, rtol=0.0, atol=1e-6):
                raise ConfigError(
                    f"{source}: field 'neutral_angle_deg': the cranks cannot be commanded to "
                    f"{math.degrees(ang):g} deg at neutral: at that height the inverse "
                    f"kinematics puts them at {math.degrees(float(got[0])):.2f} deg (give an "
                    "angle between those of the lowest and the highest pure-heave poses, or "
                    "neutral_height)"
                )
        return geometry

    @classmethod
    def from_toml(cls, path: str | Path) -> Rus6Geometry:
        """Load from a TOML file (fields as in :meth:`from_dict`)."""
        p = Path(path)
        return cls.from_dict(read_toml(p), source=str(p))

    @classmethod
    def preset(cls, name: str) -> Rus6Geometry:
        """A shipped preset (``"ceart"``) or a path to a TOML file."""
        p = resolve_preset_or_path("rus6", name)
        return cls.from_dict(read_toml(p), source=p.name if p.parent.name == "presets" else str(p))

    def to_toml(self, path: str | Path, units: Literal["si", "deg"] = "si") -> None:
        """Save to TOML.

        ``units="si"`` (default) writes :meth:`to_dict` and reloads bit for bit;
        ``units="deg"`` writes angle fields as ``<field>_deg`` for hand editing (reloading then
        agrees to about 1e-15 rad, not bit for bit).
        """
        data = self.to_dict()
        if units == "deg":
            for f in _ANGLE_ARRAYS:
                data[f + "_deg"] = [math.degrees(x) for x in data.pop(f)]
            data["park_angle_deg"] = math.degrees(data.pop("park_angle"))
            for f, suffix in _RATE_ARRAYS.items():
                data[f"{f}_{suffix}"] = [math.degrees(x) for x in data.pop(f)]
        elif units != "si":
            raise ConfigError(f"to_toml: units must be 'si' or 'deg', got {units!r}")
        write_toml(path, {"kind": "rus6", **data})


def _pick(source: str, data: Mapping[str, Any], si: str, alt: str, convert) -> Any:
    if si in data and alt in data:
        raise ConfigError(f"{source}: give either {si!r} or {alt!r}, not both")
    if si in data:
        return data[si]
    if alt in data:
        arr = as_array(source, alt, data[alt], N_LEGS)
        return convert(arr)
    return None
