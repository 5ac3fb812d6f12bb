"""Washout speed: step latency from Python (p50/p99) and batch run throughput.

Run: python benchmarks/bench_washout.py
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from motionbase.physics import STANDARD_GRAVITY as G
from motionbase.washout import ClassicalWashout, WashoutParams

DT = 1.0 / 120.0


def main() -> None:
    params = WashoutParams.preset("default")
    wo = ClassicalWashout(params, DT)
    rng = np.random.default_rng(0)
    n_step = 200_000
    f = np.array([0.0, 0.0, -G]) + rng.normal(0.0, 1.0, (n_step, 3))
    w = rng.normal(0.0, 0.2, (n_step, 3))

    wo.step(f[0], w[0])  # compile (or load the cache)
    wo.run(f[:10], w[:10])

    # step latency: one call per sample, timed individually
    lat = np.empty(n_step)
    clock = time.perf_counter_ns
    fl, wl = list(map(tuple, f)), list(map(tuple, w))
    for k in range(n_step):
        t0 = clock()
        wo.step(f[k], w[k])
        lat[k] = clock() - t0
    lat_t = np.empty(n_step)
    for k in range(n_step):
        t0 = clock()
        wo.step(fl[k], wl[k])
        lat_t[k] = clock() - t0

    # track latency (anti-windup hook)
    pose = wo.step(f[0], w[0]) * 0.5
    lat_tr = np.empty(20_000)
    for k in range(lat_tr.size):
        t0 = clock()
        wo.track(pose)
        lat_tr[k] = clock() - t0

    # batch throughput
    n_run = 2_000_000
    fr = np.array([0.0, 0.0, -G]) + rng.normal(0.0, 1.0, (n_run, 3))
    wr = rng.normal(0.0, 0.2, (n_run, 3))
    wo.reset()
    best = np.inf
    for _ in range(3):
        wo.reset()
        t0 = time.perf_counter()
        wo.run(fr, wr)
        best = min(best, time.perf_counter() - t0)

    us = 1e-3
    print("washout benchmark (default preset, dt = 1/120 s)")
    print(
        f"  step, ndarray inputs:  p50 {np.percentile(lat, 50) * us:6.2f} us   "
        f"p99 {np.percentile(lat, 99) * us:6.2f} us   ({n_step} calls)"
    )
    print(
        f"  step, tuple inputs:    p50 {np.percentile(lat_t, 50) * us:6.2f} us   "
        f"p99 {np.percentile(lat_t, 99) * us:6.2f} us"
    )
    print(
        f"  track:                 p50 {np.percentile(lat_tr, 50) * us:6.2f} us   "
        f"p99 {np.percentile(lat_tr, 99) * us:6.2f} us"
    )
    print(
        f"  run:  {n_run} samples in {best:.3f} s = "
        f"{n_run / best / 1e6:.2f} M samples/s (best of 3)"
    )


if __name__ == "__main__":
    # (no options: --help prints what it measures instead of running it)
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    main()
