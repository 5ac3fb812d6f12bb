"""FlightGear and X-Plane sources: packet-to-command latency at 100 Hz input.

Run: ``python benchmarks/bench_sims.py [--seconds 10] [--rates 100,1000] [--busy-wait]
[--flood]``

As ``bench_stream.py`` does for MAVLink: a sender in another *process* sends
100 packets/s over loopback UDP, and the pipeline runs on them exactly as
``motionbase stream --source URL --rate R`` does (6-RUS, washout, safety, MCAP
log). For each packet, the latency runs from the sender's ``time.monotonic()``
just before ``sendto`` to the moment the first tick holding it has been
processed and written to the log (the progress callback, called after every
sink). The packet's sequence number rides in its heading, so every tick knows
which packet it holds.

* FlightGear: ``FGNetFDM`` version 24 datagrams, as ``--native-fdm=socket,out,100,...``
  sends them.
* X-Plane: the sender answers the source's RREF subscriptions like an X-Plane
  running at 100 frames per second (one answer per frame at most, whatever
  rate is asked), all nine datarefs in one datagram.

The source holds the latest packet until its next tick, so a packet waits for
that tick: up to one pipeline period (10 ms at 100 Hz, 1 ms at 1 kHz) plus the
tick's own work. At a pipeline rate equal to the input rate the wait is the
phase between the two clocks, fixed within a run and random between runs.

``--flood`` measures something else: how late commands get while a flood of
datagrams hits the port (anyone who can reach it can send one). Good samples
come at 100 per second from one process while another sends junk as fast as it
can (FlightGear: NaN packets, rejected; MAVLink, the same drain through
pymavlink: HIGHRES_IMU frames from another system id) for ``--seconds``; a stop
is asked half a second before the flood ends. Prints, from the flood's start to
the end of the run (the stop ramp included), the worst and 99th-percentile delay
from a tick's due time to its command being out (more than one period is a late
command), how many were late, and how long the stop took to reach the platform
(the first tick of the stop ramp). On a machine shared with other work, the
delays include the time other processes held the processor.
"""

from __future__ import annotations

import argparse
import logging
import math
import multiprocessing as mp
import socket
import struct
import tempfile
import time
from pathlib import Path

import numpy as np

from motionbase import app
from motionbase.io.pipeline_log import PipelineLog
from motionbase.io.sources import open_live_source
from motionbase.pipeline import Pipeline, StopRequest, run

INPUT_HZ = 100.0
RING = 3600  # send times kept by sequence number modulo RING (36 s at 100 packets/s)
HEADING_STEP_DEG = 0.1  # sequence number k rides as heading (k mod RING) * 0.1 deg


def _heading_deg(k: int) -> float:
    return (k % RING) * HEADING_STEP_DEG


def _seq_from_yaw(yaw_rad: float) -> int:
    deg = math.degrees(yaw_rad % (2.0 * math.pi))
    return int(round(deg / HEADING_STEP_DEG)) % RING


def _fg_packet(k: int) -> bytes:
    """FGNetFDM v24 (net_fdm.hxx): header, position, angles, velocities, accelerations, zeros."""
    head = struct.pack(
        ">II3d6f11f3f",
        24,
        0,
        0.0,
        0.0,
        100.0,
        10.0,
        0.05,  # phi
        0.02,  # theta
        math.radians(_heading_deg(k)),  # psi
        0.0,
        0.0,
        *([0.0] * 11),
        0.5,
        0.0,
        -32.174,  # A_*_pilot, ft/s^2
    )
    return head + bytes(408 - len(head))


def _send_fg(port: int, seconds: float, send_times) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    t0 = time.monotonic()
    k = 0
    while k < int(seconds * INPUT_HZ):
        pkt = _fg_packet(k)
        send_times[k % RING] = time.monotonic()
        sock.sendto(pkt, ("127.0.0.1", port))
        k += 1
        delay = t0 + k / INPUT_HZ - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    sock.close()


def _xplane_values(k: int) -> list[tuple[int, float]]:
    # the source's RREF indices are 1700 + slot (g_axil, g_side, g_nrml, P, Q, R, phi, theta, psi)
    values = [-0.05, 0.0, 1.0, 1.0, 0.5, -0.5, 3.0, 1.0, _heading_deg(k)]
    return [(1700 + i, v) for i, v in enumerate(values)]


