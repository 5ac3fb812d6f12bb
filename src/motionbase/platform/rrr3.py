"""Kinematics of the planar 3-RRR parallel robot (thesis chapters 4, 5 and 7).

Frames and conventions
----------------------
Base frame (planar, metres): motor 1 at the origin ``A1 = (0, 0)``, motor 2 at ``A2 = (L, 0)``,
motor 3 at ``A3 = (L/2, L*sqrt(3)/2)``. A pose is ``[x, y, phi]``: the position of the platform
centroid ``P`` in the base frame (m) and the platform's orientation ``phi`` (rad,
counter-clockwise). The platform joints are, as in the thesis (appendix A.1),
``C1 = P - (h/sqrt(3)) (cos(pi/6 + phi), sin(pi/6 + phi))``, ``C2 = C1 + h (cos phi, sin phi)``,
``C3 = C1 + h (cos(phi + pi/3), sin(phi + pi/3))``. The joint angle ``theta_i`` (rad) is the
absolute angle of the crank ``A_i B_i`` from the base +x axis, counter-clockwise, in (-pi, pi].

Inverse kinematics is the tangent half-angle (Weierstrass) closed form (eqs. 4.18-4.29): with
``(xc, yc) = C_i - A_i``, ``e1 = -2 a yc``, ``e2 = -2 a xc``, ``e3 = xc^2 + yc^2 + a^2 - b^2``,
the loop closure ``e1 sin(theta) + e2 cos(theta) + e3 = 0`` becomes, with ``t = tan(theta/2)``,
``(e3 - e2) t^2 + 2 e1 t + (e3 + e2) = 0``, so
``t = (-e1 + m sqrt(e1^2 + e2^2 - e3^2)) / (e3 - e2)``, where ``m = +-1`` is the chain's
working mode. The ``+`` root is ``theta = atan2(yc, xc) + delta``
and the ``-`` root ``atan2(yc, xc) - delta`` with ``delta`` the crank-to-``A_iC_i`` angle, so a
mode is one elbow side for the whole annulus the chain can reach.

Jacobians (eqs. 5.10-5.11, derived again here, signs included): with the crank ``u_i = B_i - A_i``,
the rod ``n_i = C_i - B_i`` and ``e_i = C_i - P``, differentiating ``|n_i|^2 = b^2`` gives
``Jx xdot = Jq qdot`` with ``Jx`` rows ``[n_ix, n_iy, e_ix n_iy - e_iy n_ix]`` and
``Jq = diag(u_ix n_iy - u_iy n_ix)``; ``qdot = Jq^-1 Jx xdot``. Type I (inverse) singularity:
a diagonal entry of ``Jq`` vanishes (chain straight or folded), monitored as in the thesis by
``|a_ix b_iy - a_iy b_ix|``, here normalised by ``a b``. Type II (direct) singularity:
``det(Jx) = 0``, normalised by ``b^3 h / sqrt(3)``. Poses within the margins are refused like
unreachable ones.

Servo mapping (per motor ``i``): ``servo_deg = round((direction_i (theta_deg - zero_deg_i)) mod
360)`` must lie in ``[min_deg_i, max_deg_i]`` (0..180 for the Futaba S3003); outside, the pose
is refused, never wrapped or clipped. Rounding is half-up (``floor(x + 0.5)``).

The hot path (validity check, inverse kinematics, servo mapping, clamping) is one compiled
kernel (numba) used for single poses and for batches alike; Jacobians, joint points and the
forward kinematics are plain numpy.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from motionbase.config import (
    as_float,
    check_file_kind,
    check_keys,
    read_toml,
    resolve_preset_or_path,
    write_toml,
)
from motionbase.errors import ConfigError, MotionbaseError

__all__ = [
    "Rrr3Geometry",
    "Rrr3",
    "JointPoints",
    "Singularity",
    "PlanarWorkspace",
    "UnreachablePoseError",
    "OK",
    "UNREACHABLE",
    "TYPE1",
    "TYPE2",
    "SERVO_RANGE",
    "describe_status",
]

#: Status bits returned by :meth:`Rrr3.status` (0 means the pose is valid).
OK = 0
UNREACHABLE = 1  #: no real inverse kinematics solution for some chain (or a NaN input)
TYPE1 = 2  #: within the type I (inverse) singularity margin
TYPE2 = 4  #: within the type II (direct) singularity margin
SERVO_RANGE = 8  #: some servo's degrees fall outside its range

_SQRT3 = math.sqrt(3.0)


def describe_status(status: int) -> str:
    """Human-readable list of the reasons encoded in a status word."""
    if status == OK:
        return "valid"
    names = []
    if status & UNREACHABLE:
        names.append("unreachable")
    if status & TYPE1:
        names.append("near a type I (inverse) singularity")
    if status & TYPE2:
        names.append("near a type II (direct) singularity")
    if status & SERVO_RANGE:
        names.append("servo degrees out of range")
    return ", ".join(names)


class UnreachablePoseError(MotionbaseError, ValueError):
    """A pose or joint angle the robot cannot take (unreachable, singular, out of servo range)."""


# --------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------

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
        Joint angle ``theta_i`` (deg, base frame) at which servo ``i`` reads 0.
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
        object.__setattr__(
            self, "servo_zero_deg", _triple(src, "servo.zero_deg", self.servo_zero_deg, kind=float)
        )
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
            return cls._from_tables(data, servo, safety)
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
        """Parameters packed for the compiled kernels (internal layout, see ``_P_*``)."""
        p = np.zeros(_P_SIZE)
        p[_P_A : _P_A + 6] = self.base_points.ravel()
        p[_P_C : _P_C + 6] = self.platform_points.ravel()
        p[_P_CRANK] = self.crank
        p[_P_ROD] = self.rod
        p[_P_MODE : _P_MODE + 3] = self.modes
        p[_P_ZERO : _P_ZERO + 3] = self.servo_zero_deg
        p[_P_DIR : _P_DIR + 3] = self.servo_direction
        p[_P_MIN : _P_MIN + 3] = self.servo_min_deg
        p[_P_MAX : _P_MAX + 3] = self.servo_max_deg
        p[_P_M1] = self.type1_margin
        p[_P_M2] = self.type2_margin
        p[_P_RC] = self.platform_side / _SQRT3
        return p


# Packed parameter layout for the kernels.
_P_A, _P_C, _P_CRANK, _P_ROD = 0, 6, 12, 13
_P_MODE, _P_ZERO, _P_DIR, _P_MIN, _P_MAX = 14, 17, 20, 23, 26
_P_M1, _P_M2, _P_RC = 29, 30, 31
_P_SIZE = 32


# --------------------------------------------------------------------------------------------
# Compiled kernels (one pose at a time; loops for batches)
# --------------------------------------------------------------------------------------------


@njit(cache=True, fastmath=False)
def _solve_one(x, y, phi, p, theta, servo):  # pragma: no cover - compiled
    """Inverse kinematics + validity of one pose; writes theta (rad) and servo (deg).

    Returns the status word (0 = valid). Unreachable chains get theta = NaN, servo = -1.
    """
    status = 0
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(phi)):
        for i in range(3):
            theta[i] = math.nan
            servo[i] = -1
        return UNREACHABLE
    a = p[_P_CRANK]
    b = p[_P_ROD]
    c = math.cos(phi)
    s = math.sin(phi)
    # Jx rows for the type II test.
    j00 = j01 = j02 = j10 = j11 = j12 = j20 = j21 = j22 = 0.0
    for i in range(3):
        lx = p[_P_C + 2 * i]
        ly = p[_P_C + 2 * i + 1]
        ex = c * lx - s * ly
        ey = s * lx + c * ly
        cx = x + ex
        cy = y + ey
        ax = p[_P_A + 2 * i]
        ay = p[_P_A + 2 * i + 1]
        xc = cx - ax
        yc = cy - ay
        e1 = -2.0 * a * yc
        e2 = -2.0 * a * xc
        e3 = xc * xc + yc * yc + a * a - b * b
        disc = e1 * e1 + e2 * e2 - e3 * e3
        if disc < 0.0:
            theta[i] = math.nan
            servo[i] = -1
            status |= UNREACHABLE
            continue
        sq = math.sqrt(disc)
        m = p[_P_MODE + i]
        n1 = -e1 + m * sq
        d1 = e3 - e2
        n2 = e3 + e2
        d2 = -e1 - m * sq
        # t = n1/d1 = n2/d2 (product of the roots): take the better-conditioned quotient.
        if abs(n1) + abs(d1) >= abs(n2) + abs(d2):
            th = 2.0 * math.atan2(n1, d1)
        else:
            th = 2.0 * math.atan2(n2, d2)
        if th > math.pi:
            th -= 2.0 * math.pi
        elif th <= -math.pi:
            th += 2.0 * math.pi
        theta[i] = th
        ux = a * math.cos(th)
        uy = a * math.sin(th)
        nx = xc - ux
        ny = yc - uy
        jq = ux * ny - uy * nx
        if abs(jq) < p[_P_M1] * a * b:
            status |= TYPE1
        jr = ex * ny - ey * nx
        if i == 0:
            j00, j01, j02 = nx, ny, jr
        elif i == 1:
            j10, j11, j12 = nx, ny, jr
        else:
            j20, j21, j22 = nx, ny, jr
        # servo mapping
        deg = th * (180.0 / math.pi)
        sd = (p[_P_DIR + i] * (deg - p[_P_ZERO + i])) % 360.0
        r = math.floor(sd + 0.5)
        if r >= 360.0:
            r -= 360.0
        if r < p[_P_MIN + i] or r > p[_P_MAX + i]:
            status |= SERVO_RANGE
        servo[i] = int(r)
    if status & UNREACHABLE:
        return status
    det = (
        j00 * (j11 * j22 - j12 * j21)
        - j01 * (j10 * j22 - j12 * j20)
        + j02 * (j10 * j21 - j11 * j20)
    )
    if abs(det) < p[_P_M2] * b * b * b * p[_P_RC]:
        status |= TYPE2
    return status


@njit(cache=True)
def _solve_batch(poses, p):  # pragma: no cover - compiled
    n = poses.shape[0]
    theta = np.empty((n, 3))
    servo = np.empty((n, 3), dtype=np.int64)
    status = np.empty(n, dtype=np.int64)
    for k in range(n):
        status[k] = _solve_one(poses[k, 0], poses[k, 1], poses[k, 2], p, theta[k], servo[k])
    return theta, servo, status


@njit(cache=True)
def _status_grid(xs, ys, phis, p):  # pragma: no cover - compiled
    """Status of every (x, y, phi) of a grid, shape (len(xs), len(ys), len(phis))."""
    out = np.empty((xs.size, ys.size, phis.size), dtype=np.int8)
    theta = np.empty(3)
    servo = np.empty(3, dtype=np.int64)
    for i in range(xs.size):
        for j in range(ys.size):
            for k in range(phis.size):
                out[i, j, k] = _solve_one(xs[i], ys[j], phis[k], p, theta, servo)
    return out


@njit(cache=True)
def _clamp_one(x, y, phi, hx, hy, hphi, p, n_samples, n_bisect, theta, servo):  # pragma: no cover
    """Move (x, y, phi) toward home along the segment until valid.

    Returns (x, y, phi, clamped, status). The result is the farthest point from home such that
    every sample of the segment from home to it is valid (n_samples uniform samples, then
    n_bisect bisection steps on the first invalid interval). status != 0 only when home itself
    is invalid or the input is not finite.
    """
    st = _solve_one(x, y, phi, p, theta, servo)
    if st == 0:
        return x, y, phi, False, 0
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(phi)):
        st = _solve_one(hx, hy, hphi, p, theta, servo)
        return hx, hy, hphi, True, st | UNREACHABLE
    dx = x - hx
    dy = y - hy
    dp = phi - hphi
    lo = 0.0
    hi = 1.0
    for k in range(1, n_samples + 1):
        f = k / n_samples
        if _solve_one(hx + f * dx, hy + f * dy, hphi + f * dp, p, theta, servo) != 0:
            hi = f
            break
        lo = f
    for _ in range(n_bisect):
        mid = 0.5 * (lo + hi)
        if _solve_one(hx + mid * dx, hy + mid * dy, hphi + mid * dp, p, theta, servo) == 0:
            lo = mid
        else:
            hi = mid
    cx = hx + lo * dx
    cy = hy + lo * dy
    cp = hphi + lo * dp
    st = _solve_one(cx, cy, cp, p, theta, servo)
    return cx, cy, cp, True, st


@njit(cache=True)
def _clamp_batch(poses, home, p, n_samples, n_bisect):  # pragma: no cover - compiled
    n = poses.shape[0]
    out = np.empty((n, 3))
    clamped = np.empty(n, dtype=np.bool_)
    status = np.empty(n, dtype=np.int64)
    theta = np.empty(3)
    servo = np.empty(3, dtype=np.int64)
    for k in range(n):
        cx, cy, cp, cl, st = _clamp_one(
            poses[k, 0],
            poses[k, 1],
            poses[k, 2],
            home[0],
            home[1],
            home[2],
            p,
            n_samples,
            n_bisect,
            theta,
            servo,
        )
        out[k, 0] = cx
        out[k, 1] = cy
        out[k, 2] = cp
        clamped[k] = cl
        status[k] = st
    return out, clamped, status


# --------------------------------------------------------------------------------------------
# The robot
# --------------------------------------------------------------------------------------------


class JointPoints(NamedTuple):
    """Joint positions of the three chains, each of shape (..., 3, 2), m (NaN if unreachable).

    ``A``: motor axes; ``B``: crank tips (crank-rod joints); ``C``: platform joints.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray


