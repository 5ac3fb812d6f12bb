"""The model-predictive cueing against the robot it drives: its default set on the Stewart
platform (``mpc_seat``), the warning when a pose box exceeds the robot's reach, and the
refusal of robots that lack a pose axis.

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
from motionbase.cli import main
from motionbase.config import read_toml, write_toml
from motionbase.errors import ConfigError
from motionbase.pipeline import Pipeline, PipelineConfig
from motionbase.platform.robot import ROBOTS, load_geometry, robot_spec
from motionbase.washout import mpc
from motionbase.washout.mpc_params import MpcParams, limits_from_robot

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))

import heave3_robot  # noqa: E402
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


# --------------------------------------------------------------------------- the warning
def test_ceart_box_on_the_stewart_platform_warns_once_naming_the_axes(fresh_warnings):
    tuned_ceart = MpcParams.load("tuned_ceart")
    name, geometry = load_geometry("stewart6")
    config = PipelineConfig(robot=name, geometry=geometry, cueing="mpc", cueing_params=tuned_ceart)
    Pipeline(config)
    Pipeline(config)  # (once: the tuner builds many pipelines)
    warned = _reach_warnings(fresh_warnings)
    assert len(warned) == 1 and "\n" not in warned[0]
    beyond = _beyond_reach(tuned_ceart, _robot("stewart6"))
    assert beyond >= {"surge", "heave"}  # (ceart reaches further forward and up)
    for axis in AXES:
        assert (f" {axis} " in warned[0]) == (axis in beyond), axis
    assert "--params seat" in warned[0] and "limits_from_robot" in warned[0]


@pytest.mark.parametrize("platform,preset", [("stewart6", "seat"), ("ceart", "tuned_ceart")])
def test_a_set_made_for_the_platform_does_not_warn(fresh_warnings, platform, preset):
    config = app.load_config(platform=platform, cueing="mpc")
    assert config.cueing_params == MpcParams.load(preset)
    Pipeline(config)
    assert _reach_warnings(fresh_warnings) == []


@pytest.mark.parametrize("scale", [None, 4.0])
def test_the_whole_reach_as_limits_from_robot_writes_it_does_not_warn(
    fresh_warnings, tmp_path, scale
):
    """margin=1: the box is the reach, its 4 significant digits rounded up past it on some
    axes (measured here with robot.reachable): by up to 0.05 mm or mrad on ceart, 0.5 mm on
    a Stewart platform 4 times the seat (a surge reach of 1.2 m), which warned; no reason to
    warn."""
    platform = "ceart"
    if scale is not None:  # the seat's lengths times scale
        seat = _preset_file("stewart6_seat")
        for key in ("base_radius", "platform_radius", "neutral_length", "length_min",
                    "length_max", "park_margin"):  # fmt: skip
            seat[key] *= scale
        platform = str(tmp_path / "big.toml")
        write_toml(platform, seat)
    name, geometry = load_geometry(platform)
    robot = robot_spec(name).make(geometry)
    data = MpcParams.load("tuned_ceart").to_dict()
    data["limits"] = limits_from_robot(robot, margin=1.0)
    full = MpcParams.from_dict(data)
    assert _beyond_reach(full, robot)  # (rounded past the reach)
    Pipeline(PipelineConfig(robot=name, geometry=geometry, cueing="mpc", cueing_params=full))
    assert _reach_warnings(fresh_warnings) == []


def test_a_hand_written_box_past_the_reach_warns_on_the_command_line(tmp_path, capsys, monkeypatch):
    """ceart's own set with a yaw box of 60 deg (ceart's cranks turn it 48.9 deg, as
    robot.reachable says here): one warning line naming yaw and the fix; the flight runs."""
    data = MpcParams.load("tuned_ceart").to_dict()
    data["limits"]["angle_lower_deg"][2] = -60.0
    data["limits"]["angle_upper_deg"][2] = 60.0
    path = tmp_path / "wide_yaw.toml"
    write_toml(path, data)
    robot = _robot("ceart")
    assert not robot.reachable([0, 0, 0, 0, 0, math.radians(60.0)])
    assert robot.reachable([0, 0, 0, 0, 0, math.radians(40.0)])
    monkeypatch.setattr(mpc, "_WARNED", set())
    out = tmp_path / "wide.mcap"
    args = ["fly", "c1723", "--cueing", "mpc", "--params", str(path), "--duration", "1"]
    assert main([*args, "--out", str(out)]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "single-axis reach" in ln]
    assert len(lines) == 1
    assert "wide_yaw.toml" in lines[0] and " yaw -60.0..60.0 deg" in lines[0]
    assert not any(f" {axis} " in lines[0] for axis in AXES[:5])
    assert "limits_from_robot" in lines[0]
    assert out.is_file()


# --------------------------------------------------------------------------- lacking axes
def test_planar_robot_with_mpc_is_one_line_and_exit_2(tmp_path, capsys):
    out = tmp_path / "planar.mcap"
    args = ["fly", "c1723", "--planar", "--cueing", "mpc", "--duration", "1"]
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "does not render heave, roll, pitch" in err
    assert "--cueing classical" in err
    assert not out.exists()


def test_a_plugin_robot_lacking_axes_is_refused_by_name(monkeypatch):
    monkeypatch.setitem(ROBOTS, "heave3", heave3_robot.SPEC)
    name, geometry = load_geometry("heave3")
    config = PipelineConfig(
        robot=name, geometry=geometry, cueing="mpc", cueing_params=MpcParams.load("tuned_ceart")
    )
    with pytest.raises(ConfigError, match=r"does not render surge, sway, yaw; the MPC plans"):
        Pipeline(config)
    # the classical washout still drives it
    Pipeline(app.load_config(platform="heave3"))


def test_tune_of_the_mpc_on_the_seat_starts_from_the_seats_set(tmp_path, capsys, monkeypatch):
    """The tuner leaves an MPC set's limits as they are: on the seat it starts from the set
    made for the seat (it started from ceart's and kept its box), without a reach warning."""
    monkeypatch.setattr(mpc, "_WARNED", set())
    out = tmp_path / "tuned.toml"
    args = ["tune", "--cueing", "mpc", "--platform", "stewart6", "--scripts", "rudder_kick@0:3",
            "--holdout", "none", "--budget", "1", "--workers", "1", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    assert "single-axis reach" not in capsys.readouterr().err
    tuned = MpcParams.from_toml(out)
    assert tuned.to_dict()["limits"] == MpcParams.load("seat").to_dict()["limits"]
    assert "from the parameters seat" in out.read_text()