def _serve_xplane(port_q, seconds: float, send_times) -> None:
    """An X-Plane at 100 frames/s: wait for RREF requests, then answer once per frame."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    port_q.put(sock.getsockname()[1])
    data, client = sock.recvfrom(2048)  # the first RREF request: "RREF\0" + freq + index + path
    assert data[:5] == b"RREF\0"
    sock.setblocking(False)
    t0 = time.monotonic()
    k = 0
    while k < int(seconds * INPUT_HZ):
        try:
            while True:
                sock.recvfrom(2048)  # further requests (subscriptions, resubscriptions)
        except BlockingIOError:
            pass
        pkt = b"RREF," + b"".join(struct.pack("<if", i, v) for i, v in _xplane_values(k))
        send_times[k % RING] = time.monotonic()
        sock.sendto(pkt, client)
        k += 1
        delay = t0 + k / INPUT_HZ - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    sock.close()


def bench(kind: str, rate_hz: float, seconds: float, busy_wait: bool) -> dict[str, float]:
    warmup = 2.0
    total = seconds + warmup + 3.0
    ctx = mp.get_context("spawn")
    send_times = ctx.Array("d", RING, lock=False)
    config = app.load_config(rate_hz=rate_hz)
    pipeline = Pipeline(config)
    if kind == "fgnative":
        url = "fgnative:udp:127.0.0.1:0"
    else:
        port_q = ctx.Queue()
        proc = ctx.Process(target=_serve_xplane, args=(port_q, total, send_times))
        proc.start()
        url = f"xplane:127.0.0.1:{port_q.get(timeout=30)}?listen=127.0.0.1:0"
    source = open_live_source(
        url,
        rate_hz=rate_hz,
        duration_s=total + 1.0,
        busy_wait=busy_wait,
        stale_timeout_s=config.stale_timeout_s,
    )
    lat: list[float] = []
    mark: dict[str, float] = {}
    last_seq = [-1]
    with tempfile.TemporaryDirectory() as tmp, source:
        if kind == "fgnative":
            proc = ctx.Process(target=_send_fg, args=(source.local_address[1], total, send_times))
            proc.start()

        def on_tick(out) -> None:
            now = time.monotonic()  # every sink has written this tick: the command is out
            if "start" not in mark:
                if source.stats.accepted == 0:
                    return
                mark["start"] = now
            if not warmup <= now - mark["start"] <= warmup + seconds:
                return
            if "cpu0" not in mark:
                mark["cpu0"], mark["wall0"] = time.process_time(), now
                mark["ticks0"] = source.stats.ticks
                mark["late0"] = source.stats.late_ticks
            if out.state is not None and source.tick.new_sample:
                seq = _seq_from_yaw(float(out.state.attitude[2]))
                if seq != last_seq[0]:
                    last_seq[0] = seq
                    lat.append(now - send_times[seq])
            mark["cpu1"], mark["wall1"] = time.process_time(), now
            mark["ticks1"] = source.stats.ticks
            mark["late1"] = source.stats.late_ticks

        meta = app.run_metadata(config, source)
        health = pipeline.health.as_dict
        with PipelineLog(Path(tmp) / "s.mcap", meta, health=health) as log:
            run(pipeline, source, [log], paced=True, busy_wait=busy_wait, progress=on_tick)
    proc.join(timeout=10)
    wall = mark["wall1"] - mark["wall0"]
    lat_ms = np.array(lat) * 1e3
    return {
        "packets": len(lat),
        "wall": wall,
        "cpu": 100.0 * (mark["cpu1"] - mark["cpu0"]) / wall,
        "p50": float(np.percentile(lat_ms, 50)),
        "p99": float(np.percentile(lat_ms, 99)),
        "max": float(lat_ms.max()),
        "late": mark["late1"] - mark["late0"],
        "overrun_ms": 1e3 * pipeline.health.worst_overrun_s,
    }


def _junk(kind: str) -> bytes:
    """One datagram of the flood: work for the source, nothing it may use."""
    if kind == "fgnative":
        packet = bytearray(_fg_packet(0))
        struct.pack_into(">f", packet, 36, math.nan)  # phi (net_fdm.hxx): refused
        return bytes(packet)
    from motionbase.io.mavlink_source import mavutil

    mav = mavutil.mavlink.MAVLink(None, srcSystem=7, srcComponent=1)  # another system
    msg = mav.highres_imu_encode(0, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 0, 0x3F)
    return bytes(msg.pack(mav))


def _send_flood(port: int, kind: str, start_s: float, seconds: float, count) -> None:
    """From ``start_s`` after the start, send junk datagrams as fast as possible for
    ``seconds``; the number sent goes in ``count``."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    pkt, addr = _junk(kind), ("127.0.0.1", port)
    time.sleep(start_s)
    t0 = time.monotonic()
    n = 0
    while time.monotonic() - t0 < seconds:
        for _ in range(100):
            try:
                sock.sendto(pkt, addr)
            except OSError:  # (a full buffer: the kernel drops, the flood goes on)
                pass
            n += 1
    count.value = n
    sock.close()


