"""The tuner (issue 15): how long a tuning run takes, and how much better the tuned cueing is.

(a) Time: one evaluation (the whole chain over the five default manoeuvres, then the
    perception models) in this process, split into the chain (``Pipeline.step`` per tick)
    and the scoring; then a whole ``motionbase tune`` run of ``--budget`` evaluations
    (default 200) on ``--workers`` local processes (default: one per processor), start-up,
    manoeuvre loading and held-out scoring included. Goal: 200 evaluations in under 10
    minutes on the 2-core test machine.
(b) Quality: the tuned parameters (the file that run wrote, or ``--tuned FILE``) against
    the default washout (the SIMONA set scaled to the platform), per manoeuvre and in
    total (the mean over the manoeuvres), on the tuning set and the held-out one:
    perceived specific-force RMSE (per axis and their sum), perceived angular-velocity
    RMSE (sum of the three axes), false cues, clamping, the largest crank angle as a share
    of the way from neutral to its limit (``crank %``). Goals on the tuning set: total
    specific-force RMSE -25 %, angular no worse, no more clamping.

``--start PRESET|FILE`` tunes from another washout (default: the default washout);
``--profile ground|air`` tunes that flight-phase profile of it (``tune --profile``: the
manoeuvres run with their flight phase, through the profiled cueing's per-tick path).

Run: .venv/bin/python benchmarks/bench_cueing.py [--budget 200] [--seed 0] [--workers K]
     [--platform ceart] [--start PRESET] [--profile ground|air] [--tuned FILE.toml]
     [--out FILE.toml]
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from motionbase import app, tuning
from motionbase.io.executors import default_workers
from motionbase.io.manoeuvres import DEFAULT_HOLDOUT, DEFAULT_MANOEUVRES, load_spec
from motionbase.platform.robot import load_geometry, robot_spec
from motionbase.report import robot_reach
from motionbase.washout import WashoutParams

GOAL_S = 600.0


def _time_one_evaluation(problem: tuning.TuningProblem, params: WashoutParams) -> None:
    problem.evaluate(params)  # numba caches loaded, everything warm
    chain, score, total = [], [], []
    for _ in range(3):
        t0 = time.perf_counter()
        runs = [(m, tuning.run_chain(problem.config(params, m), m)) for m in problem.manoeuvres]
        t1 = time.perf_counter()
        for m, run in runs:
            tuning.score_motion(m, run, problem.reach, params.gravity)
        t2 = time.perf_counter()
        chain.append(t1 - t0)
        score.append(t2 - t1)
        total.append(t2 - t0)
    ticks = sum(len(m) for m in problem.manoeuvres)
    c, s, e = (statistics.median(x) for x in (chain, score, total))
    print(
        f"one evaluation, this process: {e:.3f} s for {ticks} ticks "
        f"({len(problem.manoeuvres)} manoeuvres): chain {c:.3f} s "
        f"({1e6 * c / ticks:.1f} us/tick, {ticks / c / 1e6:.3f} M samples/s), "
        f"scoring {s:.3f} s (medians of 3)"
    )
    cores = default_workers()
    per_eval_budget = GOAL_S * cores / 200
    print(
        f"  200 evaluations in {GOAL_S / 60:.0f} min on {cores} cores allow "
        f"{per_eval_budget:.1f} s per evaluation: the chain needs "
        f"{ticks / max(per_eval_budget - s, 1e-9) / 1e6:.4f} M samples/s at least"
    )


def _rows(title: str, before: tuning.SetScore, after: tuning.SetScore) -> None:
    print(title)
    head = (
        f"  {'manoeuvre':<31}{'sf RMSE x, y, z (sum) m/s^2':>40}"
        f"{'ang RMSE deg/s':>16}{'false cues %':>14}{'clamped %':>12}{'crank %':>10}"
    )
    print(head)

    def line(label: str, s, per_axis: bool) -> str:
        scores = [s] if per_axis else s.scores
        crank = 100 * max(float(np.max(x.crank_usage)) for x in scores)
        axes = (
            " ".join(f"{v:5.2f}" for v in s.rmse_specific_force)
            if per_axis
            else " ".join(
                f"{v:5.2f}" for v in np.mean([x.rmse_specific_force for x in s.scores], 0)
            )
        )
        return (
            f"    {label:<29}{axes:>26} ({s.error_specific_force:6.3f})"
            f"{math.degrees(s.error_angular_velocity):>14.2f}"
            f"{100 * s.false_cue_share:>14.1f}{100 * s.limited:>12.2f}{crank:>10.0f}"
        )

    for b, a in zip(before.scores, after.scores, strict=True):
        print(f"  {b.name}")
        print(line("default", b, True))
        print(line("tuned", a, True))
    print(f"  total (mean of {len(before.scores)})")
    print(line("default", before, False))
    print(line("tuned", after, False))

    def change(x: float, y: float) -> str:
        return f"{100 * (y - x) / x:+.1f} %" if x else "n/a"

    sf = change(before.error_specific_force, after.error_specific_force)
    ang = change(before.error_angular_velocity, after.error_angular_velocity)
    xy_b = np.mean([x.rmse_specific_force[:2].sum() for x in before.scores])
    xy_a = np.mean([x.rmse_specific_force[:2].sum() for x in after.scores])
    print(
        f"  change: specific force {sf} (x and y alone {change(xy_b, xy_a)}), angular {ang}, "
        f"false cues {100 * before.false_cue_share:.1f} -> {100 * after.false_cue_share:.1f} %, "
        f"clamped {100 * before.limited:.2f} -> {100 * after.limited:.2f} %, cost "
        f"{change(before.cost, after.cost)}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--platform", default="ceart", help="a 6-DOF platform, as tune takes it")
    ap.add_argument("--start", default="default", help="washout to tune from (preset or file)")
    ap.add_argument("--profile", help="tune this flight-phase profile of the start (ground, air)")
    ap.add_argument("--tuned", help="score this washout file instead of tuning one")
    ap.add_argument("--out", help="keep the tuned file here (default: a temporary file)")
    args = ap.parse_args()

    robot, geometry = load_geometry(args.platform)
    reach = robot_reach(robot_spec(robot).make(geometry))
    print(
        f"platform {args.platform}: reach (m, deg) lower "
        + " ".join(f"{v:.3f}" for v in np.concatenate([reach[0, :3], np.degrees(reach[0, 3:])]))
        + ", upper "
        + " ".join(f"{v:.3f}" for v in np.concatenate([reach[1, :3], np.degrees(reach[1, 3:])]))
    )
    default = WashoutParams.preset("default")
    start = WashoutParams.load(args.start)
    tuning_set = tuple(load_spec(s) for s in DEFAULT_MANOEUVRES)
    held = tuple(load_spec(s) for s in DEFAULT_HOLDOUT)
    problem = tuning.TuningProblem(geometry, tuning_set, reach, robot=robot)
    held_problem = tuning.TuningProblem(geometry, held, reach, robot=robot)

    print("\n(a) time")
    _time_one_evaluation(problem, start)
    with tempfile.TemporaryDirectory() as tmp:
        if args.tuned:
            tuned = WashoutParams.load(args.tuned)
            print(f"tuning run skipped: scoring {args.tuned}")
        else:
            out = Path(args.out) if args.out else Path(tmp) / "tuned.toml"
            workers = args.workers or default_workers()
            t0 = time.perf_counter()
            result = app.tune(
                out=out,
                platform=args.platform,
                washout=args.start,
                budget=args.budget,
                seed=args.seed,
                workers=workers,
                progress=False,
                profile=args.profile,
            )
            wall = time.perf_counter() - t0
            verdict = "goal met" if wall < GOAL_S else "goal NOT met"
            profile = f" --profile {args.profile}" if args.profile else ""
            print(
                f"motionbase tune --washout {args.start}{profile} --budget {args.budget} "
                f"--seed {args.seed} --workers {workers}: "
                f"{wall:.1f} s wall ({wall / args.budget:.2f} s per evaluation, everything "
                f"included), {result.result.generations} generations; {verdict} "
                f"(< {GOAL_S:.0f} s)"
            )
            tuned = WashoutParams.from_toml(out)

    print("\n(b) quality: the tuned parameters against the default washout")
    before, after = problem.evaluate(default), problem.evaluate(tuned)
    if args.start != "default":
        print(
            f"the start set {args.start}: cost {problem.evaluate(start).cost:.4f} "
            f"(default {before.cost:.4f}, tuned {after.cost:.4f})"
        )
    _rows("tuning set", before, after)
    _rows("held out (not tuned on)", held_problem.evaluate(default), held_problem.evaluate(tuned))
    goals = [
        (
            "total specific-force RMSE -25 %",
            after.error_specific_force <= 0.75 * before.error_specific_force,
        ),
        (
            "angular-velocity RMSE no worse",
            after.error_angular_velocity <= before.error_angular_velocity,
        ),
        ("no more clamping", after.limited <= before.limited),
    ]
    for name, ok in goals:
        print(f"goal: {name}: {'met' if ok else 'NOT met'}")


if __name__ == "__main__":
    main()
