"""`motionbase stream` speed: live MAVLink through the whole pipeline into the MCAP log.

Run: ``python benchmarks/bench_stream.py [--seconds 10]``

A pymavlink sender in another process sends HIGHRES_IMU and ATTITUDE alternately at
1,000 messages/s over loopback UDP; the pipeline runs at 250 Hz on the 6-RUS with the MCAP
log, exactly as ``motionbase stream --rate 250`` does. Prints the CPU share of the streaming
process (issue 6 target: under half a core) and the latency from a message's arrival to the
logged actuator command of the tick that carries it (target: p99 <= 5 ms).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_mavlink import _send

from motionbase import app
from motionbase.io.mavlink_source import MavlinkSource
from motionbase.io.pipeline_log import PipelineLog
from motionbase.pipeline import Pipeline, run


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    rate_hz, msg_rate, warmup = 250.0, 1000.0, 2.0
    config = app.load_config(rate_hz=rate_hz)
    pipeline = Pipeline(config)
    lat: list[float] = []
    mark: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        source = MavlinkSource(
            "udpin:127.0.0.1:0",
            rate_hz=rate_hz,
            duration_s=args.seconds + warmup + 3.0,
            request_streams=False,
        )
        with source:
            port = source.local_address[1]
            proc = mp.get_context("spawn").Process(
                target=_send, args=(port, msg_rate, args.seconds + warmup + 2.0)
            )
            proc.start()

            def on_tick(out) -> None:
                # called after every sink has written this tick: the command is logged
                now = time.monotonic()
                if "start" not in mark:
                    if source.stats.accepted == 0:
                        return
                    mark["start"] = now
                if not warmup <= now - mark["start"] <= warmup + args.seconds:
                    return  # measure while the sender sends, after a warm-up
                if "cpu0" not in mark:
                    mark["cpu0"], mark["wall0"] = time.process_time(), now
                    mark["acc0"] = source.stats.accepted
                tick = source.tick
                if tick.new_sample:
                    lat.append(now - tick.arrival_s)
                mark["cpu1"], mark["wall1"] = time.process_time(), now
                mark["acc1"] = source.stats.accepted

            meta = app.run_metadata(config, source)
            health = pipeline.health.as_dict
            with PipelineLog(Path(tmp) / "s.mcap", meta, health=health) as log:
                run(pipeline, source, [log], paced=True, progress=on_tick)
        proc.join(timeout=10)
    wall = mark["wall1"] - mark["wall0"]
    cpu = mark["cpu1"] - mark["cpu0"]
    msgs = mark["acc1"] - mark["acc0"]
    lat_ms = np.array(lat) * 1e3
    print(
        f"stream: {wall:.1f} s measured, pipeline at {rate_hz:.0f} Hz on the 6-RUS with MCAP log, "
        f"sender {msg_rate:.0f} msg/s in another process"
    )
    print(f"  messages accepted       {msgs / wall:8.0f} msg/s")
    print(f"  CPU share (process)     {100 * cpu / wall:8.1f} % of one core   (target < 50 %)")
    print(
        f"  arrival -> logged command latency: p50 {np.percentile(lat_ms, 50):.2f} ms, "
        f"p99 {np.percentile(lat_ms, 99):.2f} ms, max {lat_ms.max():.2f} ms   (target p99 <= 5 ms)"
    )
    print(f"  worst loop overrun {1e3 * pipeline.health.worst_overrun_s:.2f} ms")


if __name__ == "__main__":
    main()
