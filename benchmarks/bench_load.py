"""Load: 10 minutes of simulated flight at 1 kHz through the whole pipeline and the MCAP log.

Run: ``python benchmarks/bench_load.py`` (about a minute or two; ``--minutes M`` for another
length, ``--planar`` for the 3-RRR robot, ``--paced`` to run on the wall clock and read the
loop overruns from the log's ``/health`` record, which then takes the flight's length;
``--no-log`` leaves the MCAP writes out, to see their share; ``--busy-wait`` waits for
each tick by busy-waiting instead of sleeping, as ``motionbase fly --realtime --busy-wait``;
``--paced --loop-paced`` lets the pipeline's loop pace a source that does not pace itself,
as ``replay --output`` and ``fly --output`` do). With ``--paced`` it prints the commands
late for the actuators that ``/health`` counts from each sample's due time.
``--platform P`` and ``--params FILE`` run another geometry and cueing parameters (e.g. an
earlier version's presets, to compare the code on the same work).
``--floor`` measures the machine instead: the same paced 1 kHz loop shape with a fixed
50 us of computing per tick and nothing else, to tell what the machine does to any loop
(a virtual machine's host taking the CPU away) from what the pipeline costs.
``--hiccups`` measures the stalls themselves: a loop that only reads the clock, counting
the gaps in which it did not run (as jHiccup does).
``--live`` also serves the log to Foxglove over WebSocket (``motionbase ... --live``) with one
client connected, in another process, subscribed to every topic and reading all it gets
(the ``websockets`` package of the test extra; the server sends each topic at most 60 times a
second, ``--live-rate HZ`` for another rate); ``--no-scene`` leaves ``/platform/scene`` out.
The tick times are also given apart for the ticks that drew a scene and for the others.

The source is synthetic but physically plausible: a sum of sines in specific force
(about +-2 m/s^2 surge and sway around 1 g, +-1.5 m/s^2 heave) and body rates (about
+-0.2 rad/s), frequencies 0.05..3 Hz, with a small broadband turbulence term, so the
washout, the clamp and the limiter all work. Each tick runs validation, washout, clamp,
inverse kinematics, the safety stage and the MCAP log sink (``PipelineLog``, the same
sink ``motionbase fly`` uses). Prints:

* processing time per tick (pipeline step + log write, from the moment the source hands the
  sample over): p50 / p99 / p99.9 / max, in microseconds;
* overruns against the 1 ms budget of a 1 kHz loop (ticks whose work took longer);
* resident memory (RSS) at start, middle and end of the flight: it must stay flat;
* the log's size and its final ``/health`` record.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from motionbase.app import load_config, run_metadata
from motionbase.io.mcap_log import LiveAddress
from motionbase.io.mcap_source import read_messages
from motionbase.io.pipeline_log import PipelineLog
from motionbase.pacing import wait_until
from motionbase.physics import STANDARD_GRAVITY as G
from motionbase.pipeline import Pipeline, StopRequest, run
from motionbase.state import AircraftState


def rss_mb() -> float:
    """Current resident set size, MB (Linux /proc)."""
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


class SyntheticFlight:
    """Sum of sines in specific force and body rates at ``rate_hz`` for ``duration_s``."""

    def __init__(
        self,
        rate_hz: float,
        duration_s: float,
        seed: int = 7,
        paced: bool = False,
        busy_wait: bool = False,
    ) -> None:
        self.rate_hz = rate_hz
        self.duration_s = duration_s
        self.paced = paced  # hand each sample over at its time on the wall clock
        self.paces_itself = paced  # (then the pipeline's loop does not pace it again)
        self.busy_wait = busy_wait  # wait for it by busy-waiting (else sleeping)
        self.due_time: float | None = None  # when the last sample was due (monotonic s)
        self.fresh = True
        rng = np.random.default_rng(seed)
        self.freq = np.array([0.05, 0.13, 0.31, 0.7, 1.6, 3.0])  # Hz
        self.phase = rng.uniform(0, 2 * np.pi, (6, len(self.freq)))
        # amplitude per channel (f_x, f_y, f_z m/s^2; p, q, r rad/s), falling with frequency
        amp = np.array([2.0, 2.0, 1.5, 0.2, 0.2, 0.2])[:, None]
        self.amp = amp * (1.0 / (1.0 + self.freq))[None, :] / 1.6
        self.rng = rng

    def describe(self) -> dict:
        return {
            "kind": "synthetic sum of sines",
            "rate_hz": self.rate_hz,
            "busy_wait": self.busy_wait,
        }

    def __iter__(self):
        n = int(round(self.duration_s * self.rate_hz))
        dt = 1.0 / self.rate_hz
        w = 2 * np.pi * self.freq
        noise = self.rng.normal(0.0, 0.02, (n, 6))
        start = time.perf_counter()
        mono = time.monotonic() - start  # perf_counter -> monotonic (the same clock on Linux)
        for k in range(n):
            t = k * dt
            if self.paced:
                self.due_time = start + t + mono
                wait_until(start + t, busy=self.busy_wait)
            x = (self.amp * np.sin(w * t + self.phase)).sum(axis=1) + noise[k]
            att = (0.1 * math.sin(0.2 * t), 0.05 * math.sin(0.15 * t), 0.3 * t % (2 * math.pi))
            att = (att[0], att[1], att[2] - math.pi)
            state = AircraftState(t, (x[0], x[1], -G + x[2]), (x[3], x[4], x[5]), att)
            self.handed_cpu = time.thread_time()
            self.handed_at = time.perf_counter()
            self.due = start + t  # when the sample was due on the wall clock (perf_counter)
            yield state


class TimedLog(PipelineLog):
    """The MCAP sink, timing each tick from the source's hand-over to the end of its write."""

    def __init__(self, *a, source: SyntheticFlight, capacity: int, log: bool = True, **kw) -> None:
        super().__init__(*a, **kw)
        self.source = source
        self.log = log  # False: time the ticks, log only the final /health (the log's share)
        # preallocated and touched (fill) now: the measurement adds no memory during the run
        self.times = np.zeros(capacity)
        self.cpu = np.zeros(capacity)  # the loop thread's CPU time in the same span
        self.since_due = np.zeros(capacity)  # from the sample's due time to the end of its write
        self.drew = np.zeros(capacity, dtype=bool)  # the tick wrote /platform/scene
        self.drew.fill(False)
        self.times.fill(0.0)
        self.cpu.fill(0.0)
        self.since_due.fill(0.0)
        self.n = 0

    def write(self, out) -> None:
        if self.log:
            super().write(out)
        if out.state is None:
            return  # park ticks after the flight
        if self.n < len(self.times):
            now = time.perf_counter()
            self.times[self.n] = now - self.source.handed_at
            self.cpu[self.n] = time.thread_time() - self.source.handed_cpu
            self.since_due[self.n] = now - self.source.due
            self.drew[self.n] = self._scene_t == out.t
        self.n += 1


