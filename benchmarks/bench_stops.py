"""How gently a stop during the soft start goes back to park (field-test review, session 27).

For each robot, level flight through the default pipeline at 120 Hz: first a whole soft
start (its peak actuator speed and acceleration are the yardstick), then runs stopped at a
share of the soft start. For each: the peak actuator speed and acceleration from the
commands (finite differences from park at rest), the ticks the safety limiter had to change,
and the time to park. The actuators' own limits are printed beside them.

Run: .venv/bin/python benchmarks/bench_stops.py
"""

from __future__ import annotations

import argparse

import numpy as np

from motionbase.app import load_config
from motionbase.physics import STANDARD_GRAVITY
from motionbase.pipeline import Pipeline
from motionbase.state import AircraftState

SHARES = (0.02, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99)
LEVEL = ([0.0, 0.0, -STANDARD_GRAVITY], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])


def _peaks(pipeline: Pipeline, angles: list[np.ndarray]) -> tuple[float, float]:
    park = pipeline.robot.park_angles
    q = np.array([park, park, *angles])
    v = np.diff(q, axis=0) / pipeline.dt
    a = np.diff(v, axis=0) / pipeline.dt
    return float(np.abs(v).max()), float(np.abs(a).max())


def _run(pipeline: Pipeline, ticks: int, stop: bool) -> tuple[list, int, int]:
    pipeline.reset()
    out = [pipeline.step(AircraftState(i * pipeline.dt, *LEVEL)) for i in range(ticks)]
    if not stop:
        return out, 0, 0
    pipeline.stop()
    limited = back = 0
    while not pipeline.parked and back < 10_000:
        back += 1
        o = pipeline.step(AircraftState((ticks + back) * pipeline.dt, *LEVEL))
        limited += o.rate_limited
        out.append(o)
    return out, limited, back


def main() -> None:
    print("A stop during the soft start: level flight, default pipeline, 120 Hz")
    for platform, unit in (("rus6", "rad"), ("stewart6", "m")):
        pipeline = Pipeline(load_config(platform=platform, rate_hz=120.0))
        soft, dt, lim = pipeline.config.soft_start_s, pipeline.dt, pipeline.robot.limits
        start, _, _ = _run(pipeline, int(soft / dt) + 30, stop=False)
        v, a = _peaks(pipeline, [o.angles for o in start])
        print(
            f"  {platform}: limits {lim.max_speed.max():g} {unit}/s, "
            f"{lim.max_accel.max():g} {unit}/s^2; a whole soft start ({soft:g} s): "
            f"peak {v:.3f} {unit}/s, {a:.3f} {unit}/s^2"
        )
        for share in SHARES:
            out, limited, back = _run(pipeline, int(round(share * soft / dt)), stop=True)
            v, a = _peaks(pipeline, [o.angles for o in out])
            print(
                f"    stopped at {share:4.2f} of the start: peak {v:.3f} {unit}/s, "
                f"{a:.3f} {unit}/s^2; limiter acted on {limited:2d} ticks; "
                f"parked {back * dt:.2f} s after the stop"
            )


if __name__ == "__main__":
    # (no options: --help prints what it measures instead of running it)
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    main()
