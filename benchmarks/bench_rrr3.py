"""3-RRR speed: one teleop cycle and the full-workspace sweep.

Run: python benchmarks/bench_rrr3.py

Teleop cycle = calibration (pixel -> m) + clamp (validity check; a full clamp when the target
is outside) + inverse kinematics + servo mapping + protocol encoding, for one cursor sample.
Budget 20 us. Then the whole loop, :func:`motionbase.teleop.run_teleop` as fast as possible on
a CSV of cursor points (adds the safety stage, the pose-segment pacing of far jumps and the
serial sink on ``loop://``): wall time per tick. Sweep: 100 x 100 x 73 poses (x, y over the
base triangle's bounding box, phi -180..180 deg), budget 1 s.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from motionbase.io.servo_protocol import encode
from motionbase.platform import CursorCalibration, Rrr3, Rrr3Geometry


def cycle(rrr3: Rrr3, cal: CursorCalibration, u: float, v: float) -> bytes:
    x, y = cal.map_one(u, v)
    cx, cy, cp, _ = rrr3.clamp_one(x, y, 0.0)
    st, theta, servo = rrr3.solve_one(cx, cy, cp)
    return encode(servo.tolist())


def percentiles(fn, n: int) -> tuple[float, float, float]:
    ts = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter_ns()
        fn(i)
        ts[i] = time.perf_counter_ns() - t0
    return tuple(np.percentile(ts, [50, 90, 99]) / 1e3)


def loop_per_tick(rrr3: Rrr3, cal: CursorCalibration, n: int = 5000) -> None:
    """The real teleop loop, unpaced, on n cursor points 20 ms apart (a slow, smooth trace)."""
    import logging
    import tempfile
    import warnings
    from pathlib import Path

    from motionbase.io.cursor_input import FileCursor
    from motionbase.io.serial_link import ServoSerialSink
    from motionbase.teleop import run_teleop

    logging.getLogger("motionbase").setLevel(logging.ERROR)
    t = np.arange(n) * 0.02
    u = 655 + 300 * np.sin(0.5 * t)
    v = 357 + 150 * np.sin(0.7 * t)
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "trace.csv"
        rows = [f"{a:.3f},{b:.1f},{c:.1f}\n" for a, b, c in zip(t, u, v, strict=True)]
        for label, points in (("warm-up", 200), ("measured", n)):
            csv.write_text("".join(rows[:points]))
            sink = ServoSerialSink("loop://", ready_timeout_s=0.0, rate_hz=1e6)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # loop:// has no board to say "Rolling"
                sink.open()
            t0 = time.perf_counter()
            stats = run_teleop(FileCursor(csv), rrr3, cal, sink=sink, rate_hz=50, realtime=False)
            wall = time.perf_counter() - t0
            sink.close()
            if label == "measured":
                print(
                    f"teleop loop (run_teleop, unpaced, serial on loop://): "
                    f"{1e6 * wall / stats.ticks:.1f} us per tick over {stats.ticks} ticks"
                )


def main() -> None:
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc"))
    cal = CursorCalibration.default(rrr3, 1310, 715)
    rng = np.random.default_rng(0)
    inside = rng.uniform([0, 0], [1310, 715], (20000, 2))
    outside = rng.uniform([-3000, -3000], [4000, 4000], (20000, 2))
    # for the outside targets the same (linear) map over pixels beyond the screen: off its
    # pixels' box a calibration holds the box's edge, which is inside the workspace
    x0, x1, y0, y1 = rrr3.inscribed_rectangle(0.0)
    px = np.array([[u, v] for u in (-3000, 500, 4000) for v in (-3000, 500, 4000)], float)
    wide = CursorCalibration.fit(
        px, np.stack([x0 + px[:, 0] / 1310 * (x1 - x0), y1 - px[:, 1] / 715 * (y1 - y0)], -1)
    )
    for pts, c in ((inside, cal), (outside, wide)):
        for i in range(200):
            cycle(rrr3, c, *pts[i])
    p = percentiles(lambda i: cycle(rrr3, cal, *inside[i]), len(inside))
    print(
        f"teleop cycle, target inside (no clamp):  median {p[0]:.1f} us, p90 {p[1]:.1f}, "
        f"p99 {p[2]:.1f}  (budget 20 us)"
    )
    p = percentiles(lambda i: cycle(rrr3, wide, *outside[i]), len(outside))
    print(
        f"teleop cycle, target outside (clamped):  median {p[0]:.1f} us, p90 {p[1]:.1f}, "
        f"p99 {p[2]:.1f}"
    )
    loop_per_tick(rrr3, cal)
    rrr3.workspace(10, 10, 5)  # compile
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        ws = rrr3.workspace(100, 100, 73)
        best = min(best, time.perf_counter() - t0)
    print(
        f"workspace sweep 100 x 100 x 73 = {ws.status.size} poses: best of 5 {best * 1e3:.0f} ms "
        f"({best / ws.status.size * 1e9:.0f} ns/pose; budget 1 s), {int(ws.valid.sum())} valid"
    )
    poses = np.stack(np.meshgrid(ws.x, ws.y, ws.phi, indexing="ij"), -1).reshape(-1, 3)
    t0 = time.perf_counter()
    rrr3.inverse(poses)
    print(
        f"batch inverse of the same {len(poses)} poses: {(time.perf_counter() - t0) * 1e3:.0f} ms"
    )


if __name__ == "__main__":
    # (no options: --help prints what it measures instead of running it)
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    main()
