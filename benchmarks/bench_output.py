"""Motor-drive output: cost of formatting and sending one frame, and 1 kHz sustained output.

Run: python benchmarks/bench_output.py

Targets (issue 8): formatting + sending one frame <= 20 us; 1 kHz output with < 10 % of a core.
Issue 13: the sender ramps each frame at the drive within the speed and acceleration limits
(``limits``, as ``--output`` always does): its cost per frame, and 1 kHz with and without it.
The ramp's tracking, offline (:func:`ramp_tracking`): how far behind a moving command the
drive is, and how far past a command that comes to rest it goes, when the sender samples the
pipeline's commands at about their own rate with jitter.
"""

from __future__ import annotations

import argparse
import os
import pty
import select
import socket
import sys
import threading
import time
import tty
from pathlib import Path

import numpy as np

from motionbase.io import motor_output
from motionbase.io.motor_output import Drive, open_output
from motionbase.platform import OutputMapping
from motionbase.platform.output_map import sweep_profile
from motionbase.safety import ActuatorLimits

# the tests' own measure of a drive past a command at rest, one definition for both
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from drive_wire import past_rest  # noqa: E402

LO, HI = np.radians(np.full(6, -60.0)), np.radians(np.full(6, 60.0))
MAPPINGS = {
    "range": OutputMapping.from_dict(
        {"unit": "range", "sign": [1, -1] * 3, "range_lo": 0, "range_hi": 4095},
        angle_min=LO,
        angle_max=HI,
    ),
    "counts": OutputMapping.from_dict(
        {"unit": "counts", "counts_per_rev": 131072, "gear_ratio": 10.0},
        angle_min=LO,
        angle_max=HI,
    ),
}
FORMATS = {
    "text A{1}B{2}..": ("text:A%7B1%7DB%7B2%7DC%7B3%7DD%7B4%7DE%7B5%7DF%7B6%7D%5Cn", "range"),
    "text {1:04X}..": (
        "text:%7B1:04X%7D%7B2:04X%7D%7B3:04X%7D%7B4:04X%7D%7B5:04X%7D%7B6:04X%7D",
        "range",
    ),
    "bin 6xu16be sum8": ("bin:0xFFFE,6xu16be,sum8@2", "range"),
    "bin 6xi32le crc16": ("bin:0xAA55,6xi32le,crc16", "counts"),
}