def floor(minutes: float, rate_hz: float, busy_wait: bool, work_s: float = 50e-6) -> None:
    """The machine's own overruns: a paced loop computing ``work_s`` a tick, nothing else."""
    n = int(round(minutes * 60.0 * rate_hz))
    dt = 1.0 / rate_hz
    clock, cpu_clock = time.perf_counter, time.thread_time
    late = []  # (wall s, CPU s) of the late ticks
    steal0 = _steal_s()
    start = clock()
    for k in range(n):
        wait_until(start + k * dt, busy=busy_wait)
        t0, c0 = clock(), cpu_clock()
        while clock() - t0 < work_s:
            pass
        wall = clock() - t0
        if wall > dt:
            late.append((wall, cpu_clock() - c0))
    off_cpu = sum(c < dt for _, c in late)
    worst = max((w for w, _ in late), default=dt) - dt
    print(
        f"bench_load --floor: {minutes:g} min of a paced {rate_hz:g} Hz loop computing "
        f"{work_s * 1e6:.0f} us a tick and nothing else (no pipeline, no log), "
        f"{'busy-waiting' if busy_wait else 'sleeping'} between ticks"
    )
    print(
        f"  overruns {len(late)} of {n} ticks ({100 * len(late) / n:.4f} %), "
        f"{off_cpu} of them off the CPU; worst {1e3 * worst:.2f} ms late"
    )
    _print_steal(steal0, _steal_s())


