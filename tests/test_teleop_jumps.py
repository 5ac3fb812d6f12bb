"""Far jumps of the 3-RRR over its whole reachable workspace: every command a pose holds.

A review found jumps (teleop targets out of a tick's reach, the way home) whose crank
angles no pose of the mechanism could take, off teleop's default screen rectangle on the
thesis's robot: udesc's phi = 0 workspace is not convex (a band near a type II singularity
runs across it and a pocket lies beyond), and a straight pose path left it. Here random
valid poses are jumped between in a chain, through the real pose-mode pipeline.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from motionbase.commanding import Command, CommandPipeline
from motionbase.platform import Rrr3Geometry
from motionbase.platform.rrr3 import Rrr3Robot

RATE_HZ = 50.0
DT = 1.0 / RATE_HZ
#: Rod-length tolerance, m. A command that is the inverse kinematics of a pose (or whose
#: pose the forward kinematics solved) closes every rod to about 1e-15 m; the commands
#: without a pose that the review found missed by 5e-6 to 2.5e-3 m. (The servos' own
#: resolution, 1 deg of a 44 mm crank, is 0.8 mm: not what is asked here.)
ROD_TOL = 1e-9


def rod_errors(geometry, poses: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """|C_i - B_i| - rod for each tick and chain, m, from the geometry (the thesis's
    appendix A.1 joints, written here independently of the package)."""
    side, crank, rod, h = (geometry.base_side, geometry.crank, geometry.rod,
                           geometry.platform_side)  # fmt: skip
    base = np.array([[0.0, 0.0], [side, 0.0], [side / 2, side * math.sqrt(3) / 2]])
    x, y, phi = poses.T
    r = h / math.sqrt(3)
    c1 = np.stack([x - r * np.cos(math.pi / 6 + phi), y - r * np.sin(math.pi / 6 + phi)], -1)
    joints = [c1] + [c1 + h * np.stack([np.cos(phi + a), np.sin(phi + a)], -1)
                     for a in (0.0, math.pi / 3)]  # fmt: skip
    tips = base + crank * np.stack([np.cos(angles), np.sin(angles)], -1)
    return np.linalg.norm(np.stack(joints, 1) - tips, axis=-1) - rod


def seen_from(robot, centre: np.ndarray, pose: np.ndarray, n: int = 2000) -> bool:
    """Every point of the straight segment centre -> pose (n samples) is a valid pose."""
    return bool(robot.reachable(centre + np.linspace(0, 1, n)[:, None] * (pose - centre)).all())


def assert_rods_and_limits(robot, poses: list, angles: list) -> None:
    """Every tick's reported pose holds its commanded angles (each rod at its length), and
    the commands, from rest at park to rest at the last, keep the speed and acceleration
    limits."""
    geometry = robot.geometry
    worst = np.abs(rod_errors(geometry, np.array(poses), np.array(angles))).max()
    assert worst < ROD_TOL, f"a rod {worst * 1e3:.4f} mm off its length"
    park = np.asarray(robot.park_angles)  # at rest there before; the servos hold the last
    q = np.vstack([park, park, *angles, angles[-1]])
    v = np.diff(q, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    assert np.abs(v).max() <= geometry.max_speed * (1 + 1e-9)
    assert np.abs(a).max() <= geometry.max_accel * (1 + 1e-6)


@pytest.mark.parametrize("preset", ["udesc", "udesc_symmetric"])
def test_random_far_jumps_over_the_whole_workspace_keep_every_rod_and_the_limits(preset):
    """200 jumps between random valid phi = 0 poses anywhere in the robot's workspace (not
    only the screen rectangle), each from rest to rest. Every tick the reported pose holds
    the commanded angles (each rod at its length), the commands keep the speed and
    acceleration limits, and the robot comes to rest within 5 s: at the goal, or, for a goal
    behind invalid poses seen from home (udesc's pocket beyond its singular band, which no
    path of valid poses reaches), on the straight line from home toward it, nearer home."""
    robot = Rrr3Robot(Rrr3Geometry.preset(preset))
    geometry, home = robot.geometry, np.asarray(robot.neutral_pose)
    pipe = CommandPipeline(robot, rate_hz=RATE_HZ, mode="poses")
    rng = np.random.default_rng(7)
    side = geometry.base_side
    goals = [p for p in rng.uniform([0, 0, 0], [side, side, 0], (4000, 3)) if robot.reachable(p)]
    poses, angles, t = [], [], 0.0
    behind = 0
    for goal in goals[:200]:
        rest = 0
        for _ in range(int(5.0 / DT)):
            t += DT
            out = pipe.step(Command(t, goal))
            poses.append(out.platform_pose)
            angles.append(out.angles)
            rest = 0 if pipe.speed.any() else rest + 1
            if rest == 10:  # (a way via neutral rests there for a tick)
                break
        assert rest == 10, f"not at rest 5 s after the jump to {goal}"
        end = out.platform_pose
        if seen_from(robot, home, goal):
            np.testing.assert_allclose(end, goal, atol=1e-12)
        else:
            behind += 1
            along = np.dot(end - home, goal - home) / np.dot(goal - home, goal - home)
            assert 0.0 <= along < 1.0 and robot.reachable(end)
            np.testing.assert_allclose(end, home + along * (goal - home), atol=1e-9)
    assert_rods_and_limits(robot, poses, angles)
    assert (behind > 10) == (preset == "udesc")  # the pocket was jumped to, on udesc


def test_a_target_behind_the_band_is_clamped_toward_home_or_refused():
    """udesc: a valid pose whose straight line from home crosses invalid ones (the pocket
    below the band near a type II singularity). With the clamp the robot goes to where
    that line first leaves the valid poses and rests there; without it the target is
    refused and the robot stays home."""
    robot = Rrr3Robot(Rrr3Geometry.preset("udesc"))
    home = np.asarray(robot.neutral_pose)
    goal = next(
        p
        for p in np.random.default_rng(3).uniform([0.08, 0.03, 0], [0.18, 0.07, 0], (2000, 3))
        if robot.reachable(p) and not seen_from(robot, home, p)
    )
    first_bad = next(
        f for f in np.linspace(0, 1, 2001) if not robot.reachable(home + f * (goal - home))
    )
    for clamp in (True, False):
        pipe = CommandPipeline(robot, rate_hz=RATE_HZ, mode="poses", clamp=clamp)
        poses = [pipe.step(Command(k * DT, goal)).platform_pose for k in range(int(3.0 / DT))]
        end = poses[-1]
        assert not pipe.speed.any()
        if clamp:
            along = np.dot(end - home, goal - home) / np.dot(goal - home, goal - home)
            np.testing.assert_allclose(end, home + along * (goal - home), atol=1e-9)
            assert first_bad - 1e-3 < along < first_bad and robot.reachable(end)
        else:
            np.testing.assert_array_equal(np.array(poses), np.broadcast_to(home, (len(poses), 3)))
            assert pipe.health.unsafe_commands == len(poses)


def test_a_target_jittering_at_the_edge_of_udescs_pocket_is_held_there_not_via_home():
    """A gaze resting on udesc's pocket: its target, 0.1 mm of jitter about one point, is
    clamped to where home's line of sight leaves the valid poses, each tick to a slightly
    other point of that edge, between which the straight path grazes invalid poses. Each
    such move, a tick's reach, was routed via home: the robot went home and back some 4
    times a second, never staying. It stays at the edge, every command a pose."""
    robot = Rrr3Robot(Rrr3Geometry.preset("udesc"))
    home = np.asarray(robot.neutral_pose)
    goal = next(
        p
        for p in np.random.default_rng(3).uniform([0.08, 0.03, 0], [0.18, 0.07, 0], (2000, 3))
        if robot.reachable(p) and not seen_from(robot, home, p)
    )
    edge = home + next(  # where home's line of sight toward the goal leaves the valid poses
        f for f in np.linspace(0, 1, 2001) if not robot.reachable(home + f * (goal - home))
    ) * (goal - home)
    pipe = CommandPipeline(robot, rate_hz=RATE_HZ, mode="poses")
    jitter = np.random.default_rng(1).normal(0.0, 1e-4, (int(4.0 / DT), 2))
    outs = [pipe.step(Command(k * DT, goal + [*d, 0.0])) for k, d in enumerate(jitter)]
    poses = np.array([o.platform_pose for o in outs])
    off_edge = np.linalg.norm(poses[:, :2] - edge[:2], axis=1)
    arrived = int(np.argmax(off_edge < 3e-4))  # (the edge is 2.5 mm from home)
    assert arrived > 0 and off_edge[arrived:].max() < 3e-4, off_edge[arrived:].max()
    angles = np.array([o.angles for o in outs])
    assert np.abs(rod_errors(robot.geometry, poses, angles)).max() < ROD_TOL


def test_targets_that_change_while_the_robot_moves_keep_every_rod_and_the_limits():
    """udesc, 60 random valid phi = 0 targets anywhere in its workspace, a new one every
    0.3 s, so that most come while the robot is moving fast toward the last (the turn at
    speed asked the actuators for more than their acceleration: the limiter trimmed each
    one apart and the rods were forced, up to 7 mm, in about one jump in three), then home.
    Every tick the reported pose holds the commanded angles, the limits hold, and the robot
    is at rest at home within 5 s of the last change."""
    robot = Rrr3Robot(Rrr3Geometry.preset("udesc"))
    g, home = robot.geometry, np.asarray(robot.neutral_pose)
    pipe = CommandPipeline(robot, rate_hz=RATE_HZ, mode="poses")
    rng = np.random.default_rng(5)
    box = rng.uniform([0, 0, 0], [g.base_side, 0.87 * g.base_side, 0], (400, 3))
    goals = [p for p in box if robot.reachable(p)][:60]
    targets = [goal for goal in goals for _ in range(int(0.3 / DT))] + [home] * int(5.0 / DT)
    outs = [pipe.step(Command(k * DT, x)) for k, x in enumerate(targets)]
    assert_rods_and_limits(robot, [o.platform_pose for o in outs], [o.angles for o in outs])
    assert not pipe.speed.any()
    np.testing.assert_array_equal(outs[-1].platform_pose, home)


def test_a_target_circling_fast_keeps_every_rod_and_the_limits():
    """udesc, a target sweeping a 2 cm circle about home once a second (a cursor swept
    round, faster than the robot can follow, through the band below home, where the targets
    are clamped): each tick the target moved, and the turn toward it was trimmed by the
    limiter, axis by axis (rods forced up to 21 mm). Every tick holds, within the limits,
    and the robot follows the circle, then rests at home within 3 s."""
    robot = Rrr3Robot(Rrr3Geometry.preset("udesc"))
    home = np.asarray(robot.neutral_pose)
    pipe = CommandPipeline(robot, rate_hz=RATE_HZ, mode="poses")
    t = np.arange(int(4.0 / DT)) * DT
    circle = home + 0.02 * np.stack([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t), 0 * t], -1)
    targets = [*circle, *[home] * int(3.0 / DT)]
    outs = [pipe.step(Command(k * DT, x)) for k, x in enumerate(targets)]
    poses = np.array([o.platform_pose for o in outs])
    assert_rods_and_limits(robot, poses, [o.angles for o in outs])
    d = poses[50 : len(t), :2] - home[:2]  # round about home, as the target
    assert 0.015 < np.linalg.norm(d, axis=1).max() < 0.025
    assert set(np.floor(np.arctan2(d[:, 1], d[:, 0]) / (np.pi / 2))) == {-2, -1, 0, 1}
    assert not pipe.speed.any()
    np.testing.assert_array_equal(poses[-1], home)


def test_jumps_to_the_edge_of_the_valid_poses_keep_every_rod_and_the_limits():
    """udesc, from home to the last valid pose of rays from home every 3.6 deg (the edge of
    its phi = 0 workspace: a type I singularity, or the band), and back, each to rest. Near
    the edge an actuator's path bends sharply (a crank turns back while another speeds up):
    taken at the planned speed, the plan and its braking were both trimmed by the limiter,
    and the commands went past the edge (4 of 100 jumps, rods forced up to 2.4 mm). Each
    goal is reached, but one whose crank lies past its limit (a sliver at the top edge,
    which the pipeline holds: the robot stays home)."""
    robot = Rrr3Robot(Rrr3Geometry.preset("udesc"))
    home, lim = np.asarray(robot.neutral_pose), robot.limits
    pipe = CommandPipeline(robot, rate_hz=RATE_HZ, mode="poses")
    poses, angles, t = [], [], 0.0
    for a in np.radians(np.arange(0.0, 360.0, 3.6)):
        ray = home + np.array([np.cos(a), np.sin(a), 0.0]) * np.arange(1e-5, 0.3, 1e-5)[:, None]
        valid = np.asarray(robot.reachable(ray), dtype=bool)
        for goal in (ray[int(np.argmin(valid)) - 1], home):
            rest = 0
            while rest < 10:
                t += DT
                out = pipe.step(Command(t, goal))
                poses.append(out.platform_pose)
                angles.append(out.angles)
                rest = 0 if pipe.speed.any() else rest + 1
                assert t < 1000.0
            q = robot.inverse(goal)  # a goal with a crank past its limit is held
            held = not (lim.lower <= q).all() & (q <= lim.upper).all()
            np.testing.assert_allclose(out.platform_pose, home if held else goal, atol=1e-12)
    assert_rods_and_limits(robot, poses, angles)


@pytest.mark.parametrize("stop", ["stop", "stale"])
def test_braking_at_speed_on_a_stop_or_stale_input_keeps_every_rod(stop):
    """udesc, 40 runs: a far jump, then a new target while the robot moves fast, then a stop
    (or the input going stale) a few ticks later. The braking to rest kept every actuator on
    one straight line in actuator space (coordinated, within the limits), which is no pose
    path: 4 of the 40 forced a rod by 0.1 mm. Every tick holds, within the limits."""
    robot = Rrr3Robot(Rrr3Geometry.preset("udesc"))
    g = robot.geometry
    rng = np.random.default_rng(3)
    box = rng.uniform([0, 0, 0], [g.base_side, 0.87 * g.base_side, 0], (3000, 3))
    goals = [p for p in box if robot.reachable(p)]
    for run in range(40):
        pipe = CommandPipeline(robot, rate_hz=RATE_HZ, mode="poses")
        targets = [goals[2 * run]] * 40 + [goals[2 * run + 1]] * int(rng.integers(3, 12))
        outs = [pipe.step(Command(k * DT, x)) for k, x in enumerate(targets)]
        if stop == "stop":
            pipe.stop()
        for k in range(len(targets), len(targets) + int(3.0 / DT)):
            outs.append(pipe.step(Command(k * DT, targets[-1]), fresh=stop == "stop"))
        assert not pipe.speed.any()
        assert_rods_and_limits(robot, [o.platform_pose for o in outs], [o.angles for o in outs])
