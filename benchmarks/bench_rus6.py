"""6-RUS kinematics figures: batch inverse throughput and memory, single-pose latencies.

Targets (issue 2): batch inverse of 1,000,000 poses at >= 2,000,000 poses/s on one core;
one pose through ``inverse`` from Python <= 5 us; ``clamp`` of one pose <= 50 us.

Run: python benchmarks/bench_rus6.py
"""

from __future__ import annotations

import argparse
import os
import resource
import time
import tracemalloc

import numpy as np

N_BATCH = 1_000_000
N_CALLS = 20_000


def _pin_one_core() -> str:
    if hasattr(os, "sched_setaffinity"):
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return f"pinned to CPU {cpu}"
    return "not pinned"


def _latency_us(fn, arg, n: int = N_CALLS) -> tuple[float, float, float]:
    for _ in range(200):
        fn(arg)
    t = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        t0 = clock()
        fn(arg)
        t[i] = clock() - t0
    t /= 1e3
    return float(np.percentile(t, 50)), float(np.percentile(t, 99)), float(t.mean())


def main() -> None:
    print(f"6-RUS kinematics benchmark ({_pin_one_core()}, numba kernels, no parallelism)")
    t0 = time.perf_counter()
    from motionbase.platform import Rus6, Rus6Geometry

    rus6 = Rus6(Rus6Geometry.preset("ceart"))
    t1 = time.perf_counter()
    rus6.inverse(np.zeros(6))
    t2 = time.perf_counter()
    rus6.warm_up()
    t3 = time.perf_counter()
    print(
        f"import + preset: {1e3 * (t1 - t0):.0f} ms; first inverse (compile or cache load): "
        f"{1e3 * (t2 - t1):.0f} ms; remaining kernels: {1e3 * (t3 - t2):.0f} ms"
    )

    rng = np.random.default_rng(0)
    lim = np.array([0.15, 0.15, 0.08, 0.15, 0.15, 0.4])
    poses = rng.uniform(-lim, lim, (N_BATCH, 6))
    print(f"batch poses reachable: {100 * np.mean(rus6.reachable(poses)):.1f} %")

    # --- batch inverse: throughput and peak memory of the call
    rus6.inverse(poses[:1000])
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        angles = rus6.inverse(poses)
        best = min(best, time.perf_counter() - t0)
        del angles
    tracemalloc.start()
    angles = rus6.inverse(poses)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(
        f"batch inverse of {N_BATCH:,} poses: {best * 1e3:.1f} ms, "
        f"{N_BATCH / best / 1e6:.2f} M poses/s (target >= 2.00); "
        f"peak traced memory of the call {peak / 2**20:.1f} MiB "
        f"(input {poses.nbytes / 2**20:.1f} MiB, output {angles.nbytes / 2**20:.1f} MiB)"
    )
    for name, fn, n in (
        ("reachable", rus6.reachable, N_BATCH),
        ("clamp", rus6.clamp, N_BATCH),
        ("jacobian", rus6.jacobian, 100_000),
        ("forward", lambda a: rus6.forward(a), 100_000),
    ):
        arg = angles[:n] if name == "forward" else poses[:n]
        fn(arg[:10])
        t0 = time.perf_counter()
        fn(arg)
        dt = time.perf_counter() - t0
        print(f"batch {name:<9} of {n:>9,}: {dt * 1e3:8.1f} ms, {n / dt / 1e6:6.2f} M/s")

    # --- single-pose latencies from Python
    print(f"single-pose latency over {N_CALLS:,} calls (us):     p50     p99    mean")
    pose = np.array([0.05, -0.03, -0.04, 0.1, -0.05, 0.2])
    cases = [
        ("inverse (target p50 <= 5)", rus6.inverse, pose),
        ("inverse, list input", rus6.inverse, pose.tolist()),
        ("reachable", rus6.reachable, pose),
        ("clamp, reachable input", rus6.clamp, pose),
        ("clamp, 3x translation", rus6.clamp, pose * np.array([3, 3, 3, 1, 1, 1])),
        ("clamp, 3x rotation", rus6.clamp, pose * np.array([1, 1, 1, 3, 3, 3])),
        ("clamp, 1 km / 1000 rad", rus6.clamp, np.array([1e3, -1e3, 1e3, 1e3, -1e3, 1e3])),
        ("jacobian", rus6.jacobian, pose),
        ("forward (Newton from neutral)", rus6.forward, rus6.inverse(pose)),
    ]
    for label, fn, arg in cases:
        p50, p99, mean = _latency_us(fn, arg)
        print(f"  {label:<32} {p50:8.2f} {p99:7.2f} {mean:7.2f}")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process peak RSS: {rss:.0f} MiB")


if __name__ == "__main__":
    # (no options: --help prints what it measures instead of running it)
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    main()
