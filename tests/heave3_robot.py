"""A robot plug-in written outside motionbase, as a user would: a 3-DOF heave/pitch/roll
platform on three vertical linear actuators (``tests/test_robot_plugin.py`` drives it).

The robot
    A plate on three vertical actuators: one at the front centre, two at the rear corners.
    A central guide holds the plate's centre over the base (no surge, sway or yaw), and
    ball joints at the actuators' tops let it tilt. The actuators are taken as vertical
    (their lean at a tilt is neglected), so an actuator's length is the neutral length
    plus the height of its attachment point on the tilted plate::

        L_i = neutral_length - (z + (R a_i)_z)        (FRD: z down, heave up is -z)
            = neutral_length - z + sin(pitch) a_x - cos(pitch) sin(roll) a_y

    ``a_i`` is the attachment point in the plate frame, whose origin is the centroid of the
    three attachment points: the front one at ``(2 d / 3, 0)``, the rear ones at
    ``(-d / 3, -/+ w / 2)``, ``d`` the wheelbase (front actuator to the rear pair's line),
    ``w`` the rear track.

Robot pose and cue pose
    The robot pose is ``[z, roll, pitch]`` (m, rad). The cue's surge, sway and yaw are
    dropped: the plate cannot move that way. The cue pose it realises keeps the cue's values
    on those axes (the 3-RRR's convention for the axes it lacks), so the cueing is not told
    it was clamped there and does not wind up: a sustained surge or sway still reaches the
    rider through the washout's tilt coordination (pitch and roll), its onset does not.

Geometry TOML
    ``kind = "heave3"``, ``wheelbase``, ``rear_track``, ``neutral_length``, ``length_min``,
    ``length_max`` (m), ``max_speed`` (m/s), ``max_accel`` (m/s^2), optional ``park_margin``
    (m, default 0.01) and ``name``; every field checked by :meth:`Heave3Geometry.from_dict`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numba
import numpy as np

from motionbase.config import (
    as_float,
    check_file_kind,
    check_keys,
    read_toml,
    resolve_preset_or_path,
)
from motionbase.errors import ConfigError
from motionbase.platform.robot import ROBOTS, SOLVE_SIGNATURE, Robot, RobotSpec
from motionbase.safety import ActuatorLimits

#: The folder of this robot's geometry presets (``heave3_<preset>.toml``).
PRESETS = str(Path(__file__).parent / "data")
_FIELDS = ("wheelbase", "rear_track", "neutral_length", "length_min", "length_max")
_FIELDS += ("max_speed", "max_accel")


@dataclass(frozen=True)
class Heave3Geometry:
    """Dimensions (m) and actuator limits of the 3-actuator platform."""

    wheelbase: float
    rear_track: float
    neutral_length: float
    length_min: float
    length_max: float
    max_speed: float
    max_accel: float
    park_margin: float = 0.01
    name: str = "custom"

    @property
    def attachments(self) -> np.ndarray:
        """Attachment points ``(3, 2)``, ``(a_x, a_y)`` in the plate frame, m: front,
        rear left, rear right."""
        d, w = self.wheelbase, self.rear_track
        return np.array([[2 * d / 3, 0.0], [-d / 3, -w / 2], [-d / 3, w / 2]])

    @property
    def platform_origin(self) -> np.ndarray:
        """The plate frame's origin at neutral in base axes, m (the log's ``/tf``): the
        actuators' feet are at z = 0, the plate ``neutral_length`` above them."""
        return np.array([0.0, 0.0, -self.neutral_length])

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Any, source: str = "heave3 geometry") -> Heave3Geometry:
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected a table of geometry fields, got {data!r}")
        check_file_kind(source, data, "heave3")  # a washout file, a 6-RUS geometry...
        check_keys(source, data, {*_FIELDS, "park_margin", "name", "kind"}, required=_FIELDS)
        kw: dict[str, Any] = {
            f: as_float(source, f, data[f], min_value=0.0, strict_min=True, unit="")
            for f in _FIELDS
        }
        if "park_margin" in data:
            kw["park_margin"] = as_float(source, "park_margin", data["park_margin"], min_value=0.0)
        name = data.get("name", "custom")
        if not isinstance(name, str):
            raise ConfigError(f"{source}: field 'name': expected a string, got {name!r}")
        if not kw["length_min"] < kw["neutral_length"] < kw["length_max"]:
            raise ConfigError(
                f"{source}: field 'neutral_length': must lie between length_min and length_max"
            )
        if not kw["length_min"] + kw.get("park_margin", 0.01) < kw["neutral_length"]:
            raise ConfigError(f"{source}: field 'park_margin': parks above the neutral length")
        return cls(name=name, **kw)

    @classmethod
    def from_toml(cls, path: str | Path) -> Heave3Geometry:
        return cls.from_dict(read_toml(path), source=str(path))

    @classmethod
    def preset(cls, name: str) -> Heave3Geometry:
        """A preset (``"garage"``: ``data/heave3_garage.toml``) or a TOML path."""
        return cls.from_toml(resolve_preset_or_path("heave3", name, PRESETS))


# --------------------------------------------------------------------------- kernels
# Packed parameters: neutral length, then per actuator a_x, a_y, length min, length max.
_L0, _AX, _AY, _LO, _HI = 0, 1, 4, 7, 10


@numba.njit(cache=False)
def _lengths(p, G, out):
    """Lengths of robot pose ``p = [z, roll, pitch]`` into ``out`` (3,)."""
    sp, cp, sr = math.sin(p[2]), math.cos(p[2]), math.sin(p[1])
    for i in range(3):
        out[i] = G[_L0] - p[0] + sp * G[_AX + i] - cp * sr * G[_AY + i]