def hiccups(minutes: float, rate_hz: float) -> None:
    """The machine's stalls: a thread that only reads the clock, timing every gap between reads.

    A gap longer than a few microseconds is time the thread did not run (the OS or a virtual
    machine's host took the CPU). A stall of ``g`` seconds makes a 1 kHz tick of ``w`` seconds
    late when it starts inside the tick and ``w + g`` passes the period: with ``n`` stalls of
    at least one period, about ``n * w * rate_hz`` late ticks whatever the loop computes.
    """
    clock = time.perf_counter
    period = 1.0 / rate_hz
    steal0 = _steal_s()
    end = clock() + minutes * 60.0
    gaps = []
    prev = clock()
    while prev < end:
        now = clock()
        if now - prev > 50e-6:
            gaps.append(now - prev)
        prev = now
    steal1 = _steal_s()
    g = np.array(gaps)
    print(
        f"bench_load --hiccups: {minutes:g} min of a thread that only reads the clock "
        "(gaps between two reads: time it did not run)"
    )
    for edge in (100e-6, 500e-6, 1e-3, 2e-3, 5e-3, 10e-3):
        print(f"  gaps >= {edge * 1e3:4g} ms: {int((g >= edge).sum()):6d}")
    long = g[g >= period]
    work = 50e-6  # a tick's work, s: a stall of period - work inside it makes it late
    expected = (g >= period - work).sum() * work * rate_hz
    print(
        f"  stalls of at least one period ({period * 1e3:g} ms): {len(long)}, "
        f"{long.sum():.2f} s in all, longest {1e3 * g.max(initial=0.0):.1f} ms; "
        f"a tick computing {work * 1e6:.0f} us would be late about {expected:.0f} times"
    )
    _print_steal(steal0, steal1)


def _print_steal(steal0: float | None, steal1: float | None) -> None:
    """Print the host's steal time between two :func:`_steal_s` readings (if it has one)."""
    if steal0 is not None and steal1 is not None:
        print(
            f"  CPU time the host took from this machine during the run (/proc/stat steal, "
            f"all CPUs): {steal1 - steal0:.2f} s"
        )


def _steal_s() -> float | None:
    """Seconds of steal time (a VM's vCPUs not run by the host) summed over CPUs, or None."""
    try:
        with open("/proc/stat") as fh:
            fields = fh.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


# One Foxglove client in its own process: subscribes to every channel, reads until the end.
CLIENT = """
import json, sys
from websockets.sync.client import connect
from websockets.exceptions import ConnectionClosed
n = 0
with connect(sys.argv[1], subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
    ids = []
    while not ids:
        m = json.loads(ws.recv())
        if m["op"] == "advertise":
            want = sys.argv[2].split(",") if len(sys.argv) > 2 else None
            ids = [c["id"] for c in m["channels"] if want is None or c["topic"] in want]
    subs = [{"id": i + 1, "channelId": c} for i, c in enumerate(ids)]
    ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
    print("subscribed", flush=True)
    try:
        while True:
            n += isinstance(ws.recv(), bytes)
    except ConnectionClosed:
        pass
print(n, flush=True)
"""