class Singularity(NamedTuple):
    """Singularity measures of poses.

    Attributes
    ----------
    type1 : ndarray (..., 3)
        ``|a_ix b_iy - a_iy b_ix| / (a b)`` per chain: the sine of the crank-rod angle (0 at a
        type I singularity: chain straight or folded).
    type2 : ndarray (...)
        ``|det(Jx)| / (b^3 h / sqrt(3))`` (0 at a type II singularity).
    type1_raw : ndarray (..., 3)
        The thesis's monitor ``|a_ix b_iy - a_iy b_ix|``, m^2.
    det_jx : ndarray (...)
        ``det(Jx)``, signed, m^4.
    """

    type1: np.ndarray
    type2: np.ndarray
    type1_raw: np.ndarray
    det_jx: np.ndarray


class PlanarWorkspace(NamedTuple):
    """A workspace sweep over a grid (the thesis's triple loop), see :meth:`Rrr3.workspace`.

    ``x`` (nx,), ``y`` (ny,) in m and ``phi`` (nphi,) in rad are the grid axes; ``status``
    (nx, ny, nphi) int8 holds the status word of every pose (0 = valid).
    """

    x: np.ndarray
    y: np.ndarray
    phi: np.ndarray
    status: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """Boolean (nx, ny, nphi): the pose is reachable, non-singular and servo-valid."""
        return self.status == 0

    @property
    def total(self) -> np.ndarray:
        """Boolean (nx, ny): reachable with at least one orientation (thesis fig. 10)."""
        return self.valid.any(axis=2)

    def slice_at(self, phi: float) -> np.ndarray:
        """Boolean (nx, ny) at the grid orientation nearest ``phi`` rad (thesis fig. 11)."""
        return self.valid[:, :, int(np.argmin(np.abs(self.phi - phi)))]


