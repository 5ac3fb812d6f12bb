"""Model-predictive cueing (issue 16): solve time, and quality against the classical washout.

(a) Time: the real-time mode (no preview) at 100 Hz with the preset's horizon, on one core:
    the MPC alone (``MpcCueing.advance``, the platform's robot bound) over the tuning manoeuvres
    resampled to 100 Hz; per tick the linearisation of the actuator rows + OSQP update
    (a numeric refactorisation) + solve time (``info.solve_time_s``) and the whole tick,
    p50 / p99 / max, iterations, fallbacks. Goal: solve p99 <= 5 ms, no fallback.
(b) Quality: on the tuning manoeuvre set of issue 15 (:data:`DEFAULT_MANOEUVRES`) and the
    held-out set, the whole pipeline (``Pipeline.run_batch``) and the tuner's scoring
    (:func:`motionbase.tuning.score_motion`: perceived specific-force and angular-velocity
    RMSE, false cues, clamping, crank use) for the default classical washout, the tuned one
    (the platform's: ``washout_tuned_ceart`` on ceart, ``washout_tuned_seat`` on stewart6),
    the MPC in real-time mode and the MPC in preview mode (the
    recorded future of the reference). Goals: specific-force RMSE at least 15 % below the
    tuned classical, angular RMSE no worse, false cues no more frequent.

Run: .venv/bin/python benchmarks/bench_mpc.py [--mpc tuned_ceart|ceart|seat|PATH]
     [--platform ceart|stewart6|PRESET|PATH] (the MPC set: the platform's default unless given)
     [--preview-mpc PRESET|PATH] [--no-preview] [--no-quality] [--no-time]
"""

from __future__ import annotations

import argparse
import math
import os
import platform as _platform
import time

import numpy as np

from motionbase import tuning
from motionbase.app import tuned_preset
from motionbase.io.manoeuvres import DEFAULT_HOLDOUT, DEFAULT_MANOEUVRES, load_spec
from motionbase.pipeline import PipelineConfig
from motionbase.platform.robot import load_geometry
from motionbase.report import robot_reach
from motionbase.washout import WashoutParams
from motionbase.washout.cueing import cueing_spec
from motionbase.washout.mpc import MpcCueing
from motionbase.washout.mpc_params import MpcParams


def score_set(problem: tuning.TuningProblem, cueing: str, params, preview: bool = False):
    """The tuner's score of one cueing over the problem's manoeuvres (no sizing term: the
    sizing rule is the classical washout's) and the ticks the MPC fell back on."""
    scores = []
    fallbacks = 0
    for m in problem.manoeuvres:
        config = PipelineConfig(
            robot=problem.robot,
            geometry=problem.geometry,
            cueing=cueing,
            cueing_params=params,
            rate_hz=m.rate_hz,
        )
        run = tuning.run_chain(config, m, preview)
        fallbacks += run.cueing_counts.get("fallbacks", 0)
        scores.append(
            tuning.score_motion(m, run, problem.reach, 9.80665, problem.weights, problem.cranks)
        )
    return tuning.SetScore(tuple(scores), np.zeros(6), problem.weights), fallbacks


def _resample(m, rate_hz: float):
    t = np.arange(m.t[0], m.t[-1], 1.0 / rate_hz)
    f = np.column_stack([np.interp(t, m.t, m.specific_force[:, i]) for i in range(3)])
    w = np.column_stack([np.interp(t, m.t, m.angular_velocity[:, i]) for i in range(3)])
    return f, w


def time_realtime(
    params: MpcParams, manoeuvres, robot: str, geometry, rate_hz: float = 100.0
) -> dict:
    """Per-tick solve and tick times of the real-time mode at ``rate_hz``, the robot bound
    (its actuator rows re-linearised and OSQP refactorised every tick)."""
    cue = MpcCueing(params, 1.0 / rate_hz)
    cue.bind_robot(
        PipelineConfig(robot=robot, geometry=geometry, cueing_params=params).make_robot()
    )
    solve, tick, iters = [], [], []
    out = np.empty(6)
    u = np.empty(6)
    for m in manoeuvres:
        f, w = _resample(m, rate_hz)
        cue.reset()
        for k in range(len(f)):
            u[:3], u[3:] = f[k], w[k]
            t0 = time.perf_counter()
            cue.advance(u, out)
            tick.append(time.perf_counter() - t0)
            solve.append(cue.info.solve_time_s)
            iters.append(cue.info.iterations)
    return {
        "ticks": len(tick),
        "solve": np.array(solve),
        "tick": np.array(tick),
        "iters": np.array(iters),
        "fallbacks": cue.counts["fallbacks"],
        "horizon_s": float(cue.model.h.sum()),
    }


def _pct(x: float, y: float) -> str:
    return f"{100 * (y - x) / x:+.1f} %" if x else "n/a"


