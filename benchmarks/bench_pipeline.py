"""The main job's speed: `motionbase fly c1723` against JSBSim alone, and the pipeline's own cost.

Run: ``python benchmarks/bench_pipeline.py`` (about two minutes). Prints

* wall time of the c1723 script run by JSBSim alone (no pipeline), side by side with
  ``motionbase fly c1723`` (the whole job: JSBSim, pipeline, MCAP log), and their ratio,
  twice: as whole processes, start-up included (what a user waits for; issue 14 target:
  <= 3x), and inside one warm process (the work alone; issue 4 target: <= 2x);
* the batch path's throughput (:meth:`Pipeline.run_batch`: cueing, clamp, inverse
  kinematics and the limiter over a whole flight's arrays, no log; issue 14 target: >= 1 M
  samples/s);
* the pipeline's own work per sample (validation, washout, clamp, inverse kinematics,
  safety, MCAP logging) as percentiles (targets: p50 <= 30 us, p99 <= 150 us);
* the peak resident memory of ``fly`` for a 50 s and a 200 s flight (it must not grow
  with flight length: the log streams to disk).
"""

from __future__ import annotations

import argparse
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


#: JSBSim alone as a process: the same script, reading the same properties each step as
#: motionbase's JSBSim source (``PROPERTIES``), quiet, as fast as possible.
_ALONE_PROCESS = """
import os, sys, tempfile, jsbsim
from pathlib import Path
from motionbase.io.jsbsim_source import PROPERTIES, _QuietLogger
root = Path(jsbsim.get_default_root_dir())
jsbsim.set_logger(_QuietLogger())
os.chdir(tempfile.mkdtemp())
fdm = jsbsim.FGFDMExec(str(root))
fdm.set_debug_level(0)
fdm.load_script(str(root / "scripts" / (sys.argv[1] + ".xml")))
fdm.run_ic()
fdm.disable_output()
pm = fdm.get_property_manager()
nodes = [pm.get_node(name) for name in PROPERTIES]
while fdm.run():
    [node.get_double_value() for node in nodes]
"""


def process_walls(script: str = "c1723") -> tuple[float, float]:
    """Wall time of two processes, start-up included: JSBSim alone, and ``motionbase fly``."""
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", _ALONE_PROCESS, script], check=True)
        alone = time.perf_counter() - t0
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "motionbase.cli", "fly", script, "--out", f"{tmp}/f.mcap"],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        return alone, time.perf_counter() - t0


def flight_arrays(script: str = "c1723") -> tuple[np.ndarray, ...]:
    """A JSBSim script's aircraft samples as arrays: t, f, w, att (and its rate, Hz)."""
    from motionbase.io.jsbsim_source import JsbsimSource

    with JsbsimSource(script) as source:
        states = list(source)
        rate = source.rate_hz
    t = np.array([s.t for s in states])
    f = np.array([s.specific_force for s in states])
    w = np.array([s.angular_velocity for s in states])
    att = np.array([s.attitude for s in states])
    return t, f, w, att, rate


def batch_throughput(
    arrays: tuple[np.ndarray, ...], repeat: int = 10, planar: bool = False
) -> tuple[float, float]:
    """Samples per second of :meth:`Pipeline.run_batch` (6-RUS, or the planar 3-RRR,
    classical washout) over a flight repeated ``repeat`` times end to end, best of 3; and
    the share of ticks clamped."""
    from motionbase import app
    from motionbase.pipeline import Pipeline

    t, f, w, att, rate = arrays
    span = t[-1] - t[0] + 1.0 / rate
    t = np.concatenate([t + k * span for k in range(repeat)])
    f, w, att = (np.tile(x, (repeat, 1)) for x in (f, w, att))
    config = app.load_config(rate_hz=rate, planar=planar)
    best = np.inf
    for _ in range(3):
        pipeline = Pipeline(config)
        t0 = time.perf_counter()
        result = pipeline.run_batch(t, f, w, att)
        best = min(best, time.perf_counter() - t0)
    return len(t) / best, float(result.clamped.mean())


