"""The main job's speed: `motionbase fly c1723` against JSBSim alone, and the pipeline's own cost.

Run: ``python benchmarks/bench_pipeline.py`` (about a minute). Prints

* wall time of the c1723 script run by JSBSim alone (no pipeline), side by side with
  ``motionbase fly c1723`` (the whole job: JSBSim, pipeline, MCAP log), and their ratio
  (issue 4 target: fly <= 2x JSBSim alone);
* the pipeline's own work per sample (validation, washout, clamp, inverse kinematics,
  safety, MCAP logging) as percentiles (targets: p50 <= 30 us, p99 <= 150 us);
* the peak resident memory of ``fly`` for a 50 s and a 200 s flight (it must not grow
  with flight length: the log streams to disk).
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def jsbsim_alone(script: str = "c1723") -> tuple[float, int]:
    """The script run by JSBSim's own loop, quiet, as fast as possible."""
    import jsbsim

    from motionbase.io.jsbsim_source import _QuietLogger

    root = Path(jsbsim.get_default_root_dir())
    previous = jsbsim.get_logger()
    jsbsim.set_logger(_QuietLogger())  # its script notices kept from the terminal, as in fly
    with tempfile.TemporaryDirectory() as tmp:
        cwd = os.getcwd()
        os.chdir(tmp)  # c1723 writes a state file into the working directory
        try:
            fdm = jsbsim.FGFDMExec(str(root))
            fdm.set_debug_level(0)
            t0 = time.perf_counter()
            fdm.load_script(str(root / "scripts" / f"{script}.xml"))
            fdm.run_ic()
            steps = 0
            while fdm.run():
                # read what the pipeline reads, so the comparison is fair
                for name in ("x", "y", "z"):
                    fdm[f"accelerations/a-pilot-{name}-ft_sec2"]
                steps += 1
            return time.perf_counter() - t0, steps
        finally:
            os.chdir(cwd)
            jsbsim.set_logger(previous)


def fly_wall(script: str = "c1723") -> tuple[float, int]:
    from motionbase import app

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        result = app.fly(script, out=Path(tmp) / "bench.mcap", progress=False)
        return time.perf_counter() - t0, result.summary.samples


def per_sample_cost(script: str = "c1723") -> tuple[np.ndarray, np.ndarray]:
    """Time of Pipeline.step + the MCAP sink's write, per sample, in seconds: wall
    clock and the loop thread's CPU time.

    Measured inside the real loop (:func:`motionbase.pipeline.run`, JSBSim source,
    MCAP log), so JSBSim's cache pollution counts, and so do the log's compression
    and chunk hand-overs; park ticks after the source ends are left out. The CPU time
    leaves out what other processes take from a shared machine (the wall-clock
    figures then move from run to run): it is the work the tick itself does.
    """
    from motionbase import app
    from motionbase.io.jsbsim_source import JsbsimSource
    from motionbase.io.pipeline_log import PipelineLog
    from motionbase.pipeline import Pipeline, run

    clock, cpu = time.perf_counter_ns, time.thread_time_ns
    wall_ns: list[int] = []
    cpu_ns: list[int] = []
    started = [0, 0]

    class TimedPipeline(Pipeline):
        def step(self, state, fresh=True):
            started[:] = clock(), cpu()
            return super().step(state, fresh)

    class TimedLog(PipelineLog):
        def write(self, out):
            super().write(out)
            if out.state is not None:
                wall_ns.append(clock() - started[0])
                cpu_ns.append(cpu() - started[1])

    with tempfile.TemporaryDirectory() as tmp, JsbsimSource(script) as source:
        config = app.load_config(rate_hz=source.rate_hz)
        pipeline = TimedPipeline(config)
        wall_ns.clear()  # the constructor's warm-up tick is not part of the run
        cpu_ns.clear()
        meta = app.run_metadata(config, source)
        with TimedLog(Path(tmp) / "b.mcap", meta, health=pipeline.health.as_dict) as log:
            run(pipeline, source, [log])
    return np.array(wall_ns) * 1e-9, np.array(cpu_ns) * 1e-9


def fly_peak_rss_mib(duration_s: float) -> float:
    """Peak RSS of a `motionbase fly` subprocess, MiB."""
    with tempfile.TemporaryDirectory() as tmp:
        code = (
            "import resource, sys\n"
            "from motionbase import app\n"
            f"app.fly('c1723', duration_s={duration_s}, out=sys.argv[1], progress=False)\n"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
        )
        out = subprocess.run(
            [sys.executable, "-c", code, str(Path(tmp) / "m.mcap")],
            capture_output=True,
            text=True,
            check=True,
        )
        return int(out.stdout.strip().splitlines()[-1]) / 1024


def main() -> None:
    print("motionbase pipeline benchmark (c1723: 200 s of simulated flight at 120 Hz)")
    fly_wall("c1723")  # warm the numba caches and the OS file cache first
    # side by side, interleaved, best of 3 each (the machine's speed drifts)
    alones, flies = [], []
    for _ in range(3):
        alone, steps = jsbsim_alone()
        fly, samples = fly_wall()
        alones.append(alone)
        flies.append(fly)
    base, fly = min(alones), min(flies)
    runs = ", ".join(f"{f / a:.2f}" for a, f in zip(alones, flies, strict=True))
    print(f"  JSBSim alone:        {base:6.2f} s  ({steps} steps; best of 3)")
    print(f"  motionbase fly:      {fly:6.2f} s  ({samples} samples incl. soft start and park)")
    print(f"  ratio fly / alone:   {fly / base:6.2f}   (target <= 2; run by run: {runs})")
    wall, cpu = per_sample_cost()
    print(f"  pipeline work per sample (step + log), {len(wall)} samples (targets p50 <= 30 us,")
    print("  p99 <= 150 us):")
    for name, cost in (("wall clock", wall), ("thread CPU", cpu)):
        p50, p99, p999 = np.percentile(cost, [50, 99, 99.9]) * 1e6
        print(
            f"    {name}: p50 {p50:.1f} us, p99 {p99:.1f} us, p99.9 {p999:.1f} us, "
            f"max {cost.max() * 1e6:.0f} us"
        )
    short, full = fly_peak_rss_mib(50.0), fly_peak_rss_mib(200.0)
    print(f"  peak RSS of fly: 50 s flight {short:.0f} MiB, 200 s flight {full:.0f} MiB")
    print(f"  (this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB)")


if __name__ == "__main__":
    main()