@numba.njit(cache=False)
def _ok(p, G, q):
    """Reachable: finite, tilts within +-90 deg (one pose per set of lengths), every length
    within its stroke."""
    if not (abs(p[1]) < 0.5 * math.pi and abs(p[2]) < 0.5 * math.pi and math.isfinite(p[0])):
        return False
    _lengths(p, G, q)
    for i in range(3):
        if not (G[_LO + i] <= q[i] <= G[_HI + i]):
            return False
    return True


@numba.njit(cache=False)
def _clamp(p, G, out, q):
    """The whole pose scaled toward neutral (zero) until reachable; True when it moved."""
    if _ok(p, G, q):
        out[:] = p
        return False
    if not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])):
        out[:] = 0.0
        _lengths(out, G, q)
        return True
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        for j in range(3):
            out[j] = mid * p[j]
        if _ok(out, G, q):
            lo = mid
        else:
            hi = mid
    for j in range(3):
        out[j] = lo * p[j]
    _lengths(out, G, q)
    return True


@numba.njit(SOLVE_SIGNATURE, cache=False)
def solve(G, target, cue_out, pose_out, q_out):
    """The robot's kernel: cue -> [z, roll, pitch], clamp, lengths."""
    p = np.empty(3)
    p[0], p[1], p[2] = target[2], target[3], target[4]
    clamped = _clamp(p, G, pose_out, q_out)
    for j in range(6):
        cue_out[j] = target[j]
    cue_out[2], cue_out[3], cue_out[4] = pose_out[0], pose_out[1], pose_out[2]
    return clamped


# --------------------------------------------------------------------------- the robot
class Heave3Robot(Robot):
    """The 3-actuator heave/pitch/roll platform as a pipeline robot."""

    name = "heave3"
    actuator_unit = "m"
    solve_kernel = staticmethod(solve)

    def __init__(self, geometry: Heave3Geometry) -> None:
        self.geometry = geometry
        self.kin = self
        self.n = 3
        g = geometry
        a = g.attachments
        self.limits = ActuatorLimits.broadcast(
            3, g.length_min, g.length_max, g.max_speed, g.max_accel
        )
        self.kernel_params = np.concatenate(
            [[g.neutral_length], a[:, 0], a[:, 1], self.limits.lower, self.limits.upper]
        )
        self.neutral_pose = np.zeros(3)
        park_z = g.neutral_length - (g.length_min + g.park_margin)  # below neutral: z > 0
        self.park_pose = np.array([park_z, 0.0, 0.0])
        self.park_cue = np.array([0.0, 0.0, park_z, 0.0, 0.0, 0.0])
        self.park_angles = np.full(3, g.length_min + g.park_margin)

    def _rows(self, pose):
        p = np.asarray(pose, dtype=float)
        return np.ascontiguousarray(p.reshape(-1, 3)), p.shape[:-1]

    def inverse(self, pose):
        rows, lead = self._rows(pose)
        out = np.empty_like(rows)
        for k in range(len(rows)):
            _lengths(rows[k], self.kernel_params, out[k])
        return out.reshape(lead + (3,))

    def reachable(self, pose):
        rows, lead = self._rows(pose)
        q = np.empty(3)
        ok = np.array([_ok(r, self.kernel_params, q) for r in rows])
        return bool(ok[0]) if lead == () else ok.reshape(lead)

    def clamp(self, pose):
        rows, lead = self._rows(pose)
        out = np.empty_like(rows)
        q = np.empty(3)
        moved = np.array([_clamp(r, self.kernel_params, out[k], q) for k, r in enumerate(rows)])
        return out.reshape(lead + (3,)), bool(moved[0]) if lead == () else moved.reshape(lead)

    def forward(self, q, guess=None):
        """Closed form: the rear pair's difference gives the roll, the front against the
        rear pair's mean the pitch (``guess`` is not needed)."""
        q = np.asarray(q, dtype=float)
        a = self.geometry.attachments
        h = self.geometry.neutral_length - q  # z - sin(pitch) a_x + cos(pitch) sin(roll) a_y
        hf, hl, hr = h[..., 0], h[..., 1], h[..., 2]
        with np.errstate(invalid="ignore"):
            sp = -(hf - 0.5 * (hl + hr)) / (a[0, 0] - a[1, 0])
            pitch = np.arcsin(sp)
            roll = np.arcsin((hr - hl) / (a[2, 1] - a[1, 1]) / np.cos(pitch))
        z = hf + sp * a[0, 0]
        return np.stack([z, roll, pitch], axis=-1)

    def pose_from_cue(self, cue):
        return np.asarray(cue, dtype=float)[..., [2, 3, 4]]

    def cue_from_pose(self, pose, cue):
        out = np.array(cue, dtype=float)
        out[..., [2, 3, 4]] = pose
        return out

    def joint_points(self, pose):
        """Base points (actuators' feet) and plate points (their tops), (3, 3) each."""
        p = np.asarray(pose, dtype=float)
        a = self.geometry.attachments
        q = self.inverse(p)
        feet = np.column_stack([a, np.zeros(3)])
        tops = np.column_stack([a, -q])
        return feet, tops


#: The registry entry: the robot's name (also its presets' prefix and its files' ``kind``),
#: its classes as ``"module:Class"`` (imported on use), its default preset and where its
#: presets are.
SPEC = RobotSpec(
    "heave3",
    "heave3_robot:Heave3Robot",
    "heave3_robot:Heave3Geometry",
    "garage",
    description="3-actuator heave/pitch/roll platform",
    preset_dir=PRESETS,
)


def register() -> None:
    """Register the robot: what a user's script does before ``motionbase.cli.main()``."""
    ROBOTS["heave3"] = SPEC