def bench_flood(kind: str, rate_hz: float, seconds: float) -> dict[str, float]:
    """Command delays while ``kind``'s port is flooded (see the module docstring)."""
    from bench_mavlink import _send as _send_mavlink

    warmup = 1.5
    ctx = mp.get_context("spawn")
    config = app.load_config(rate_hz=rate_hz)
    pipeline = Pipeline(config)
    if kind == "fgnative":
        source = open_live_source(
            "fgnative:udp:127.0.0.1:0", rate_hz=rate_hz, stale_timeout_s=config.stale_timeout_s
        )
    else:
        source = open_live_source(
            None,
            mavlink="udpin:127.0.0.1:0",
            rate_hz=rate_hz,
            stale_timeout_s=config.stale_timeout_s,
            request_streams=False,
        )
    stop = StopRequest()
    count = ctx.Value("q", 0)
    delays: list[float] = []
    mark: dict[str, float] = {}
    dt = 1.0 / rate_hz
    with tempfile.TemporaryDirectory() as tmp, source:
        port = source.local_address[1]
        total = warmup + seconds + 2.0
        if kind == "fgnative":
            good = ctx.Process(
                target=_send_fg, args=(port, total, ctx.Array("d", RING, lock=False))
            )
        else:
            good = ctx.Process(target=_send_mavlink, args=(port, 2 * INPUT_HZ, total))
        flood = ctx.Process(target=_send_flood, args=(port, kind, warmup, seconds, count))
        good.start()
        flood.start()
        t0 = time.monotonic()
        flood_from, flood_to = t0 + warmup + 0.2, t0 + warmup + seconds
        stop_at = flood_to - 0.5

        def on_tick(out) -> None:
            now = time.monotonic()  # every sink has written this tick: the command is out
            # from the flood's start to the end of the run (a tick held back by the flood
            # comes out after the flood has ended)
            if now >= flood_from and source.due_time is not None:
                delays.append(now - source.due_time)
            if now >= stop_at and not stop:
                stop.set("benchmark")
                mark["stop"] = now
            if "stop" in mark and "stopping" not in mark and out.phase != "running":
                mark["stopping"] = now

        meta = app.run_metadata(config, source)
        health = pipeline.health.as_dict
        with PipelineLog(Path(tmp) / "s.mcap", meta, health=health) as log:
            run(pipeline, source, [log], paced=True, stop=stop, progress=on_tick)
        stats = source.stats
    good.join(timeout=30)
    flood.join(timeout=30)
    d_ms = np.array(delays) * 1e3
    return {
        "flood": count.value,
        "ticks": len(delays),
        "worst": float(d_ms.max()),
        "p99": float(np.percentile(d_ms, 99)),
        "late": int(np.sum(d_ms > 1e3 * dt)),
        "stop_ms": 1e3 * (mark.get("stopping", math.nan) - mark.get("stop", math.nan)),
        "received": stats.received,
        "stale": stats.stale_ticks,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="measurement time per run, s")
    ap.add_argument("--rates", default="100,1000", help="pipeline rates to run, Hz (comma list)")
    ap.add_argument("--busy-wait", action="store_true", help="busy-wait between ticks")
    ap.add_argument(
        "--flood", action="store_true", help="command delays under a flood of datagrams instead"
    )
    args = ap.parse_args()
    logging.getLogger("motionbase").setLevel(logging.ERROR)  # the senders' end is not news
    rates = [float(r) for r in args.rates.split(",")]
    if args.flood:
        print(
            f"flood: junk datagrams as fast as one process sends them for {args.seconds:.0f} s, "
            f"good samples at {INPUT_HZ:.0f}/s; delay from a tick's due time to its command "
            "(late: more than one period)"
        )
        for kind in ("fgnative", "mavlink"):
            for rate in rates:
                r = bench_flood(kind, rate, args.seconds)
                print(
                    f"  {kind:8} pipeline {rate:6.0f} Hz (period {1e3 / rate:.0f} ms): "
                    f"worst {r['worst']:7.2f} ms  p99 {r['p99']:7.2f} ms  "
                    f"late commands {r['late']} of {r['ticks']}"
                    f"  stop reached the platform after {r['stop_ms']:.1f} ms"
                    f"  ({r['flood']} junk datagrams sent, {r['received']} read; "
                    f"{r['stale']} stale ticks)"
                )
        return
    print(
        f"packet -> logged command, sender at {INPUT_HZ:.0f} packets/s in another process, "
        f"6-RUS with MCAP log, {args.seconds:.0f} s per run"
        + (", busy-waiting" if args.busy_wait else "")
    )
    for kind in ("fgnative", "xplane"):
        for rate in rates:
            r = bench(kind, rate, args.seconds, args.busy_wait)
            print(
                f"  {kind:8} pipeline {rate:6.0f} Hz: p50 {r['p50']:6.2f} ms"
                f"  p99 {r['p99']:6.2f} ms"
                f"  max {r['max']:6.2f} ms  ({r['packets']} packets; CPU {r['cpu']:4.1f} %; "
                f"late ticks {r['late']}; worst overrun {r['overrun_ms']:.2f} ms)"
            )


if __name__ == "__main__":
    main()
