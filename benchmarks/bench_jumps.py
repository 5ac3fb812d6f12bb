"""3-RRR far jumps over the whole valid phi = 0 workspace: ticks whose command no pose holds.

Run: python benchmarks/bench_jumps.py [--preset udesc] [--jumps 200] [--seed 0] [--hold S]
     python benchmarks/bench_jumps.py [--preset udesc] --circle R,HZ
     python benchmarks/bench_jumps.py [--preset udesc] --edge

Random valid poses (uniform over the base triangle's box, kept where ``reachable``) are
jumped between in a chain through the real pose-mode pipeline
(:class:`motionbase.commanding.CommandPipeline`, teleop's). Each goal is held until the
robot rests 10 ticks, or for ``--hold`` s (a target that changes mid-motion). The mechanism
is followed independently of the package's kinematics: each tick its pose is carried from
the last one by damped Gauss-Newton on the three rod-length closures
``|C_i(pose) - B_i(theta_i)| = rod`` (the thesis's appendix A.1 joints); a tick whose worst
rod stays more than 1 um off its length is one no pose near the mechanism's holds (the
linkage would bind). Also counted: ticks over the speed or acceleration limit, jumps not at
rest within 8 s. ``--circle``: instead, a target circling home (radius R m, HZ turns a
second) for 6 s, then home for 3 s (a cursor swept round): the same counts, and the mean
distance from the robot's pose to the target after the first 2 s (the lag). ``--edge``:
jumps from home to the last valid pose of rays from home every 3.6 deg, and back, each to
rest.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from motionbase.commanding import Command, CommandPipeline
from motionbase.platform import Rrr3Geometry
from motionbase.platform.rrr3 import Rrr3Robot

# the tests' own rod-length closure (written from the thesis, not the package): one for both
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_teleop_jumps import rod_errors as tick_rod_errors  # noqa: E402

TOL_M = 1e-6


def rod_errors(g: Rrr3Geometry, pose: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``|C_i - B_i| - rod`` (3,), m, of a pose ``[x, y, phi]`` and crank angles (rad)."""
    return tick_rod_errors(g, np.asarray(pose)[None], np.asarray(theta)[None])[0]


def closure(g: Rrr3Geometry, theta: np.ndarray, guess: np.ndarray) -> tuple[np.ndarray, float]:
    """The pose near ``guess`` holding ``theta`` (damped Gauss-Newton), its worst rod error (m)."""
    p, lam = np.array(guess, dtype=float), 1e-9
    for _ in range(100):
        e = rod_errors(g, p, theta)
        if np.abs(e).max() < 1e-13:
            break
        d = 1e-7 * np.eye(3)
        jac = np.stack([rod_errors(g, p + d[k], theta) - rod_errors(g, p - d[k], theta)
                        for k in range(3)], -1) / 2e-7  # fmt: skip
        trial = p - np.linalg.solve(jac.T @ jac + lam * np.eye(3), jac.T @ e)
        if np.abs(rod_errors(g, trial, theta)).max() < np.abs(e).max():
            p, lam = trial, lam * 0.1
        elif (lam := lam * 10) > 1e3:
            break
    return p, float(np.abs(rod_errors(g, p, theta)).max())


def main(
    preset: str, jumps: int, seed: int, hold_s: float | None, circle: str | None, edge: bool
) -> None:
    g = Rrr3Geometry.preset(preset)
    robot = Rrr3Robot(g)
    pipe = CommandPipeline(robot, rate_hz=50.0, mode="poses")
    dt, lim = pipe.dt, robot.limits
    rng = np.random.default_rng(seed)
    goals: list[np.ndarray] = []
    while circle is None and not edge and len(goals) < jumps + 1:
        p = np.array([*rng.uniform([0.0, 0.0], [g.base_side, 0.87 * g.base_side]), 0.0])
        if robot.reachable(p):
            goals.append(p)
    if circle is not None:  # one target a tick, each a "jump" of one tick
        radius, hz = (float(v) for v in circle.split(","))
        home, tc = np.asarray(robot.neutral_pose), np.arange(int(6.0 / dt)) * dt
        turn = 2 * np.pi * hz * tc
        goals = [*(home + radius * np.stack([np.cos(turn), np.sin(turn), 0 * tc], -1))]
        goals = [home, *goals, *[home] * int(3.0 / dt)]
        hold_s, jumps = dt, len(goals) - 1
    if edge:  # from home to the last valid pose of rays from home, and back, at rest each
        home, goals = np.asarray(robot.neutral_pose), []
        for a in np.radians(np.arange(0.0, 360.0, 3.6)):
            ray = home + np.array([np.cos(a), np.sin(a), 0.0]) * np.arange(1e-5, 0.3, 1e-5)[:, None]
            ok = np.asarray(robot.reachable(ray), dtype=bool)
            if ok[0] and not ok.all():
                goals += [home, ray[int(np.argmin(ok)) - 1]]
        jumps = len(goals) - 1
    lags = []
    mech, q_prev, v_prev = np.array(robot.park_pose), np.array(robot.park_angles), np.zeros(3)
    bad_jumps = bad_ticks = over = late = ticks = 0
    worst, t, t0 = 0.0, 0.0, time.perf_counter()
    for j, goal in enumerate(goals):  # (goal 0: the jump from home, not counted)
        bad, rest = False, 0
        for k in range(int(8.0 / dt)):
            t += dt
            q = np.asarray(pipe.step(Command(t, goal)).angles, dtype=float)
            ticks += 1
            v = (q - q_prev) / dt
            fast = np.abs(v) > lim.max_speed * (1 + 1e-9)
            over += bool((fast | (np.abs(v - v_prev) > lim.max_accel * dt * (1 + 1e-6))).any())
            q_prev, v_prev = q, v
            pose, err = closure(g, q, mech)
            if err > TOL_M:
                bad, worst, bad_ticks = True, max(worst, err), bad_ticks + (j > 0)
            else:
                mech = pose
            if circle is not None and 2.0 <= t <= 6.0:
                lags.append(np.linalg.norm(mech[:2] - goal[:2]))
            rest = 0 if pipe.speed.any() else rest + 1
            if rest == 10 or hold_s is not None and k + 1 >= round(hold_s / dt):
                break
        bad_jumps += bad and j > 0
        late += rest < 10 and hold_s is None and j > 0
    print(
        f"{preset}: {bad_jumps}/{jumps} jumps with ticks no pose holds ({bad_ticks} ticks, "
        f"worst rod {worst * 1e3:.3f} mm), {late} not at rest in 8 s, {over} ticks over a "
        f"limit; {ticks} ticks, {1e6 * (time.perf_counter() - t0) / ticks:.0f} us a tick "
        f"(with the check)" + (f"; mean lag {1e3 * np.mean(lags):.1f} mm" if lags else "")
    )


if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--preset", default="udesc")
    ap.add_argument("--jumps", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hold", type=float, default=None, help="hold each goal this long, s")
    ap.add_argument("--circle", default=None, metavar="R,HZ", help="a circling target instead")
    ap.add_argument("--edge", action="store_true", help="jumps from home to the valid poses' edge")
    a = ap.parse_args()
    main(a.preset, a.jumps, a.seed, a.hold, a.circle, a.edge)
