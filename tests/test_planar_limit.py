"""The planar 3-RRR's commands always realise a pose its kinematics accept.

Near a chain's type I singularity (its workspace's edge) a servo must turn ever faster for
the same motion of the platform. Limited each alone, that servo lagged while the others
followed, then overshot the clamped pose: the servo angles sent made poses the robot
refuses, a chain straightened and its elbow flipped (a 3 m/s^2 sway at 0.3 Hz; the
Concorde's take-off run). Here the commands are checked as the robot would take them:
the pose they make is found by closing the three chains (Newton, from the pose before, as
the mechanism moves), from the thesis's geometry alone (appendix A.1), and each chain's
crank-rod sine and the platform's type II measure must stay within the geometry's margins,
each elbow on its side; the commands themselves within the servos' speed and acceleration.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from motionbase import stages
from motionbase.app import fly, load_config
from motionbase.io.mcap_source import read_messages, read_metadata
from motionbase.pipeline import Pipeline
from motionbase.platform.rrr3_geometry import Rrr3Geometry

G = 9.80665


def _joints(g: Rrr3Geometry, pose: np.ndarray) -> np.ndarray:
    """Platform joints C1..C3 (3, 2) of ``[x, y, phi]`` (thesis appendix A.1)."""
    x, y, phi = pose
    r = g.platform_side / math.sqrt(3)
    c1 = np.array([x - r * math.cos(math.pi / 6 + phi), y - r * math.sin(math.pi / 6 + phi)])
    h = g.platform_side
    return np.array(
        [c1, c1 + h * np.array([math.cos(phi), math.sin(phi)])]
        + [c1 + h * np.array([math.cos(phi + math.pi / 3), math.sin(phi + math.pi / 3)])]
    )


def realised_poses(g: Rrr3Geometry, angles: np.ndarray, start: np.ndarray) -> dict:
    """The poses the crank angles (N, 3) make, each closed by Newton from the one before
    (``start`` first), and per tick the smallest crank-rod sine, the type II measure and
    each chain's elbow side (the sign of crank x rod)."""
    L, a, b, h = g.base_side, g.crank, g.rod, g.platform_side
    base = np.array([[0.0, 0.0], [L, 0.0], [L / 2, L * math.sqrt(3) / 2]])
    pose = np.array(start, dtype=float)
    out = {"pose": [], "type1": [], "type2": [], "side": []}
    for th in angles:
        tips = base + a * np.column_stack([np.cos(th), np.sin(th)])

        def residual(p, tips=tips):
            return np.sum((_joints(g, p) - tips) ** 2, axis=1) - b * b

        for _ in range(60):
            r = residual(pose)
            if np.max(np.abs(r)) < 1e-15:
                break
            jac = np.column_stack(
                [(residual(pose + e) - residual(pose - e)) / 2e-9 for e in np.eye(3) * 1e-9]
            )
            pose = pose - np.linalg.solve(jac, r)
        assert np.max(np.abs(residual(pose))) < 1e-13, f"no pose closes the chains at {th}"
        c = _joints(g, pose)
        crank, rod = tips - base, c - tips
        cross = crank[:, 0] * rod[:, 1] - crank[:, 1] * rod[:, 0]
        e = c - pose[:2]
        jx = np.column_stack([rod[:, 0], rod[:, 1], e[:, 0] * rod[:, 1] - e[:, 1] * rod[:, 0]])
        out["pose"].append(pose.copy())
        out["type1"].append(np.min(np.abs(cross)) / (a * b))
        out["type2"].append(abs(np.linalg.det(jx)) / (b**3 * h / math.sqrt(3)))
        out["side"].append(np.sign(cross))
    return {k: np.array(v) for k, v in out.items()}


