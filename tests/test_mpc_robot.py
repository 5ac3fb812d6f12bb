"""The model-predictive cueing against the robot it drives: its default set on the Stewart
platform (``mpc_seat``).

Expectations are independent of the code under test: reach from ``robot.reachable`` on
poses along each axis, the stroke and crank ranges from the geometry files' own numbers.
"""

from __future__ import annotations

import logging
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from motionbase import app
from motionbase.config import read_toml
from motionbase.pipeline import Pipeline
from motionbase.platform.robot import load_geometry, robot_spec
from motionbase.washout import mpc
from motionbase.washout.mpc_params import MpcParams

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))

from test_mpc import _inputs  # noqa: E402

AXES = ("surge", "sway", "heave", "roll", "pitch", "yaw")
DT = 0.01


def _robot(platform: str):
    name, geometry = load_geometry(platform)
    return robot_spec(name).make(geometry)


def _preset_file(name: str) -> dict:
    return read_toml(Path(app.__file__).parent / "presets" / f"{name}.toml")


def _along_axes(bounds: np.ndarray, k: int, count: int = 400) -> np.ndarray:
    """Poses from neutral out to ``bounds[k]`` on axis ``k`` alone, (count, 6)."""
    poses = np.zeros((count, 6))
    poses[:, k] = np.linspace(0.0, bounds[k], count)
    return poses


def _beyond_reach(params: MpcParams, robot) -> set[str]:
    """The axes where the box leaves the robot's reach on the way out from neutral."""
    out = set()
    for bounds in (params.pose_lower, params.pose_upper):
        for k in range(6):
            if not np.asarray(robot.reachable(_along_axes(bounds, k))).all():
                out.add(AXES[k])
    return out


@pytest.fixture
def fresh_warnings(monkeypatch, caplog):
    """Each reach warning is given once a process: start this test with none given."""
    monkeypatch.setattr(mpc, "_WARNED", set())
    caplog.set_level(logging.WARNING, logger="motionbase")
    return caplog


def _reach_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "single-axis reach" in r.getMessage()]


# --------------------------------------------------------------------------- the seat's set
def test_stewart6_default_mpc_set_is_the_seats_and_lies_within_its_reach():
    seat = app.load_config(platform="stewart6", cueing="mpc").cueing_params
    assert seat == MpcParams.load("seat")
    robot = _robot("stewart6")
    # the whole box, axis by axis, reachable from neutral...
    assert _beyond_reach(seat, robot) == set()
    # ...and most of the reach used: 15 % further out is beyond it on every axis both ways
    # (limits_from_robot takes 90 %)
    for bounds in (seat.pose_lower, seat.pose_upper):
        for k in range(6):
            far = np.zeros(6)
            far[k] = 1.15 * bounds[k]
            assert not robot.reachable(far), (AXES[k], bounds[k])
    # the ceart's default is unchanged
    assert app.load_config(cueing="mpc").cueing_params == MpcParams.load("tuned_ceart")


def test_seat_violation_weight_means_on_the_stroke_what_ceart_s_means_on_the_cranks():
    """A slack of one share of the actuator range costs the same on both platforms: the
    weight (per actuator unit^2) scales with the inverse square of the range, taken here from
    the geometry files (legs length_min..length_max, cranks angle_min..angle_max)."""
    seat_file, ceart_file = _preset_file("stewart6_seat"), _preset_file("rus6_ceart")
    stroke = seat_file["length_max"] - seat_file["length_min"]  # m
    cranks = math.radians(ceart_file["angle_max_deg"] - ceart_file["angle_min_deg"])  # rad
    seat, ceart = MpcParams.load("seat"), MpcParams.load("tuned_ceart")
    assert seat.violation_weight * stroke**2 == pytest.approx(
        ceart.violation_weight * cranks**2, rel=1e-3
    )
    # everything else but the limits, the fallback washout and the description as in
    # tuned_ceart
    a, b = seat.to_dict(), ceart.to_dict()
    for d in (a, b):
        del d["limits"], d["robot"]["violation_weight"], d["solver"]["fallback"]
        del d["description"]
    assert a == b
    assert seat.fallback == "tuned_seat"


def test_a_short_stewart6_mpc_flight_stays_within_the_robot():
    """A hard flight (force steps past the reference limits, rate pulses on every axis) on
    the Stewart platform's default MPC: every pose the cueing asks is reachable (the clamp
    never acts), every leg length and speed within its limits."""
    config = app.load_config(platform="stewart6", cueing="mpc", rate_hz=1 / DT)
    pipeline = Pipeline(config)
    u = _inputs(800)
    result = pipeline.run_batch(np.arange(len(u)) * DT, u[:, :3], u[:, 3:])
    robot = pipeline.robot
    assert np.asarray(robot.reachable(result.cue_poses)).all()
    assert not result.clamped.any()
    p = config.cueing_params
    assert (result.cue_poses >= p.pose_lower - 1e-9).all()
    assert (result.cue_poses <= p.pose_upper + 1e-9).all()
    seat = _preset_file("stewart6_seat")  # (one number for every leg)
    q = result.commands
    assert np.isfinite(q).all()
    assert (q >= seat["length_min"]).all() and (q <= seat["length_max"]).all()
    assert (np.abs(np.diff(q, axis=0)) / DT <= seat["max_speed"] * (1 + 1e-9)).all()
    assert np.ptp(q) > 0.05  # (and it moved: legs over more than 5 cm)
