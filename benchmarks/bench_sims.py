"""FlightGear and X-Plane sources: packet-to-command latency at 100 Hz input.

Run: ``python benchmarks/bench_sims.py [--seconds 10] [--rates 100,1000] [--busy-wait]``

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
from motionbase.pipeline import Pipeline, run

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="measurement time per run, s")
    ap.add_argument("--rates", default="100,1000", help="pipeline rates to run, Hz (comma list)")
    ap.add_argument("--busy-wait", action="store_true", help="busy-wait between ticks")
    args = ap.parse_args()
    logging.getLogger("motionbase").setLevel(logging.ERROR)  # the senders' end is not news
    rates = [float(r) for r in args.rates.split(",")]
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