def check_commands(g: Rrr3Geometry, angles: np.ndarray, park: np.ndarray, dt: float) -> None:
    """Assert every command realises a valid pose and keeps the servo limits."""
    home = np.array([g.base_side / 2, g.base_side * math.sqrt(3) / 6, 0.0])
    got = realised_poses(g, angles, home)
    bad = np.flatnonzero((got["type1"] < g.type1_margin) | (got["type2"] < g.type2_margin))
    assert bad.size == 0, (
        f"{bad.size} ticks realise refused poses, first at tick {bad[0]}: crank-rod sine "
        f"{got['type1'][bad[0]]:.3f} (margin {g.type1_margin}), pose {got['pose'][bad[0]]}"
    )
    assert (got["side"] == got["side"][0]).all(), "an elbow flipped"
    v = np.diff(np.vstack([park, angles]), axis=0) / dt
    acc = np.diff(np.vstack([np.zeros(3), v]), axis=0) / dt
    assert np.abs(v).max() <= g.max_speed * (1 + 1e-9)
    assert np.abs(acc).max() <= g.max_accel * (1 + 1e-6)


@pytest.mark.parametrize("amplitude, hz", [(3.0, 0.3), (20.0, 0.3)])
def test_a_sway_into_the_workspace_edge_realises_only_valid_poses(amplitude, hz):
    """A 3 m/s^2 sway at 0.3 Hz drives the cue into chain 3's type I edge at speed: the
    per-servo limiter took that chain within 0.002 of straight (53 ticks refused)."""
    config = load_config(planar=True)
    n = int(20.0 / config.dt)
    t = np.arange(1, n + 1) * config.dt
    f = np.zeros((n, 3))
    f[:, 2] = -G
    f[:, 1] = amplitude * np.sin(2 * math.pi * hz * t)
    pipeline = Pipeline(config)
    out = pipeline.run_batch(t, f, np.zeros((n, 3)), np.zeros((n, 3)), np.ones(n, bool))
    assert out.clamped.any() and out.limited.any()  # the cue reached the edge, the limits acted
    check_commands(pipeline.robot.geometry, out.commands, pipeline.robot.park_angles, config.dt)


def test_the_concorde_take_off_run_realises_only_valid_poses(tmp_path):
    """The real JSBSim's Concorde take-off run through ``fly --planar`` (41 ticks refused,
    chain 2 within 0.012 of straight and its elbow flipped for about 0.5 s): the log's
    commands, closed from the log's own geometry."""
    out = tmp_path / "concorde.mcap"
    fly("Concorde_runway_test", planar=True, out=out, progress=False)
    msgs = read_messages(out, skip={"/platform/scene"})
    config = read_metadata(out)["pipeline_config"]
    g = Rrr3Geometry.from_dict(config["geometry"])
    angles = np.array([m["angles"] for m in msgs["/planar/actuators"]])
    dt = 1.0 / config["pipeline"]["rate_hz"]
    park = angles[0]  # the run starts at park
    check_commands(g, angles, park, dt)


def test_after_a_fallback_the_path_stage_resumes_and_poses_stay_valid():
    """A 1 Hz cue beyond the workspace's edge, reversing at speed (the cue itself, through
    the robot's side of the tick): where the path stage found no point the limiter's own
    command was sent and the state's cue was left stale, so no later tick found one either
    (5788 of 6000 ticks per servo) and a chain left its assembly 5 ticks after the first."""
    config = load_config(planar=True)
    pipeline = Pipeline(config)
    P, S = pipeline.params, pipeline.state
    S[0]["phase"], S[0]["blend"] = stages.RUNNING, 1.0
    target, cue_out, pose, wanted = np.empty(6), np.empty(6), np.empty(3), np.empty(3)
    angles, bits = np.empty((3000, 3)), np.empty(3000, dtype=int)
    for k in range(3000):
        t = k * config.dt
        cue = np.array([0.15 * math.sin(4.84 * t), 0.5 * math.sin(6.28 * t), 0, 0, 0, 0])
        cue[5] = 0.6 * math.sin(8.17 * t)
        bits[k] = stages.after_cueing(
            P, S, pipeline._solve, pipeline._G, cue, target, cue_out, pose, wanted, angles[k]
        )
    assert (bits & stages.PATH).any()  # the edge was met at speed
    check_commands(pipeline.robot.geometry, angles, pipeline.robot.park_angles, config.dt)