def manoeuvring_arrays(seconds: float = 2000.0, rate_hz: float = 120.0) -> tuple[np.ndarray, ...]:
    """Strong synthetic manoeuvring that keeps the workspace clamp busy (for comparison)."""
    n = int(seconds * rate_hz)
    t = np.arange(1, n + 1) / rate_hz
    s = np.sin(2 * np.pi * 0.3 * t)
    c = np.cos(2 * np.pi * 0.17 * t)
    f = np.column_stack([3 * s, 2 * c, -9.80665 + 2 * s * c])
    w = np.column_stack([0.3 * c, 0.2 * s, 0.1 * c])
    return t, f, w, np.zeros((n, 3)), rate_hz


def per_sample_cost(script: str = "c1723", planar: bool = False) -> tuple[np.ndarray, np.ndarray]:
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
        config = app.load_config(rate_hz=source.rate_hz, planar=planar)
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
    print("  in one warm process (the work alone):")
    print(f"    JSBSim alone:        {base:6.2f} s  ({steps} steps; best of 3)")
    print(f"    motionbase fly:      {fly:6.2f} s  ({samples} samples incl. soft start and park)")
    print(f"    ratio fly / alone:   {fly / base:6.2f}   (target <= 2; run by run: {runs})")
    pairs = [process_walls() for _ in range(3)]
    alone_p, fly_p = min(a for a, _ in pairs), min(f for _, f in pairs)
    runs = ", ".join(f"{f / a:.2f}" for a, f in pairs)
    print("  as whole processes, start-up included (what a user waits for):")
    print(f"    python JSBSim alone: {alone_p:6.2f} s  (best of 3)")
    print(f"    motionbase fly:      {fly_p:6.2f} s  (best of 3)")
    print(f"    ratio fly / alone:   {fly_p / alone_p:6.2f}   (target <= 3; run by run: {runs})")
    print("  batch path (Pipeline.run_batch: every stage, 6-RUS, classical washout, no log):")
    rate, clamped = batch_throughput(flight_arrays(), repeat=10)
    print(
        f"    c1723's samples, 10 times over: {rate / 1e6:.2f} M samples/s (target >= 1; "
        f"best of 3; {clamped:.1%} of ticks clamped)"
    )
    rate, clamped = batch_throughput(manoeuvring_arrays(), repeat=1)
    print(
        f"    strong synthetic manoeuvring: {rate / 1e6:.2f} M samples/s ({clamped:.1%} of "
        "ticks clamped: a clamped tick searches the reachable scale, about 80 inverse "
        "kinematics)"
    )
    wall, cpu = per_sample_cost()
    print(f"  pipeline work per sample (step + log), {len(wall)} samples (targets p50 <= 30 us,")
    print("  p99 <= 150 us):")
    for name, cost in (("wall clock", wall), ("thread CPU", cpu)):
        p50, p99, p999 = np.percentile(cost, [50, 99, 99.9]) * 1e6
        print(
            f"    {name}: p50 {p50:.1f} us, p99 {p99:.1f} us, p99.9 {p999:.1f} us, "
            f"max {cost.max() * 1e6:.0f} us"
        )
    # the planar 3-RRR: its limiter commands poses (stages.path_stage: a bisection a tick)
    rate, clamped = batch_throughput(flight_arrays(), repeat=10, planar=True)
    wall, cpu = per_sample_cost(planar=True)
    p50, p99 = np.percentile(cpu, [50, 99]) * 1e6
    print(
        f"  planar 3-RRR (path stage): batch {rate / 1e6:.2f} M samples/s ({clamped:.1%} "
        f"clamped); step + log, thread CPU: p50 {p50:.1f} us, p99 {p99:.1f} us"
    )
    short, full = fly_peak_rss_mib(50.0), fly_peak_rss_mib(200.0)
    print(f"  peak RSS of fly: 50 s flight {short:.0f} MiB, 200 s flight {full:.0f} MiB")
    print(f"  (this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB)")


if __name__ == "__main__":
    # (no options: --help prints what it measures instead of running it)
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    main()
