"""Per-motor actuator output mapping: crank angles to the values a motor drive expects.

Pure math, no I/O. DESIGN.md puts mirrored motors, gear ratios and zero offsets here, not in
the kinematics. For motor ``i`` with crank angle ``q`` (rad, 0 with the crank horizontal,
growing as the crank tip rises):

1. motor shaft angle ``m = sign * gear_ratio * q + zero_offset`` (rad). ``sign`` is -1 for a
   mirrored motor; ``gear_ratio`` is motor turns per crank turn; ``zero_offset`` is the motor
   shaft angle (rad) the drive reports when the crank is horizontal.
2. drive value, by ``unit``:

   * ``"deg"``: ``degrees(m)`` (float);
   * ``"rad"``: ``m`` (float);
   * ``"counts"``: ``round(m * counts_per_rev / (2 pi))`` (integer encoder counts or steps);
   * ``"range"``: ``round(lo + (hi - lo) (m - span_min) / (span_max - span_min))``, a
     normalised integer range ``lo..hi`` (e.g. 0..4095, 0..65535) across the motor-angle span
     ``span_min..span_max`` (rad). The default span is the image of the crank range, so ``lo``
     and ``hi`` are the crank limits (reversed for a mirrored motor);
   * ``"mm"``, ``"m"``: linear actuators. Their actuator value ``q`` is a length (m), and
     so is ``m`` (``zero_offset`` in m); the drive value is ``1000 m`` (mm, float) or ``m``.
     The default mapping of a linear-actuator robot is ``"mm"``; ``"range"`` works for
     lengths too (its span then in m).

Every motor has a drive range ``drive_min..drive_max`` (drive units); a value outside it is
never sent. The default is the image of the crank limits (rounded for integer units), so a
command within the crank limits always fits; for ``"range"`` only its part within
``range_lo..range_hi`` (a span narrower than the crank range leaves the commands beyond it
unsent, never sent past the range).

TOML (an ``[output]`` table of the 6-RUS geometry file)::

    [output]
    unit = "range"          # deg | rad | counts | range
    sign = [1, -1, 1, -1, 1, -1]
    zero_offset_deg = 0.0   # or zero_offset (rad); one number or one per motor
    gear_ratio = 1.0
    range_lo = 0
    range_hi = 4095
    # counts_per_rev = 10000          (unit = "counts")
    # span_min_deg / span_max_deg     (unit = "range"; default: the crank range)
    # drive_min / drive_max           (drive units; default: the crank range's image,
    #                                  within range_lo..range_hi for unit "range", where
    #                                  given ones must lie within it too)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from motionbase.config import as_array, as_float, check_keys
from motionbase.errors import ConfigError

__all__ = ["OutputMapping", "UNITS", "sweep_profile"]

UNITS = ("deg", "rad", "counts", "range", "mm", "m")
_INTEGER_UNITS = ("counts", "range")
#: The largest drive value whose neighbours are whole numbers in a double (2^53).
_EXACT = 2.0**53
_TWO_PI = 2.0 * math.pi


def _tuple(a: Any) -> tuple[float, ...]:
    return tuple(float(x) for x in np.asarray(a, dtype=float).ravel())


@dataclass(frozen=True)
class OutputMapping:
    """How each motor's drive value follows from its crank angle.

    Parameters
    ----------
    unit : {"deg", "rad", "counts", "range", "mm", "m"}
        What the drive expects (see the module docstring).
    sign : tuple of n float
        +1, or -1 for a mirrored motor.
    zero_offset : tuple of n float
        Motor shaft angle at crank angle 0, rad.
    gear_ratio : tuple of n float
        Motor turns per crank turn (> 0).
    counts_per_rev : float or None
        Counts (or steps) per motor revolution; required for ``unit="counts"``.
    range_lo, range_hi : int or None
        The normalised integer range (``lo < hi``); required for ``unit="range"``.
    span_min, span_max : tuple of n float or None
        Motor-shaft angles (rad) that map to ``range_lo`` and ``range_hi`` (``"range"`` only).
    drive_min, drive_max : tuple of n float
        Values the drive accepts, drive units; anything outside is never sent.

    Use :meth:`from_dict` (or :meth:`default`) to build one from crank limits; the
    constructor takes every field resolved, which is what :meth:`to_dict` gives back.
    """

    unit: str
    sign: tuple[float, ...]
    zero_offset: tuple[float, ...]
    gear_ratio: tuple[float, ...]
    drive_min: tuple[float, ...]
    drive_max: tuple[float, ...]
    counts_per_rev: float | None = None
    range_lo: int | None = None
    range_hi: int | None = None
    span_min: tuple[float, ...] | None = None
    span_max: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        src = "output mapping"
        if self.unit not in UNITS:
            raise ConfigError(
                f"{src}: field 'unit': expected one of {', '.join(UNITS)}, got {self.unit!r}"
            )
        sign = np.asarray(self.sign, dtype=float).ravel()
        n = sign.size
        if n < 1:
            raise ConfigError(f"{src}: field 'sign': give one value per motor")
        for f in ("sign", "zero_offset", "gear_ratio", "drive_min", "drive_max"):
            object.__setattr__(self, f, _tuple(as_array(src, f, getattr(self, f), n)))
        if any(s not in (1.0, -1.0) for s in self.sign):
            raise ConfigError(f"{src}: field 'sign': each motor's sign must be 1 or -1")
        if any(g <= 0 for g in self.gear_ratio):
            raise ConfigError(f"{src}: field 'gear_ratio': must be > 0 (use sign to mirror)")
        for i in range(n):
            if not self.drive_min[i] < self.drive_max[i]:
                raise ConfigError(
                    f"{src}: fields 'drive_min'/'drive_max': motor {i + 1} needs min < max, got "
                    f"{self.drive_min[i]:g} .. {self.drive_max[i]:g}"
                )
        if self.unit == "counts":
            if self.counts_per_rev is None:
                raise ConfigError(f"{src}: unit 'counts' needs 'counts_per_rev' (add it)")
            cpr = as_float(src, "counts_per_rev", self.counts_per_rev, min_value=0, strict_min=True)
            object.__setattr__(self, "counts_per_rev", cpr)
        elif self.counts_per_rev is not None:
            raise ConfigError(f"{src}: 'counts_per_rev' only applies to unit 'counts'")
        if self.unit == "range":
            for f in ("range_lo", "range_hi"):
                v = getattr(self, f)
                if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                    raise ConfigError(f"{src}: unit 'range' needs an integer {f!r}, got {v!r}")
                if not abs(int(v)) <= _EXACT:  # (a float no longer holds every whole number)
                    raise ConfigError(
                        f"{src}: field {f!r}: must be within +-2^53, got a whole number of "
                        f"{len(str(abs(int(v))))} digits (fix the value)"
                    )
                object.__setattr__(self, f, int(v))
            if not self.range_lo < self.range_hi:
                raise ConfigError(
                    f"{src}: 'range_lo' must be < 'range_hi', got {self.range_lo}..{self.range_hi}"
                    " (use sign = -1 to reverse a motor)"
                )
            if self.span_min is None or self.span_max is None:
                raise ConfigError(f"{src}: unit 'range' needs 'span_min' and 'span_max'")
            for f in ("span_min", "span_max"):
                object.__setattr__(self, f, _tuple(as_array(src, f, getattr(self, f), n)))
            for i in range(n):
                if not self.span_min[i] < self.span_max[i]:
                    raise ConfigError(
                        f"{src}: fields 'span_min'/'span_max': motor {i + 1} needs min < max"
                    )
        else:
            for f in ("range_lo", "range_hi", "span_min", "span_max"):
                if getattr(self, f) is not None:
                    raise ConfigError(f"{src}: {f!r} only applies to unit 'range'")
        # Affine coefficients: value = a * q + b (before rounding), cached for speed.
        a, b = self._affine()
        for name, arr in (("_a", a), ("_b", b)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        lo, hi = np.array(self.drive_min), np.array(self.drive_max)
        lo.setflags(write=False)
        hi.setflags(write=False)
        object.__setattr__(self, "_lo", lo)
        object.__setattr__(self, "_hi", hi)

    # ------------------------------------------------------------------ the map
    @property
    def n(self) -> int:
        """Number of motors."""
        return len(self.sign)

    @property
    def integer(self) -> bool:
        """Whether drive values are integers (``counts`` and ``range``)."""
        return self.unit in _INTEGER_UNITS

    def _motor_to_drive(self) -> tuple[np.ndarray, np.ndarray]:
        """Per motor, value = k * m + c for the motor-shaft angle m (rad)."""
        n = self.n
        if self.unit == "deg":
            return np.full(n, 180.0 / math.pi), np.zeros(n)
        if self.unit in ("rad", "m"):
            return np.ones(n), np.zeros(n)
        if self.unit == "mm":
            return np.full(n, 1000.0), np.zeros(n)
        if self.unit == "counts":
            return np.full(n, self.counts_per_rev / _TWO_PI), np.zeros(n)
        smin, smax = np.array(self.span_min), np.array(self.span_max)
        k = (self.range_hi - self.range_lo) / (smax - smin)
        return k, self.range_lo - k * smin

    def _affine(self) -> tuple[np.ndarray, np.ndarray]:
        k, c = self._motor_to_drive()
        sg, gr, off = np.array(self.sign), np.array(self.gear_ratio), np.array(self.zero_offset)
        return k * sg * gr, k * off + c

    def motor_angles(self, angles: np.ndarray) -> np.ndarray:
        """Motor shaft angles (rad) of crank angles (rad), shape ``(..., n)``."""
        q = np.asarray(angles, dtype=float)
        return np.array(self.sign) * np.array(self.gear_ratio) * q + np.array(self.zero_offset)

    def to_drive(self, angles: np.ndarray) -> np.ndarray:
        """Drive values of crank angles.

        Parameters
        ----------
        angles : array_like, shape (..., n)
            Crank angles, rad.

        Returns
        -------
        ndarray of float, shape (..., n)
            Drive values in drive units (integer-valued for ``counts`` and ``range``; NaN stays
            NaN, so :meth:`in_range` is False for it).
        """
        v = self._a * np.asarray(angles, dtype=float) + self._b
        return np.rint(v) if self.unit in _INTEGER_UNITS else v

    def from_drive(self, values: np.ndarray) -> np.ndarray:
        """Crank angles (rad) of drive values, shape ``(..., n)``; inverse of :meth:`to_drive`
        up to its rounding (half a count or range step)."""
        return (np.asarray(values, dtype=float) - self._b) / self._a

    def in_range(self, values: np.ndarray) -> np.ndarray:
        """Per value, whether the drive accepts it (finite and within drive_min..drive_max)."""
        v = np.asarray(values, dtype=float)
        return (v >= self._lo) & (v <= self._hi)  # False for NaN

    def resolution(self) -> np.ndarray:
        """Crank angle (rad) of one drive unit (one count or range step, 1 deg, 1 rad), (n,)."""
        return 1.0 / np.abs(self._a)

    # ------------------------------------------------------------------ construction
    @classmethod
    def default(
        cls, angle_min: Sequence[float], angle_max: Sequence[float], unit: str = "deg"
    ) -> OutputMapping:
        """No mirroring, no offset, direct drive, for actuator limits: degrees for crank
        limits (rad), or ``unit="mm"`` for the length limits (m) of linear actuators."""
        return cls.from_dict({"unit": unit}, angle_min=angle_min, angle_max=angle_max)

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        *,
        angle_min: Sequence[float],
        angle_max: Sequence[float],
        source: str = "output mapping",
    ) -> OutputMapping:
        """Build from a table (the geometry file's ``[output]``), resolving defaults.

        Parameters
        ----------
        data : mapping
            ``unit`` (required), ``sign``, ``zero_offset`` or ``zero_offset_deg``,
            ``gear_ratio``, ``counts_per_rev``, ``range_lo``, ``range_hi``,
            ``span_min``/``span_max`` (rad) or ``span_min_deg``/``span_max_deg``,
            ``drive_min``/``drive_max`` (drive units). Per-motor fields take one number per
            motor or one for all.
        angle_min, angle_max : sequence of n float
            Crank limits, rad: their number sets the number of motors and they give the
            default span and drive range.
        source : str
            Named in error messages.
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: expected a table of output fields, got {data!r}")
        allowed = {
            "unit",
            "sign",
            "zero_offset",
            "zero_offset_deg",
            "gear_ratio",
            "counts_per_rev",
            "range_lo",
            "range_hi",
            "span_min",
            "span_max",
            "span_min_deg",
            "span_max_deg",
            "drive_min",
            "drive_max",
        }
        check_keys(source, data, allowed, required=("unit",))
        qmin = np.asarray(angle_min, dtype=float).ravel()
        qmax = np.asarray(angle_max, dtype=float).ravel()
        n = qmin.size

        def per_motor(si: str, deg: str | None, default: float) -> np.ndarray:
            if deg is not None and si in data and deg in data:
                raise ConfigError(f"{source}: give either {si!r} or {deg!r}, not both")
            if deg is not None and deg in data:
                return np.radians(as_array(source, deg, data[deg], n))
            if si in data:
                return as_array(source, si, data[si], n)
            return np.full(n, default)

        kw: dict[str, Any] = {"unit": data["unit"]}
        kw["sign"] = per_motor("sign", None, 1.0)
        kw["zero_offset"] = per_motor("zero_offset", "zero_offset_deg", 0.0)
        kw["gear_ratio"] = per_motor("gear_ratio", None, 1.0)
        for f in ("counts_per_rev", "range_lo", "range_hi"):
            if f in data:
                kw[f] = data[f]
        # Motor-shaft image of the crank range (sorted per motor).
        sg, gr, off = kw["sign"], kw["gear_ratio"], kw["zero_offset"]
        m1, m2 = sg * gr * qmin + off, sg * gr * qmax + off
        mlo, mhi = np.minimum(m1, m2), np.maximum(m1, m2)
        if kw["unit"] == "range":
            kw["span_min"] = per_motor("span_min", "span_min_deg", math.nan)
            kw["span_max"] = per_motor("span_max", "span_max_deg", math.nan)
            kw["span_min"] = np.where(np.isnan(kw["span_min"]), mlo, kw["span_min"])
            kw["span_max"] = np.where(np.isnan(kw["span_max"]), mhi, kw["span_max"])
        else:
            for f in ("span_min", "span_max", "span_min_deg", "span_max_deg"):
                if f in data:
                    raise ConfigError(f"{source}: {f!r} only applies to unit 'range'")
        dmin = per_motor("drive_min", None, math.nan)
        dmax = per_motor("drive_max", None, math.nan)
        try:
            if np.isnan(dmin).any() or np.isnan(dmax).any():
                # Default drive range: the crank range's image, through a provisional mapping.
                probe = cls(**{**kw, "drive_min": np.zeros(n), "drive_max": np.ones(n)})
                v1, v2 = probe.to_drive(qmin), probe.to_drive(qmax)
                flat = ~(np.abs(v1 - v2) > 0) & (np.isnan(dmin) | np.isnan(dmax))
                if flat.any():
                    i = int(np.flatnonzero(flat)[0])
                    raise ConfigError(
                        f"output mapping: motor {i + 1}'s crank range maps to one drive value "
                        f"({v1[i]:g}): check its zero_offset and gear_ratio (the offset "
                        "swamps the crank's motion), or give drive_min/drive_max"
                    )
                lo, hi = np.minimum(v1, v2), np.maximum(v1, v2)
                if kw["unit"] == "range":
                    # the range is the drive's: a span narrower than the crank range (0..4095
                    # across +-45 deg of +-60 deg cranks) sent 4778 to a 12-bit drive
                    lo = np.maximum(lo, probe.range_lo)
                    hi = np.minimum(hi, probe.range_hi)
                dmin = np.where(np.isnan(dmin), lo, dmin)
                dmax = np.where(np.isnan(dmax), hi, dmax)
            kw["drive_min"], kw["drive_max"] = dmin, dmax
            mapping = cls(**kw)
            if mapping.unit == "range":
                # the range is the drive's: a drive_max of 400 on a 0..300 range sent 375 for
                # the longest actuator of a span narrower than the stroke
                lo, hi = mapping.range_lo, mapping.range_hi
                for i in range(n):
                    if not lo <= mapping.drive_min[i] < mapping.drive_max[i] <= hi:
                        raise ConfigError(
                            f"output mapping: fields 'drive_min'/'drive_max': motor {i + 1}'s "
                            f"drive range {mapping.drive_min[i]:g} .. {mapping.drive_max[i]:g} "
                            f"passes range_lo..range_hi {lo}..{hi}, past which no value is "
                            "sent (keep them within it)"
                        )
            # Past 2^53 a double no longer holds every whole number: a gear ratio or counts
            # per revolution of 1e300 sent 300-digit values of rounding noise to the drive.
            ends = np.stack([mapping.to_drive(qmin), mapping.to_drive(qmax)])
            huge = (mapping.in_range(ends) & (np.abs(ends) > _EXACT)).any(axis=0)
            if huge.any():
                i = int(np.flatnonzero(huge)[0])
                raise ConfigError(
                    f"output mapping: motor {i + 1}'s crank range reaches drive value "
                    f"{np.max(np.abs(ends[:, i])):g}, past 2^53, where the values lose whole "
                    "units (check its gear_ratio and counts_per_rev)"
                )
            return mapping
        except ConfigError as exc:
            raise ConfigError(str(exc).replace("output mapping", source, 1)) from None

    def to_dict(self) -> dict[str, Any]:
        """Plain SI data; ``OutputMapping(**m.to_dict())`` and ``from_dict`` rebuild it exactly.

        Fields that do not apply to the unit (None) are left out.
        """
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    def describe(self) -> str:
        """One line for humans."""
        extra = ""
        if self.unit == "counts":
            extra = f", {self.counts_per_rev:g} counts/rev"
        elif self.unit == "range":
            extra = f", {self.range_lo}..{self.range_hi}"
        mirrored = [i + 1 for i, s in enumerate(self.sign) if s < 0]
        return (
            f"unit {self.unit}{extra}; mirrored motors {mirrored or 'none'}; gear ratios "
            f"{', '.join(f'{g:g}' for g in self.gear_ratio)}"
        )


# --------------------------------------------------------------------------- wiring check


#: The longest wiring check, s: a slower sweep is a mistyped speed (1e-6 deg/s took years).
MAX_SWEEP_S = 3600.0


def _move_duration(dist: float, vmax: float, amax: float) -> float:
    """How long a cosine move over ``dist`` takes within ``vmax`` and ``amax``, s."""
    return max(math.pi * dist / (2 * vmax), math.pi * math.sqrt(dist / (2 * amax)))


def _move(a: np.ndarray, b: np.ndarray, vmax: float, amax: float, dt: float) -> np.ndarray:
    """A cosine move from a to b (rad, shape (n,)) within vmax (rad/s) and amax (rad/s^2)."""
    dist = float(np.max(np.abs(b - a)))
    if dist == 0.0:
        return a[None, :].copy()
    duration = _move_duration(dist, vmax, amax)
    steps = max(1, math.ceil(duration / dt))
    s = (1 - np.cos(np.pi * np.arange(1, steps + 1) / steps)) / 2
    return a + s[:, None] * (b - a)


def sweep_profile(
    park: np.ndarray,
    neutral: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    range_rad: float,
    speed: float,
    accel: float,
    dt: float,
    dwell_s: float = 0.0,
    linear: bool = False,
    motors: Sequence[int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Crank commands of the wiring check: park -> neutral, each motor in turn through
    ``+range, -range`` about neutral, neutral -> park.

    Every move is a cosine blend whose peak speed is at most ``speed`` and peak acceleration
    at most ``accel``.

    Parameters
    ----------
    park, neutral, lower, upper : ndarray, shape (n,)
        Park and neutral crank angles and the crank limits, rad.
    range_rad : float
        Sweep half-range about neutral, rad (> 0).
    speed : float
        Peak crank speed, rad/s (> 0).
    accel : float
        Peak crank acceleration, rad/s^2 (> 0).
    dt : float
        Sample period, s.
    dwell_s : float
        Rest this long at each end of a sweep, s (so a slow sender or a watcher sees it).
    linear : bool
        Linear actuators (m, m/s, m/s^2): the messages then say mm and ``--range-mm``,
        ``--speed-mm-s``.
    motors : sequence of int, optional
        The motors to sweep (0-based, in this order); default every one.

    Returns
    -------
    angles : ndarray, shape (k, n)
        Commands, rad, one per ``dt``.
    motor : ndarray of int, shape (k,)
        The motor (1-based) being swept at each sample; 0 while moving from or to park.
    """
    park, neutral = np.asarray(park, float), np.asarray(neutral, float)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    if not (range_rad > 0 and speed > 0 and accel > 0 and dt > 0):
        raise ConfigError("output test: range, speed, acceleration and dt must be > 0")
    unit, per_unit, what = (
        ("mm", 1e3, "length limits") if linear else ("deg", 180 / math.pi, "crank limits")
    )
    # (a motor not swept only goes from park to neutral and back)
    motors = list(range(park.size) if motors is None else motors)
    if np.any(neutral[motors] + range_rad > upper[motors]) or np.any(
        neutral[motors] - range_rad < lower[motors]
    ):
        raise ConfigError(
            f"output test: +-{range_rad * per_unit:g} {unit} about neutral leaves the "
            f"{what} (choose a smaller --range-{unit})"
        )
    # (the moves: park -> neutral, each actuator +range, -range, back, neutral -> park)
    dists = [float(np.max(np.abs(neutral - park)))] * 2 + [range_rad, 2 * range_rad, range_rad]
    total = sum(_move_duration(d, speed, accel) for d in dists[:2]) + len(motors) * (
        sum(_move_duration(d, speed, accel) for d in dists[2:]) + 2 * dwell_s
    )
    if not total <= MAX_SWEEP_S:
        raise ConfigError(
            f"output test: at {speed * per_unit:g} {unit}/s the sweep would take "
            f"{total:.3g} s, more than an hour (give a faster --speed-{unit}-s)"
        )
    parts = [park[None, :], _move(park, neutral, speed, accel, dt)]
    labels = [np.zeros(1 + len(parts[1]), dtype=int)]
    cur = neutral
    for i in motors:
        seg = []
        for target in (+range_rad, -range_rad, 0.0):
            nxt = neutral.copy()
            nxt[i] += target
            seg.append(_move(cur, nxt, speed, accel, dt))
            if target != 0.0 and dwell_s > 0:
                seg.append(np.repeat(nxt[None, :], math.ceil(dwell_s / dt), axis=0))
            cur = nxt
        block = np.concatenate(seg)
        parts.append(block)
        labels.append(np.full(len(block), i + 1))
    back = _move(cur, park, speed, accel, dt)
    parts.append(back)
    labels.append(np.zeros(len(back), dtype=int))
    return np.concatenate(parts), np.concatenate(labels)