class Drain:
    """Reads and discards whatever arrives (a UDP socket or a pty master)."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.count = 0
        self.stamps: list[float] = []
        if kind == "udp":
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind(("127.0.0.1", 0))
            self.sock.settimeout(0.05)
            self.where = f"udp:127.0.0.1:{self.sock.getsockname()[1]}"
        else:
            self.master, self.slave = pty.openpty()
            tty.setraw(self.slave)
            self.where = f"serial:{os.ttyname(self.slave)}"
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if self.kind == "udp":
                try:
                    self.sock.recv(4096)
                except TimeoutError:
                    continue
                self.count += 1
                self.stamps.append(time.perf_counter())
            else:
                r, _, _ = select.select([self.master], [], [], 0.05)
                if r:
                    os.read(self.master, 65536)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(1)
        if self.kind == "udp":
            self.sock.close()
        else:
            os.close(self.master)
            os.close(self.slave)


def per_frame(n: int = 20000) -> None:
    rng = np.random.default_rng(1)
    qs = rng.uniform(-1.0, 1.0, size=(n, 6))
    print("one frame (us per frame, median / p99), 6 motors:")
    print(
        f"  {'format':<20} {'map+check+encode':>18} {'send udp':>12} {'send pty':>12} {'total':>8}"
    )
    for name, (fmt, mkey) in FORMATS.items():
        m = MAPPINGS[mkey]
        row = []
        drains = {k: Drain(k) for k in ("udp", "pty")}
        try:
            sinks = {k: open_output(f"{d.where}?rate=1&format={fmt}", m) for k, d in drains.items()}
            for s in sinks.values():
                s.open()
            sink = sinks["udp"]
            t = np.empty(n)
            for i in range(n):  # the pipeline's side: MotorOutput.write
                t0 = time.perf_counter_ns()
                sink.write(qs[i])
                t[i] = time.perf_counter_ns() - t0
            enc = t / 1e3
            frame = sink._command[1]
            sends = {}
            for k, s in sinks.items():
                tr = s.transport
                ts = np.empty(n)
                for i in range(n):
                    t0 = time.perf_counter_ns()
                    tr.send(frame)
                    ts[i] = time.perf_counter_ns() - t0
                    if k == "pty" and i % 200 == 199:
                        time.sleep(0.002)  # let the reader keep the pty buffer from filling
                sends[k] = ts / 1e3
            for s in sinks.values():
                s.close()
        finally:
            for d in drains.values():
                d.close()
        tot_u = np.median(enc) + np.median(sends["udp"])
        tot_p = np.median(enc) + np.median(sends["pty"])
        row = (
            f"  {name:<20} {np.median(enc):8.1f} / {np.percentile(enc, 99):6.1f}"
            f" {np.median(sends['udp']):5.1f} / {np.percentile(sends['udp'], 99):5.1f}"
            f" {np.median(sends['pty']):5.1f} / {np.percentile(sends['pty'], 99):5.1f}"
            f" {tot_u:6.1f} / {tot_p:5.1f}"
        )
        print(row)


def _thread_cpu_s(tid: int) -> float:
    with open(f"/proc/self/task/{tid}/stat") as fh:
        parts = fh.read().rsplit(")", 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


LIMITS = ActuatorLimits.broadcast(6, LO, HI, 3.0, 30.0)  # the ceart preset's crank limits


def ramp_step(n: int = 20000) -> None:
    """The sender's work per frame when it ramps the drive within its limits."""
    fmt, mkey = FORMATS["bin 6xu16be sum8"]
    sink = open_output(f"udp:127.0.0.1:9?rate=1000&format={fmt}", MAPPINGS[mkey], limits=LIMITS)
    sink.write(np.zeros(6))
    sink.write(np.full(6, 1.0))  # a far command: every frame is limited, mapped and encoded anew
    command = sink._command
    start = Drive(np.zeros(6), np.zeros(6), time.monotonic())
    sink._drive = start
    t = np.empty(n)
    for i in range(n):
        now = sink._drive.t + 1e-3
        t0 = time.perf_counter_ns()
        q, v, _ = motor_output.ramp_step(
            sink._drive, command, now, period=1e-3, command_dt=sink.command_dt, limits=sink.limits
        )
        if q is not command.angles:  # what the sender does with a frame short of the command
            sink._encode(sink.mapping.to_drive(q))
        t[i] = time.perf_counter_ns() - t0
        sink._drive = Drive(q, v, now)
        if q is command.angles:
            sink._drive = start._replace(t=now)
    us = t / 1e3
    print(
        f"ramp at the drive (ramp_command + map + encode of a limited frame), us per frame: "
        f"median {np.median(us):.1f}, p99 {np.percentile(us, 99):.1f}"
    )


def ramp_tracking(
    command_hz: float = 200.0,
    frame_hz: float = 200.0,
    speed_deg_s: float = 60.0,
    jitter: float = 0.3,
    trials: int = 20,
) -> None:
    """The drive-side ramp fed offline as a paced run feeds it: the pipeline's commands at
    ``command_hz``, each written up to ``jitter`` of its period after its due time, sampled
    by frames at ``frame_hz`` with the same jitter (seeded: ``trials`` phases).

    * lag: a move at half the acceleration limit to ``speed_deg_s``, 0.5 s at that speed,
      braking to rest; in the cruise, how long after the command was at the drive's
      position (its due time, on the pipeline's schedule) the drive is there: mean, and the
      worst frame. The latest command's own age at the frames (what a drive that jumped to
      it would lag) is given beside it.
    * past rest: the wiring check's sweep (``sweep_profile``, +-5 deg at that speed) and the
      move above: how far the drive goes past a command that comes to rest.
    """
    tick, period = 1.0 / command_hz, 1.0 / frame_hz
    rng = np.random.default_rng(7)
    speed, accel = np.radians(speed_deg_s), 0.5 * float(LIMITS.max_accel[0])
    t_acc, cruise = speed / accel, 0.5
    t = np.arange(0.0, 2 * t_acc + cruise + 0.3, tick)
    t1 = np.clip(t, 0, t_acc)
    t2 = np.clip(t - t_acc, 0, cruise)
    t3 = np.clip(t - t_acc - cruise, 0, t_acc)
    x = 0.5 * accel * t1**2 + speed * t2 + speed * t3 - 0.5 * accel * t3**2
    move = np.repeat(x[:, None] - 0.5 * x[-1], 6, axis=1)
    sweep, _ = sweep_profile(
        np.full(6, np.radians(-55.0)), np.zeros(6), LO, HI, range_rad=np.radians(5.0),
        speed=speed, accel=accel, dt=tick, dwell_s=0.2,
    )  # fmt: skip
    lags, worst_lag, ages, past = [], [], [], []
    for _ in range(trials):
        phase = rng.uniform(0.0, period)
        for name, commands in (("move", move), ("sweep", sweep)):
            due = np.arange(len(commands)) * tick
            written = due + rng.uniform(0.0, jitter * tick, len(due))
            n = int((due[-1] + 0.5) / period)
            frames = np.arange(n) * period + phase + rng.uniform(0.0, jitter * period, n)
            ft, q, sampled = motor_output.ramp_offline(
                commands, written, frames, period=1.0 / frame_hz, command_dt=tick, limits=LIMITS
            )
            past.append(float(past_rest(commands, q, sampled).max()))
            if name == "move":
                cruising = (ft > t_acc + 0.1) & (ft < t_acc + cruise - 0.05)
                lag = ft[cruising] - np.interp(q[cruising, 0], commands[:, 0], due)
                lags.append(lag.mean())
                worst_lag.append(lag.max())
                ages.append(np.mean(ft[cruising] - due[sampled[cruising]]))
    print(
        f"  {command_hz:g} Hz commands, {frame_hz:g} Hz frames, {speed_deg_s:g} deg/s: lag mean "
        f"{1e3 * np.mean(lags):.2f} ms, worst frame {1e3 * np.max(worst_lag):.2f} ms (the "
        f"latest command's age {1e3 * np.mean(ages):.2f} ms); past a command at rest: worst "
        f"{np.degrees(np.max(past)):.4f} deg, in {sum(p > 1e-9 for p in past)} of {len(past)}"
    )