def _as_poses(pose: Any, what: str = "pose") -> tuple[np.ndarray, tuple[int, ...]]:
    arr = np.asarray(pose, dtype=float)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ConfigError(
            f"{what}: expected [x, y, phi] or an array of shape (..., 3), got shape {arr.shape}"
        )
    batch = arr.shape[:-1]
    return np.ascontiguousarray(arr.reshape(-1, 3)), batch


class Rrr3:
    """Kinematics of a planar 3-RRR robot (see the module docstring for the conventions).

    Parameters
    ----------
    geometry : Rrr3Geometry, optional
        The robot; the thesis's ``udesc`` preset by default.

    Raises
    ------
    ConfigError
        If the home pose is not valid for this geometry (unreachable, singular or out of the
        servo ranges): clamping needs a valid home.
    """

    def __init__(self, geometry: Rrr3Geometry | None = None) -> None:
        self.geometry = geometry if geometry is not None else Rrr3Geometry.preset("udesc")
        self._p = self.geometry.packed()
        self._A = self.geometry.base_points
        self._c = self.geometry.platform_points
        self.home = self.geometry.home
        self._tbuf = np.empty(3)
        self._sbuf = np.empty(3, dtype=np.int64)
        st = self.status(self.home)
        if st != OK:
            raise ConfigError(
                f"rrr3 geometry {self.geometry.name!r}: home pose {self.home.tolist()} is "
                f"{describe_status(int(st))} (fix modes, servo mapping or margins)"
            )

    # -- inverse kinematics -----------------------------------------------------------------
    def solve(self, pose: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inverse kinematics, servo degrees and status in one pass.

        Parameters
        ----------
        pose : array_like (..., 3)
            ``[x, y, phi]``, m and rad, base frame.

        Returns
        -------
        theta : ndarray (..., 3)
            Joint angles, rad (NaN for an unreachable chain).
        servo_deg : ndarray (..., 3) int64
            Servo degrees as the mapping gives them (-1 for an unreachable chain; may lie
            outside the servo range: check ``status``).
        status : ndarray (...) int64
            Status word, 0 when valid (bits UNREACHABLE, TYPE1, TYPE2, SERVO_RANGE).
        """
        flat, batch = _as_poses(pose)
        theta, servo, status = _solve_batch(flat, self._p)
        return theta.reshape(batch + (3,)), servo.reshape(batch + (3,)), status.reshape(batch)

    def inverse(self, pose: Any) -> np.ndarray:
        """Joint angles (rad, (..., 3)) of poses ``[x, y, phi]``; NaN where unreachable.

        Only the existence of a real solution is required here; use :meth:`status` or
        :meth:`reachable` to also refuse singular or servo-invalid poses.
        """
        return self.solve(pose)[0]

    def status(self, pose: Any) -> np.ndarray:
        """Status word of poses (..., 3): 0 when valid, else OR of the reason bits."""
        return self.solve(pose)[2]

    def reachable(self, pose: Any) -> np.ndarray:
        """True where the pose is reachable, outside both singularity margins, servo-valid."""
        return self.status(pose) == OK

    # -- servo mapping ------------------------------------------------------------------------
    @property
    def angle_limits(self) -> np.ndarray:
        """Joint-angle interval per motor allowed by the servo ranges, (3, 2) rad, base frame.

        Row ``i`` is ``(lo, hi)`` with ``lo <= hi``; the interval may extend beyond
        (-pi, pi] (compare angles modulo 2 pi).
        """
        g = self.geometry
        out = np.empty((3, 2))
        for i in range(3):
            ends = g.servo_zero_deg[i] + g.servo_direction[i] * np.array(
                [g.servo_min_deg[i], g.servo_max_deg[i]], dtype=float
            )
            out[i] = np.radians(np.sort(ends))
        return out

    def to_servo_masked(self, angles: Any) -> tuple[np.ndarray, np.ndarray]:
        """Servo degrees of joint angles, with a validity mask instead of an error.

        Parameters
        ----------
        angles : array_like (..., 3)
            Joint angles, rad, base frame.

        Returns
        -------
        servo_deg : ndarray (..., 3) int64
            Integer degrees; -1 where the angle is NaN or its degrees fall outside the range.
        ok : ndarray (..., 3) bool
        """
        g = self.geometry
        th = np.asarray(angles, dtype=float)
        if th.ndim == 0 or th.shape[-1] != 3:
            raise ConfigError(f"angles: expected shape (..., 3), got {th.shape}")
        with np.errstate(invalid="ignore"):
            sd = np.mod(np.asarray(g.servo_direction) * (np.degrees(th) - g.servo_zero_deg), 360.0)
            r = np.floor(sd + 0.5)
            r = np.where(r >= 360.0, r - 360.0, r)
            ok = np.isfinite(r) & (r >= g.servo_min_deg) & (r <= g.servo_max_deg)
        deg = np.where(ok, np.nan_to_num(r, nan=-1.0), -1.0).astype(np.int64)
        return deg, ok

    def to_servo(self, angles: Any) -> np.ndarray:
        """Integer servo degrees (..., 3) of joint angles (rad); refuses rather than clips.

        Raises
        ------
        UnreachablePoseError
            If any angle is NaN or maps outside its servo's ``[min_deg, max_deg]``; the message
            names the first offending motor. Use :meth:`to_servo_masked` for a mask instead.
        """
        deg, ok = self.to_servo_masked(angles)
        if not ok.all():
            th = np.asarray(angles, dtype=float).reshape(-1, 3)
            bad = np.argwhere(~ok.reshape(-1, 3))[0]
            k, i = int(bad[0]), int(bad[1])
            g = self.geometry
            raise UnreachablePoseError(
                f"servo {i + 1}: joint angle {math.degrees(th[k, i]):.2f} deg maps outside "
                f"{g.servo_min_deg[i]}..{g.servo_max_deg[i]} servo degrees (refused, not clipped)"
            )
        return deg

    # -- clamping -----------------------------------------------------------------------------
    def clamp(self, pose: Any, *, n_samples: int = 32, n_bisect: int = 20):
        """Move targets toward home along the straight segment until they are valid.

        Parameters
        ----------
        pose : array_like (..., 3)
            Targets ``[x, y, phi]``, m and rad.
        n_samples, n_bisect : int
            The segment from home to the target is sampled at ``n_samples`` points; the first
            invalid interval is refined by ``n_bisect`` bisection steps. The result is the
            farthest point such that every sample from home to it is valid, so the clamped
            pose never jumps across an unreachable or singular region.

        Returns
        -------
        pose : ndarray (..., 3)
            The valid pose (the target itself when it was valid; home for a non-finite target).
        clamped : ndarray (...) bool
            True where the target was moved.
        """
        flat, batch = _as_poses(pose)
        out, clamped, _ = _clamp_batch(flat, self.home, self._p, int(n_samples), int(n_bisect))
        return out.reshape(batch + (3,)), clamped.reshape(batch)

    def clamp_one(self, x: float, y: float, phi: float) -> tuple[float, float, float, bool]:
        """Scalar fast path of :meth:`clamp` (no array allocation): ``(x, y, phi, clamped)``."""
        cx, cy, cp, cl, _ = _clamp_one(
            x,
            y,
            phi,
            self.home[0],
            self.home[1],
            self.home[2],
            self._p,
            32,
            20,
            self._tbuf,
            self._sbuf,
        )
        return cx, cy, cp, cl

    def solve_one(self, x: float, y: float, phi: float) -> tuple[int, np.ndarray, np.ndarray]:
        """Scalar fast path of :meth:`solve`: ``(status, theta (3,), servo_deg (3,))``.

        The arrays returned are fresh copies.
        """
        theta = np.empty(3)
        servo = np.empty(3, dtype=np.int64)
        st = _solve_one(float(x), float(y), float(phi), self._p, theta, servo)
        return int(st), theta, servo

    # -- geometry of a pose -------------------------------------------------------------------
    def platform_joints(self, pose: Any) -> np.ndarray:
        """Platform joints ``C_i`` of poses, (..., 3, 2), m."""
        P = np.asarray(pose, dtype=float)
        c, s = np.cos(P[..., 2]), np.sin(P[..., 2])
        lx, ly = self._c[:, 0], self._c[:, 1]
        cx = P[..., 0, None] + c[..., None] * lx - s[..., None] * ly
        cy = P[..., 1, None] + s[..., None] * lx + c[..., None] * ly
        return np.stack([cx, cy], axis=-1)

    def joint_points(self, pose: Any, angles: Any | None = None) -> JointPoints:
        """A, B, C of every chain for poses (..., 3); each (..., 3, 2), m.

        ``angles`` (..., 3) rad may be given to skip the inverse kinematics; otherwise the
        working modes of the geometry choose them. Unreachable chains give NaN in ``B``.
        """
        P = np.asarray(pose, dtype=float)
        _as_poses(P)
        th = self.inverse(P) if angles is None else np.asarray(angles, dtype=float)
        C = self.platform_joints(P)
        A = np.broadcast_to(self._A, C.shape).copy()
        a = self.geometry.crank
        B = A + a * np.stack([np.cos(th), np.sin(th)], axis=-1)
        return JointPoints(A, B, C)

    def jacobians(self, pose: Any, angles: Any | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Jx and Jq (each (..., 3, 3)) of eqs. 5.10-5.11: ``Jx xdot = Jq qdot``.

        Rows of Jx: ``[n_ix, n_iy, e_ix n_iy - e_iy n_ix]`` (m, m, m^2), Jq diagonal
        ``u_ix n_iy - u_iy n_ix`` (m^2), with crank ``u_i = B_i - A_i``, rod ``n_i = C_i - B_i``
        and ``e_i = C_i - P``. The inverse-kinematics Jacobian is ``Jq^-1 Jx``.
        """
        P = np.asarray(pose, dtype=float)
        A, B, C = self.joint_points(P, angles)
        u = B - A
        n = C - B
        e = C - P[..., None, :2]
        Jx = np.stack([n[..., 0], n[..., 1], e[..., 0] * n[..., 1] - e[..., 1] * n[..., 0]], -1)
        jq = u[..., 0] * n[..., 1] - u[..., 1] * n[..., 0]
        Jq = jq[..., :, None] * np.eye(3)
        return Jx, Jq

    def singularity(self, pose: Any) -> Singularity:
        """Type I and type II singularity measures of poses (..., 3); see :class:`Singularity`."""
        Jx, Jq = self.jacobians(pose)
        g = self.geometry
        raw = np.abs(np.diagonal(Jq, axis1=-2, axis2=-1))
        with np.errstate(invalid="ignore"):
            det = np.linalg.det(Jx)
        scale2 = g.rod**3 * g.platform_side / _SQRT3
        return Singularity(raw / (g.crank * g.rod), np.abs(det) / scale2, raw, det)

    # -- forward kinematics -------------------------------------------------------------------
    def forward(
        self, angles: Any, guess: Any | None = None, *, tol: float = 1e-16, max_iter: int = 50
    ) -> np.ndarray:
        """Pose (..., 3) from joint angles (..., 3) rad, by Newton's method.

        Parameters
        ----------
        angles : array_like (..., 3)
            Joint angles, rad.
        guess : array_like (..., 3), optional
            Starting pose (home by default); Newton converges to the assembly mode nearest it.
        tol : float
            Convergence on the constraint residual ``max_i | |C_i - B_i|^2 - b^2 |``, m^2.

        Returns
        -------
        ndarray (..., 3)
            The pose; NaN where Newton did not converge (no assembly, or a singular path).
        """
        th = np.asarray(angles, dtype=float)
        if th.ndim == 0 or th.shape[-1] != 3:
            raise ConfigError(f"angles: expected shape (..., 3), got {th.shape}")
        x = np.broadcast_to(self.home if guess is None else np.asarray(guess, float), th.shape)
        x = x.astype(float).copy()
        a, b = self.geometry.crank, self.geometry.rod
        B = self._A + a * np.stack([np.cos(th), np.sin(th)], axis=-1)
        done = np.zeros(th.shape[:-1], dtype=bool)
        for _ in range(max_iter):
            C = self.platform_joints(x)
            n = C - B
            e = C - x[..., None, :2]
            F = np.einsum("...ij,...ij->...i", n, n) - b * b
            done = np.all(np.abs(F) < tol, axis=-1)
            if done.all():
                break
            Jx = np.stack([n[..., 0], n[..., 1], e[..., 0] * n[..., 1] - e[..., 1] * n[..., 0]], -1)
            with np.errstate(all="ignore"):
                det = np.linalg.det(Jx)
                ok = np.abs(det) > 1e-30
                Jsafe = np.where(ok[..., None, None], Jx, np.eye(3))
                dx = np.linalg.solve(2.0 * Jsafe, F[..., None])[..., 0]
            dx = np.where(ok[..., None], dx, 0.0)
            x = np.where(done[..., None], x, x - dx)
        else:
            C = self.platform_joints(x)
            n = C - B
            F = np.einsum("...ij,...ij->...i", n, n) - b * b
            done = np.all(np.abs(F) < tol, axis=-1)
        x[..., 2] = (x[..., 2] + np.pi) % (2 * np.pi) - np.pi
        return np.where(done[..., None] & np.isfinite(x), x, np.nan)

    def forward_all(self, angles: Any, *, n_phi: int = 1440) -> np.ndarray:
        """All real assembly modes for one set of joint angles (3,) rad: poses (k, 3).

        Method: for each of ``n_phi`` orientations, ``C1`` lies on the circle about ``B1`` and
        on the circle about ``B2 - R(phi)(c2 - c1)`` (both radius b): two candidates; the
        residual of chain 3 is tracked along each branch, its sign changes are refined by
        Newton on the full system and duplicates removed. Roots where the residual only
        touches zero (double roots) can be missed; ``n_phi`` bounds the angular resolution.
        """
        th = np.asarray(angles, dtype=float)
        if th.shape != (3,):
            raise ConfigError(f"angles: expected shape (3,), got {th.shape}")
        a, b = self.geometry.crank, self.geometry.rod
        B = self._A + a * np.stack([np.cos(th), np.sin(th)], axis=-1)
        phis = np.linspace(-np.pi, np.pi, n_phi, endpoint=False)
        c, s = np.cos(phis), np.sin(phis)

        def rot(v: np.ndarray) -> np.ndarray:
            return np.stack([c * v[0] - s * v[1], s * v[0] + c * v[1]], axis=-1)

        d21 = rot(self._c[1] - self._c[0])  # (n, 2)
        d31 = rot(self._c[2] - self._c[0])
        O2 = B[1] - d21  # C1 must be at distance b from O2
        D = O2 - B[0]
        dist = np.hypot(D[:, 0], D[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            along = dist / 2  # equal radii: the chord's midpoint
            half = np.sqrt(b * b - along**2)
            ux, uy = D[:, 0] / dist, D[:, 1] / dist
        found = []
        for sign in (1.0, -1.0):
            C1 = np.stack(
                [B[0, 0] + along * ux - sign * half * uy, B[0, 1] + along * uy + sign * half * ux],
                axis=-1,
            )
            C3 = C1 + d31
            g = np.sum((C3 - B[2]) ** 2, axis=-1) - b * b
            P = C1 - rot(self._c[0])
            nxt = np.roll(np.arange(n_phi), -1)
            change = np.isfinite(g) & np.isfinite(g[nxt]) & (np.sign(g) != np.sign(g[nxt]))
            for k in np.flatnonzero(change):
                guess = np.array([P[k, 0], P[k, 1], phis[k]])
                sol = self.forward(th, guess=guess)
                if np.all(np.isfinite(sol)):
                    found.append(sol)
        uniq: list[np.ndarray] = []
        for sol in found:
            if not any(
                np.hypot(*(sol[:2] - u[:2])) < 1e-9
                and abs((sol[2] - u[2] + np.pi) % (2 * np.pi) - np.pi) < 1e-9
                for u in uniq
            ):
                uniq.append(sol)
        return np.array(uniq).reshape(-1, 3)

    # -- workspace ----------------------------------------------------------------------------
    def workspace(
        self,
        nx: int = 100,
        ny: int = 100,
        nphi: int = 73,
        *,
        x_range: tuple[float, float] | None = None,
        y_range: tuple[float, float] | None = None,
        phi_range: tuple[float, float] = (-math.pi, math.pi),
    ) -> PlanarWorkspace:
        """The thesis's triple sweep over x, y and phi (chapter 7), compiled.

        Parameters
        ----------
        nx, ny, nphi : int
            Grid sizes (phi includes both ends of ``phi_range``: 73 gives 5 deg steps on
            -180..180 deg).
        x_range, y_range : (float, float), m, optional
            Default: the bounding box of the base triangle.
        phi_range : (float, float), rad
        """
        L = self.geometry.base_side
        xr = x_range if x_range is not None else (0.0, L)
        yr = y_range if y_range is not None else (0.0, L * _SQRT3 / 2)
        xs = np.linspace(xr[0], xr[1], int(nx))
        ys = np.linspace(yr[0], yr[1], int(ny))
        ps = np.linspace(phi_range[0], phi_range[1], int(nphi))
        return PlanarWorkspace(xs, ys, ps, _status_grid(xs, ys, ps, self._p))

    def inscribed_rectangle(
        self, phi: float = 0.0, *, n: int = 241
    ) -> tuple[float, float, float, float]:
        """Largest axis-aligned rectangle of valid positions at orientation ``phi``.

        Returns ``(x_min, x_max, y_min, y_max)`` in m. Found on an ``n x n`` grid over the base
        triangle's bounding box (largest rectangle of ones in a binary matrix), then shrunk by
        one grid step on every side so that its edges lie inside the valid region.
        """
        L = self.geometry.base_side
        xs = np.linspace(0.0, L, n)
        ys = np.linspace(0.0, L * _SQRT3 / 2, n)
        ok = _status_grid(xs, ys, np.array([float(phi)]), self._p)[:, :, 0] == 0  # (nx, ny)
        best = (0, 0, 0, 0, 0)  # area, i0, i1, j0, j1 (inclusive grid indices)
        heights = [0] * n  # along x: run length of valid cells in y ending at row j
        okl = ok.tolist()
        for j in range(n):
            heights = [h + 1 if okl[i][j] else 0 for i, h in enumerate(heights)]
            stack: list[int] = []
            for i in range(n + 1):
                hcur = heights[i] if i < n else 0
                while stack and heights[stack[-1]] >= hcur:
                    top = stack.pop()
                    left = stack[-1] + 1 if stack else 0
                    area = (i - left) * heights[top]
                    if area > best[0]:
                        best = (area, left, i - 1, j - heights[top] + 1, j)
                stack.append(i)
        _, i0, i1, j0, j1 = best
        if i1 - i0 < 3 or j1 - j0 < 3:
            raise ConfigError(f"no usable workspace rectangle at phi = {phi:g} rad")
        return (xs[i0 + 1], xs[i1 - 1], ys[j0 + 1], ys[j1 - 1])