def start_client(url: str, topics: str | None = None) -> subprocess.Popen:
    """The client process, once it has subscribed (to ``topics``, comma-separated, or all)."""
    argv = [sys.executable, "-c", CLIENT, url, *([topics] if topics else [])]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "subscribed"
    return proc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--planar", action="store_true")
    ap.add_argument("--platform", help="a geometry preset or TOML file (default: ceart)")
    ap.add_argument("--params", help="the cueing's parameters, a preset or TOML file")
    ap.add_argument("--paced", action="store_true")
    ap.add_argument(
        "--loop-paced",
        action="store_true",
        help="with --paced: the source hands samples over at once and the pipeline's loop "
        "paces the ticks (as replay --output does)",
    )
    ap.add_argument("--floor", action="store_true")
    ap.add_argument("--no-log", action="store_true", help="skip the MCAP writes (their share)")
    ap.add_argument(
        "--busy-wait", action="store_true", help="paced: busy-wait between ticks, not sleep"
    )
    ap.add_argument(
        "--hiccups", action="store_true", help="measure the machine's stalls (a clock-reading loop)"
    )
    ap.add_argument("--live", action="store_true", help="serve Foxglove, one client connected")
    ap.add_argument("--no-scene", action="store_true", help="leave /platform/scene out")
    ap.add_argument("--live-topics", metavar="T1,T2", help="--live: the client subscribes to these")
    ap.add_argument(
        "--live-rate", type=float, default=60.0, help="--live: messages per second per topic"
    )
    args = ap.parse_args()
    if args.hiccups:
        hiccups(args.minutes, args.rate)
        return
    if args.floor:
        floor(args.minutes, args.rate, args.busy_wait)
        return

    config = load_config(
        planar=args.planar, platform=args.platform, washout=args.params, rate_hz=args.rate
    )
    duration = args.minutes * 60.0
    if args.loop_paced and not args.paced:
        ap.error("--loop-paced goes with --paced")
    source = SyntheticFlight(
        args.rate, duration, paced=args.paced and not args.loop_paced, busy_wait=args.busy_wait
    )
    pipeline = Pipeline(config)
    budget = 1.0 / args.rate
    n_total = int(round(duration * args.rate))
    rss = {"start": rss_mb()}

    with tempfile.TemporaryDirectory(prefix="bench-load-") as tmp:
        path = Path(tmp) / "load.mcap"
        log = TimedLog(
            path,
            run_metadata(config, source),
            health=pipeline.health.as_dict,
            source=source,
            capacity=n_total,
            log=not args.no_log,
            robot=None if args.no_scene else pipeline.robot,
            live=LiveAddress("127.0.0.1", 0) if args.live else None,
            live_rate_hz=args.live_rate,
        )
        every = max(1, n_total // 10)

        def progress(out) -> None:
            if log.n % every == 0 and log.n <= n_total:
                rss[f"{100 * log.n // n_total}%"] = rss_mb()

        with log:
            url = f"ws://127.0.0.1:{log.live_port}" if args.live else ""
            client = start_client(url, args.live_topics) if args.live else None
            steal0 = _steal_s()
            wall0 = time.perf_counter()
            summary = run(
                pipeline,
                source,
                [log],
                paced=args.paced,
                busy_wait=args.busy_wait,
                stop=StopRequest(),
                progress=progress,
            )
            wall = time.perf_counter() - wall0
            steal1 = _steal_s()
            rss["end"] = rss_mb()
        size = path.stat().st_size
        health = read_messages(path)["/health"][-1]
        received = int(client.communicate(timeout=60)[0].strip() or 0) if client else None

    # the first ticks include numba dispatch warm-up: report them separately
    samples = log.times[: min(log.n, len(log.times))]
    loop = samples[10:] * 1e6
    cpu = log.cpu[10 : len(samples)] * 1e6
    late = loop > budget * 1e6
    over = int(late.sum())
    computing = np.nonzero(late & (cpu >= budget * 1e6))[0]
    robot = "3-RRR (planar)" if args.planar else "6-RUS"
    robot += f" {getattr(config.geometry, 'name', '')}, {config.cueing} cueing"
    robot += f" ({args.params or 'default parameters'})"
    what = " (--no-log: no MCAP writes but the final /health)" if args.no_log else ""
    if args.paced:
        what += ", busy-waiting between ticks" if args.busy_wait else ", sleeping between ticks"
        if args.loop_paced:
            what += ", paced by the pipeline's loop (the times below include its wait)"
    what += ", no /platform/scene" if args.no_scene else ", /platform/scene at 30 Hz"
    if args.live:
        what += f", live: one Foxglove client received {received} messages"
        what += f" of {args.live_topics}" if args.live_topics else " (every topic)"
        what += f", at most {args.live_rate:g} a second each"
    print(f"bench_load: {args.minutes:g} min simulated flight at {args.rate:g} Hz, {robot}{what}")
    print(
        f"  ticks {summary.samples} (incl. park ramp), wall {wall:.1f} s "
        f"({summary.sim_time_s / wall:.1f}x real time), source + pipeline + MCAP log"
    )
    print(
        "  tick processing (pipeline step + log write, from the source's hand-over) us: "
        f"p50 {np.percentile(loop, 50):.1f}  p99 {np.percentile(loop, 99):.1f}  "
        f"p99.9 {np.percentile(loop, 99.9):.1f}  max {loop.max():.1f}"
    )
    print(
        "  the same ticks' CPU time (the loop thread's: what other load on the machine does "
        f"not add) us: p50 {np.percentile(cpu, 50):.1f}  p99 {np.percentile(cpu, 99):.1f}"
    )
    drew = log.drew[10 : len(samples)]
    if drew.any():
        scene, other = loop[drew], loop[~drew]
        print(
            f"    ticks that drew a scene ({len(scene)}) us: p50 {np.percentile(scene, 50):.1f}  "
            f"p99 {np.percentile(scene, 99):.1f}; the others: p50 {np.percentile(other, 50):.1f}"
            f"  p99 {np.percentile(other, 99):.1f}"
        )
    print(
        f"  overruns vs the {budget * 1e3:g} ms budget: {over} of {len(loop)} ticks "
        f"({100 * over / len(loop):.4f} %); first 10 ticks (warm-up) max "
        f"{samples[:10].max() * 1e6:.0f} us"
    )
    print(
        f"    of which the loop thread was waiting (CPU time under the budget): "
        f"{over - len(computing)}; computing: {len(computing)}"
        + "".join(
            f"\n      tick {k + 10} (t {(k + 10) / args.rate:.3f} s): "
            f"{loop[k]:.0f} us wall, {cpu[k]:.0f} us CPU"
            for k in computing[:10]
        )
    )
    if args.paced and not args.loop_paced:
        # what the actuator sees: the command is ready this long after the sample was due
        # (the sleep's wake-up, or a backlog after a stall, plus the tick itself)
        ready = log.since_due[10 : len(samples)] * 1e6
        print(
            "  command ready after the sample's due time (wake-up + tick) us: "
            f"p50 {np.percentile(ready, 50):.1f}  p99 {np.percentile(ready, 99):.1f}  "
            f"p99.9 {np.percentile(ready, 99.9):.1f}; over 1 period: "
            f"{int((ready > budget * 1e6).sum())} ticks"
        )
    middle = rss.get("50%", math.nan)
    print(
        f"  RSS MB: start {rss['start']:.1f}  middle {middle:.1f}  end {rss['end']:.1f}  "
        f"(middle -> end {rss['end'] - middle:+.1f})"
    )
    print("  RSS MB every 10 %: " + " ".join(f"{v:.0f}" for k, v in rss.items() if "%" in k))
    print(f"  log {size / 1e6:.1f} MB ({size / duration / 1e3:.0f} kB per simulated second)")
    keys = (
        "samples",
        "rejected_inputs",
        "clamps",
        "rate_limited",
        "unsafe_commands",
        "watchdog_fades",
        "time_jumps",
        "estops",
        "overruns",
        "overruns_off_cpu",
        "worst_overrun_s",
        "late_commands",
        "worst_late_s",
    )
    print("  /health: " + ", ".join(f"{k} {health.get(k)}" for k in keys))
    if args.paced:
        print(
            f"  commands late for the actuators (/health, from each sample's due time): "
            f"{health.get('late_commands')} more than one period late, worst by "
            f"{1e3 * health.get('worst_late_s', 0.0):.2f} ms beyond it"
        )
    if not args.paced:
        print("  (overruns are measured only with --paced, on the wall clock)")
    else:
        _print_steal(steal0, steal1)


if __name__ == "__main__":
    main()
