"""I/O figures: JSBSim c1723 alone (the `fly` baseline), McapLogger.add cost, replay read speed.

Run: python benchmarks/bench_io.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from importlib.metadata import version
from pathlib import Path

import jsbsim
import numpy as np
from mcap.reader import make_reader

from motionbase.io.jsbsim_source import JsbsimSource, default_root
from motionbase.io.mcap_log import McapLogger
from motionbase.io.mcap_source import McapSource, read_messages


def bench_jsbsim_raw() -> tuple[float, int]:
    """JSBSim's own loop, nothing read: the floor."""
    root = default_root()
    logger = jsbsim.get_logger()

    class Quiet(jsbsim.FGLogger):
        def set_level(self, level):  # noqa: ANN001
            pass

        def message(self, message):  # noqa: ANN001
            pass

    jsbsim.set_logger(Quiet())
    with tempfile.TemporaryDirectory() as tmp:
        fdm = jsbsim.FGFDMExec(str(root), None)
        fdm.set_output_path(tmp)
        fdm.load_script(str(root / "scripts" / "c1723.xml"))
        fdm.run_ic()
        fdm.disable_output()
        t0 = time.perf_counter()
        n = 0
        while fdm.run():
            n += 1
        wall = time.perf_counter() - t0
        del fdm
    jsbsim.set_logger(logger)
    return wall, n


def bench_jsbsim_source() -> tuple[float, float, int]:
    """JsbsimSource("c1723"): load + 200 s of flight as AircraftState samples."""
    t0 = time.perf_counter()
    with JsbsimSource("c1723") as src:
        t1 = time.perf_counter()
        n = sum(1 for _ in src)
    t2 = time.perf_counter()
    return t2 - t0, t2 - t1, n


def bench_logger(path: Path, samples: int = 24000) -> tuple[dict[str, np.ndarray], str]:
    rng = np.random.default_rng(1)
    sf, av, att, acc = (rng.normal(size=3) for _ in range(4))
    pose = rng.normal(size=6) * 0.05
    angles = rng.normal(size=6) * 0.3
    per_topic: dict[str, list[int]] = {
        k: []
        for k in (
            "/aircraft/state",
            "/washout/pose",
            "/platform/pose",
            "/platform/actuators",
            "/tf",
            "sample (5 messages)",
        )
    }
    clock = time.perf_counter_ns
    with McapLogger(path, {"rate_hz": 120.0}) as logger:
        add = logger.add
        for k in range(1, samples + 1):
            t = k / 120
            c0 = clock()
            add(
                "/aircraft/state",
                t,
                {
                    "t": t,
                    "specific_force": sf,
                    "angular_velocity": av,
                    "attitude": att,
                    "angular_acceleration": acc,
                },
            )
            c1 = clock()
            add("/washout/pose", t, {"t": t, "pose": pose})
            c2 = clock()
            add("/platform/pose", t, {"t": t, "pose": pose, "clamped": False})
            c3 = clock()
            add("/platform/actuators", t, {"t": t, "angles": angles})
            c4 = clock()
            logger.add_transform(t, pose)
            c5 = clock()
            per_topic["/aircraft/state"].append(c1 - c0)
            per_topic["/washout/pose"].append(c2 - c1)
            per_topic["/platform/pose"].append(c3 - c2)
            per_topic["/platform/actuators"].append(c4 - c3)
            per_topic["/tf"].append(c5 - c4)
            per_topic["sample (5 messages)"].append(c5 - c0)
    return {k: np.asarray(v) / 1e3 for k, v in per_topic.items()}, logger.compression


def main() -> None:
    print(
        f"motionbase I/O benchmark (jsbsim {jsbsim.__version__}, MCAP writer foxglove-sdk "
        f"{version('foxglove-sdk')}, {os.cpu_count()} CPUs)"
    )
    raw, n_raw = bench_jsbsim_raw()
    total, run, n = bench_jsbsim_source()
    print("\nJSBSim c1723 alone (200 s simulated, 24,000 steps at 120 Hz):")
    print(
        f"  raw FGFDMExec.run loop        {raw:7.3f} s wall  ({n_raw} steps, "
        f"{raw / n_raw * 1e6:5.1f} us/step)"
    )
    print(
        f"  JsbsimSource (baseline)       {total:7.3f} s wall  (load {total - run:.3f} s + "
        f"{n} samples in {run:.3f} s, {run / n * 1e6:5.1f} us/sample)"
    )

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        stats, compression = bench_logger(path)
        size = path.stat().st_size
        print(f"\nMcapLogger.add cost (24,000 samples, {compression}, 1 s chunks):")
        for name, us in stats.items():
            print(
                f"  {name:22s} p50 {np.percentile(us, 50):6.1f} us   "
                f"p99 {np.percentile(us, 99):6.1f} us   max {us.max():8.1f} us"
            )
        # as the file's summary counts them (five a sample, and /tf's world frame once a
        # second; the count was written as six a sample)
        with open(path, "rb") as fh:
            written = make_reader(fh).get_summary().statistics.message_count
        print(f"  file: {size / 1e6:.2f} MB for {written} messages")

        t0 = time.perf_counter()
        with McapSource(path) as src:
            scan = time.perf_counter() - t0
            states = sum(1 for _ in src)
        replay = time.perf_counter() - t0
        t0 = time.perf_counter()
        msgs = sum(len(v) for v in read_messages(path).values())
        read_all = time.perf_counter() - t0
        print("\nReading back:")
        print(f"  McapSource: scan {scan:.3f} s + {states} states in {replay - scan:.3f} s")
        print(
            f"  read_messages: {msgs} messages in {read_all:.3f} s "
            f"({read_all / msgs * 1e6:.1f} us/message)"
        )


if __name__ == "__main__":
    # (no options: --help prints what it measures instead of running it)
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    main()