def sustained(rate_hz: float = 1000.0, seconds: float = 5.0, ramped: bool = True) -> None:
    fmt, mkey = FORMATS["bin 6xu16be sum8"]
    drain = Drain("udp")
    sink = open_output(
        f"{drain.where}?rate={rate_hz:g}&format={fmt}",
        MAPPINGS[mkey],
        limits=LIMITS if ramped else None,
    )
    pipeline_rate = 120.0
    stop = threading.Event()

    def pipeline() -> None:  # a 120 Hz pipeline offering new commands
        k = 0
        while not stop.is_set():
            sink.write(np.full(6, 0.5 * np.sin(k / pipeline_rate)))
            k += 1
            time.sleep(1 / pipeline_rate)

    with sink:
        tid = sink._thread.native_id
        writer = threading.Thread(target=pipeline, daemon=True)
        writer.start()
        time.sleep(0.5)
        c0, n0, w0 = _thread_cpu_s(tid), sink.frames_sent, time.perf_counter()
        p0 = time.process_time()
        time.sleep(seconds)
        c1, n1, w1 = _thread_cpu_s(tid), sink.frames_sent, time.perf_counter()
        p1 = time.process_time()
        stop.set()
        writer.join()
    drain.close()
    wall = w1 - w0
    stamps = np.array([s for s in drain.stamps if w0 <= s <= w1])
    gaps = np.diff(stamps) * 1e3
    print(
        f"sustained {rate_hz:g} Hz over UDP for {wall:.1f} s (pipeline writing at 120 Hz), "
        f"{'ramped at the drive' if ramped else 'latest command as it is'}: "
        f"{(n1 - n0) / wall:.1f} frames/s sent, {len(stamps) / wall:.1f} received"
    )
    print(
        f"  sender thread CPU {100 * (c1 - c0) / wall:.1f} % of a core "
        f"(whole process incl. writer and receiver {100 * (p1 - p0) / wall:.1f} %)"
    )
    print(
        f"  interval ms: median {np.median(gaps):.3f}, p1 {np.percentile(gaps, 1):.3f}, "
        f"p99 {np.percentile(gaps, 99):.3f}, max {gaps.max():.3f}"
    )


if __name__ == "__main__":
    # (no options: --help prints what it measures instead of running it)
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    per_frame()
    ramp_step()
    print("ramp at the drive, offline (commands and frames each up to 0.3 of a period late):")
    ramp_tracking()  # motionbase output --test --rate 200 --speed-deg-s 60
    ramp_tracking(speed_deg_s=150.0)
    ramp_tracking(120.0, 100.0)  # fly --output's defaults
    sustained(ramped=False)
    sustained(ramped=True)
