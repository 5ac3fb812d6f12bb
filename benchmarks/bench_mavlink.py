"""MAVLink source speed: sustained input, CPU share, per-message cost, latency.

Run: python benchmarks/bench_mavlink.py [--seconds 10]

1. Live: a pymavlink sender in another *process* sends HIGHRES_IMU and
   ATTITUDE alternately at 1,000 messages/s over loopback UDP; the source ticks
   at 250 Hz. Reports the input rate received, the CPU share of the receiving
   process (time.process_time / wall time), the CPU cost per message, and the
   latency from a message's parse to the yield of the tick holding it
   (arrival -> state handed to the pipeline; the issue's 5 ms budget also
   covers washout, IK and logging, measured by the pipeline benchmark).
2. Per-message parse cost, offline: pymavlink decode + mavutil bookkeeping +
   the source's filter and unit conversion, on pre-packed messages.
3. Log replay as fast as possible: ticks per second from erle_plane_329.BIN, a real log the
   repository does not ship: ``MOTIONBASE_TEST_DATA`` names its folder (as for the tests;
   ``MOTIONBASE_TEST_DATA=../shared/data``); skipped when unset.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np

from motionbase.io.mavlink_source import MavlinkSource, mavutil

#: The folder of the real flight logs (not in the repository), as for the tests.
DATA_ENV = "MOTIONBASE_TEST_DATA"


def _send(port: int, msg_rate: float, seconds: float) -> None:
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=1
    )
    mav = conn.mav
    t0 = time.monotonic()
    i = 0
    n = int(msg_rate * seconds)
    while i < n:
        x = 0.001 * i
        if i % 2 == 0:
            mav.highres_imu_send(i, x, 0.1, -9.8, 0.01, 0.02, x, 0, 0, 0, 0, 0, 0, 0, 0x3F)
        else:
            mav.attitude_send(i, 0.1, 0.05, x % 3.0, 0.01, 0.02, 0.03)
        i += 1
        delay = t0 + i / msg_rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    conn.close()


def bench_live(seconds: float, rate_hz: float, msg_rate: float) -> None:
    warmup = 1.0
    with MavlinkSource(
        "udpin:127.0.0.1:0",
        rate_hz=rate_hz,
        duration_s=seconds + warmup + 5.0,
        request_streams=False,
    ) as src:
        port = src.local_address[1]
        proc = mp.get_context("spawn").Process(
            target=_send, args=(port, msg_rate, seconds + warmup + 4.0)
        )
        proc.start()
        lat: list[float] = []
        phase, warm_until = "wait", 0.0
        cpu0 = wall0 = 0.0
        acc0 = ticks = stale = 0
        for _ in src:
            now = time.monotonic()
            if phase == "wait":  # until the sender process is up
                if src.stats.accepted > 0:
                    phase, warm_until = "warm", now + warmup
                continue
            if phase == "warm":
                if now >= warm_until:
                    phase = "measure"
                    cpu0, wall0, acc0 = time.process_time(), now, src.stats.accepted
                continue
            ticks += 1
            tick = src.tick
            stale += not tick.fresh
            if tick.new_sample:
                lat.append(now - tick.arrival_s)
            if now - wall0 >= seconds:
                break
        cpu = time.process_time() - cpu0
        wall = time.monotonic() - wall0
        stats = src.stats
        n_msgs = stats.accepted - acc0
    proc.join(timeout=10)
    lat_ms = np.array(lat) * 1e3
    print(
        f"live: {seconds:.0f} s, source at {rate_hz:.0f} Hz, "
        f"sender {msg_rate:.0f} msg/s (HIGHRES_IMU+ATTITUDE, another process)"
    )
    print(f"  messages received      {n_msgs / wall:8.0f} msg/s  ({n_msgs} in {wall:.2f} s)")
    print(f"  ticks yielded          {ticks / wall:8.1f} Hz  (late ticks {stats.late_ticks})")
    print(f"  CPU share (process)    {100 * cpu / wall:8.1f} % of one core")
    print(
        f"  CPU per message        {1e6 * cpu / max(n_msgs, 1):8.1f} us "
        "(all source work incl. ticks / messages)"
    )
    print(
        f"  parse->yield latency   p50 {np.percentile(lat_ms, 50):.2f} ms, "
        f"p99 {np.percentile(lat_ms, 99):.2f} ms, max {lat_ms.max():.2f} ms "
        f"(tick period {1e3 / rate_hz:.1f} ms)"
    )
    print(
        f"  rejected {stats.rejected}, bad_data {stats.bad_data}, "
        f"stale ticks {stale} while measuring ({stats.stale_ticks} in all, startup included)"
    )


class _Sink:
    def __init__(self) -> None:
        self.buf = bytearray()

    def write(self, b: bytes) -> None:
        self.buf += b


def bench_parse(n: int = 20000) -> None:
    sink = _Sink()
    enc = mavutil.mavlink.MAVLink(sink, srcSystem=1, srcComponent=1)
    packets = []
    for i in range(n):
        start = len(sink.buf)
        if i % 2 == 0:
            enc.highres_imu_send(i, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0, 0, 0, 0, 0, 0, 0, 0x3F)
        else:
            enc.attitude_send(i, 0.1, 0.05, 1.0, 0.01, 0.02, 0.03)
        packets.append(bytes(sink.buf[start:]))
    with MavlinkSource("udpin:127.0.0.1:0", request_streams=False) as src:
        conn = src._conn
        parse, post, handle = conn.mav.parse_char, conn.post_message, src._handle
        t0 = time.perf_counter()
        for p in packets:
            parse(p)
        t_decode = time.perf_counter() - t0
        t0 = time.perf_counter()
        for p in packets:
            m = parse(p)
            post(m)
            handle(m, 0.0)
        t_all = time.perf_counter() - t0
        assert src.stats.used == n
    print(f"parse (offline, {n} messages, HIGHRES_IMU/ATTITUDE):")
    print(f"  pymavlink decode only  {1e6 * t_decode / n:8.1f} us/message")
    print(f"  decode+mavutil+source  {1e6 * t_all / n:8.1f} us/message")


def bench_log() -> None:
    folder = os.environ.get(DATA_ENV, "")
    if not folder:
        print(f"log replay: {DATA_ENV} is unset (the folder of erle_plane_329.BIN), skipped")
        return
    path = Path(folder).expanduser().resolve() / "erle_plane_329.BIN"
    if not path.is_file():
        print(f"log replay: {path} not found, skipped")
        return
    t0 = time.perf_counter()
    with MavlinkSource(str(path), rate_hz=250.0, realtime=False) as src:
        n = sum(1 for _ in src)
        msgs = src.stats.received
    dt = time.perf_counter() - t0
    print("log replay (erle_plane_329.BIN, as fast as possible, 250 Hz ticks):")
    print(f"  {n} ticks + {msgs} records in {dt:.2f} s = {n / dt:,.0f} ticks/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="live measurement time, s")
    ap.add_argument("--rate", type=float, default=250.0, help="source tick rate, Hz")
    ap.add_argument("--msg-rate", type=float, default=1000.0, help="sender rate, msg/s")
    args = ap.parse_args()
    bench_live(args.seconds, args.rate, args.msg_rate)
    bench_parse()
    bench_log()


if __name__ == "__main__":
    main()