def _table(title: str, rows: list[tuple[str, tuning.SetScore, int | None]]) -> None:
    print(title)
    names = [s.name for s in rows[0][1].scores]
    wide = max(26, 2 + max(map(len, names)))  # (a longer name ran into the cueing's)
    print(
        f"  {'manoeuvre':<{wide}}{'cueing':<18}{'sf RMSE x / y / z (sum) m/s^2':>36}"
        f"{'ang deg/s':>11}{'false %':>9}{'clamp %':>9}{'limited %':>11}{'crank %':>9}"
    )
    for i, name in enumerate([*names, "total (mean)"]):
        for label, s, _fb in rows:
            sc = s if i == len(names) else s.scores[i]
            axes = (
                np.mean([x.rmse_specific_force for x in s.scores], 0)
                if i == len(names)
                else sc.rmse_specific_force
            )
            crank = 100 * (
                max(float(np.max(x.crank_usage)) for x in s.scores)
                if i == len(names)
                else float(np.max(sc.crank_usage))
            )
            print(
                f"  {name:<{wide}}{label:<18}"
                f"{' / '.join(f'{v:.2f}' for v in axes):>26} ({sc.error_specific_force:6.3f})"
                f"{math.degrees(sc.error_angular_velocity):>11.2f}"
                f"{100 * sc.false_cue_share:>9.1f}{100 * sc.clamped:>9.2f}"
                f"{100 * sc.limited:>11.2f}{crank:>9.0f}"
            )
            name = ""
    for label, s, fb in rows:
        extra = f", fallback ticks {fb}" if fb is not None else ""
        print(
            f"  {label}: sf {s.error_specific_force:.3f}, ang "
            f"{math.degrees(s.error_angular_velocity):.2f} deg/s, false cues "
            f"{100 * s.false_cue_share:.1f} %, clamp {100 * s.clamped:.2f} %, clamp or rate "
            f"limit {100 * s.limited:.2f} %{extra}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mpc", help="MPC preset or TOML path (default: the platform's)")
    ap.add_argument("--platform", default="ceart")
    ap.add_argument(
        "--preview-mpc",
        metavar="PRESET",
        help="MPC preset or TOML path of the preview-mode rows (default: --mpc's)",
    )
    ap.add_argument("--no-preview", action="store_true", help="skip the preview-mode rows")
    ap.add_argument("--no-quality", action="store_true")
    ap.add_argument("--no-time", action="store_true")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    print(
        f"{time.strftime('%Y-%m-%d')}, {_platform.node()}, {_platform.processor() or ''} "
        f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; one core pinned"
    )
    robot, geometry = load_geometry(args.platform)
    spec = cueing_spec("mpc")
    mpc_name = args.mpc or tuned_preset(spec, robot, geometry) or spec.default_preset
    mpc = MpcParams.load(mpc_name)
    preview_mpc = MpcParams.load(args.preview_mpc) if args.preview_mpc else mpc
    tuned_name = tuned_preset(cueing_spec("classical"), robot, geometry) or "default"
    print(
        f"platform: {args.platform} ({robot}); MPC: {mpc_name}; preview rows: "
        f"{args.preview_mpc or mpc_name}; classical tuned: {tuned_name}"
    )
    tuning_set = tuple(load_spec(s) for s in DEFAULT_MANOEUVRES)

    if not args.no_time:
        r = time_realtime(mpc, tuning_set, robot, geometry)
        s, tk = 1e3 * r["solve"], 1e3 * r["tick"]
        print(
            f"\n(a) real-time mode, 100 Hz, horizon {r['horizon_s']:.2f} s ({mpc.steps} steps), "
            f"{r['ticks']} ticks over the tuning manoeuvres resampled to 100 Hz"
        )
        print(
            f"  solve (OSQP update + solve): p50 {np.median(s):.3f} ms, p99 "
            f"{np.percentile(s, 99):.3f} ms, max {s.max():.3f} ms; whole tick p50 "
            f"{np.median(tk):.3f} ms, p99 {np.percentile(tk, 99):.3f} ms; iterations p50 "
            f"{np.median(r['iters']):.0f}, p99 {np.percentile(r['iters'], 99):.0f}, "
            f"max {r['iters'].max()}; fallback ticks {r['fallbacks']}"
        )
        ok = np.percentile(s, 99) <= 5.0 and r["fallbacks"] == 0
        print(f"  goal (solve p99 <= 5 ms, no fallback): {'met' if ok else 'NOT met'}")

    if args.no_quality:
        return
    reach = robot_reach(
        PipelineConfig(robot=robot, geometry=geometry, cueing_params=None).make_robot()
    )
    default = WashoutParams.preset("default")
    tuned = WashoutParams.preset(tuned_name)
    for title, manoeuvres in (
        ("(b) tuning set", tuning_set),
        ("(c) held out", tuple(load_spec(s) for s in DEFAULT_HOLDOUT)),
    ):
        problem = tuning.TuningProblem(geometry, manoeuvres, reach, robot=robot)
        rows = [
            ("classical default", score_set(problem, "classical", default)[0], None),
            ("classical tuned", score_set(problem, "classical", tuned)[0], None),
        ]
        t0 = time.perf_counter()
        s_rt, fb_rt = score_set(problem, "mpc", mpc)
        t_rt = time.perf_counter() - t0
        rows.append(("mpc real-time", s_rt, fb_rt))
        if not args.no_preview:
            s_pv, fb_pv = score_set(problem, "mpc", preview_mpc, preview=True)
            rows.append(("mpc preview", s_pv, fb_pv))
        print()
        _table(f"{title} ({t_rt:.1f} s for the real-time MPC runs)", rows)
        base = rows[1][1]
        for label, s, _ in rows[2:]:
            goals = (
                (
                    "sf RMSE -15 % vs tuned",
                    s.error_specific_force <= 0.85 * base.error_specific_force,
                ),
                ("angular no worse", s.error_angular_velocity <= base.error_angular_velocity),
                ("false cues no more", s.false_cue_share <= base.false_cue_share),
            )
            sf = _pct(base.error_specific_force, s.error_specific_force)
            print(
                f"  {label} vs classical tuned: sf {sf}, "
                f"angular {_pct(base.error_angular_velocity, s.error_angular_velocity)}; "
                + ", ".join(f"{n}: {'met' if ok else 'NOT met'}" for n, ok in goals)
            )


if __name__ == "__main__":
    main()
