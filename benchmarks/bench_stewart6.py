"""6-UPS Stewart platform kinematics figures: single-pose latencies, batch throughput.

The figure issue 14 asks for is one pose through ``inverse`` from Python (the real-time path
calls it, or ``clamp_inverse``, once per tick); the others are for comparison with the 6-RUS
(``bench_rus6.py``, whose timing helpers this script reuses).

Run: .venv/bin/python benchmarks/bench_stewart6.py
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
from bench_rus6 import _latency_us, _pin_one_core

N_BATCH = 1_000_000
N_CALLS = 20_000


def main() -> None:
    print(f"Stewart6 kinematics benchmark ({_pin_one_core()}, numba kernels, no parallelism)")
    t0 = time.perf_counter()
    from motionbase.platform import Stewart6, Stewart6Geometry

    geometry = Stewart6Geometry.preset("seat")
    t1 = time.perf_counter()
    hexapod = Stewart6(geometry)  # checks neutral and finds the park pose: loads kernels
    t2 = time.perf_counter()
    hexapod.warm_up()
    t3 = time.perf_counter()
    print(
        f"import + preset: {1e3 * (t1 - t0):.0f} ms; construction (compile or cache load): "
        f"{1e3 * (t2 - t1):.0f} ms; remaining kernels: {1e3 * (t3 - t2):.0f} ms"
    )

    rng = np.random.default_rng(0)
    lim = np.array([0.15, 0.15, 0.08, 0.15, 0.15, 0.4])
    poses = rng.uniform(-lim, lim, (N_BATCH, 6))
    print(f"batch poses reachable: {100 * np.mean(hexapod.reachable(poses)):.1f} %")
    hexapod.inverse(poses[:1000])
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        lengths = hexapod.inverse(poses)
        best = min(best, time.perf_counter() - t0)
    rate = N_BATCH / best / 1e6
    print(f"batch inverse of {N_BATCH:,} poses: {best * 1e3:.1f} ms, {rate:.2f} M poses/s")
    for name, fn, n in (
        ("reachable", hexapod.reachable, N_BATCH),
        ("clamp", hexapod.clamp, N_BATCH),
        ("forward", hexapod.forward, 100_000),
    ):
        arg = lengths[:n] if name == "forward" else poses[:n]
        fn(arg[:10])
        t0 = time.perf_counter()
        fn(arg)
        dt = time.perf_counter() - t0
        print(f"batch {name:<9} of {n:>9,}: {dt * 1e3:8.1f} ms, {n / dt / 1e6:6.2f} M/s")

    print(f"single-pose latency over {N_CALLS:,} calls (us):     p50     p99    mean")
    pose = np.array([0.05, -0.03, -0.04, 0.1, -0.05, 0.2])
    cases = [
        ("inverse", hexapod.inverse, pose),
        ("inverse, list input", hexapod.inverse, pose.tolist()),
        ("reachable", hexapod.reachable, pose),
        ("clamp, reachable input", hexapod.clamp, pose),
        ("clamp, 3x pose", hexapod.clamp, 3 * pose),
        ("clamp, 1 km / 1000 rad", hexapod.clamp, np.array([1e3, -1e3, 1e3, 1e3, -1e3, 1e3])),
        ("clamp_inverse, 3x pose", hexapod.clamp_inverse, 3 * pose),
        ("forward (Newton from neutral)", hexapod.forward, hexapod.inverse(pose)),
    ]
    for label, fn, arg in cases:
        p50, p99, mean = _latency_us(fn, arg, N_CALLS)
        print(f"  {label:<32} {p50:8.2f} {p99:7.2f} {mean:7.2f}")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process peak RSS: {rss:.0f} MiB")


if __name__ == "__main__":
    # (no options: --help prints what it measures instead of running it)
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    main()
