"""False cues and crank limits on real MAVLink logs (issue 13, item 18).

Run: MOTIONBASE_TEST_DATA=/path/to/data python benchmarks/bench_false_cues.py

The two real logs, ``vtol.tlog`` (ArduPlane SITL telemetry, ATTITUDE and
SCALED_IMU2 at about 4 Hz) and ``erle_plane_329.BIN`` (a DataFlash log of a real
flight), are streamed through the pipeline exactly as ``motionbase stream
--mavlink LOG --fast`` does (:func:`motionbase.app.stream` with its defaults for
MAVLink sources: 100 Hz, the ``ceart`` platform, the default washout for MAVLink
sources), logged to a temporary MCAP file, and the recording is read back through
the cue computation of ``motionbase report`` (:func:`motionbase.report.build_report`,
i.e. :func:`motionbase.washout.perception.platform_specific_force`).

The data directory is ``$MOTIONBASE_TEST_DATA`` (default ``../shared/data``
relative to the repository).

Definitions (per tick ``k`` of the running phase, per axis ``i`` in x, y, z)
-----------------------------------------------------------------------------
* aircraft deviation ``a = f_aircraft - (0, 0, -g)``: the specific force at the pilot
  the pipeline was given (held between messages, as the pipeline held it), minus
  level flight;
* platform deviation ``p = f_cab - (0, 0, -g)``, where ``f_cab = R^T (x'' - (0, 0, g))``
  is the specific force of the realised platform pose (``/platform/pose``, after
  fades, clamping and the limiter) by central second differences at the pipeline
  period: the cue the seated pilot gets, translational acceleration plus the
  gravity component of the tilt;
* the *false part* of the cue, m/s^2::

      false = |p|                    if sign(p) != sign(a)  (the other way, or the
                                                              aircraft gives nothing)
      false = max(0, |p| - |a|)      otherwise              (beyond the aircraft's own)

  i.e. how much of the platform's cue the aircraft did not have at that instant;
* a *false cue* is a tick and axis whose false part exceeds the perception threshold
  (0.17, 0.17, 0.28 m/s^2, :data:`motionbase.washout.perception.THRESHOLD_SPECIFIC_FORCE`);
  the *peak false cue* is the largest false part over the run (m/s^2, with its axis
  and time). A classical washout's return lobe and the lag of tilt coordination give
  small false parts by design (well below 1 m/s^2); the limiter braking a crank, a
  fade rescaling the pose or a clamp snapping it give large ones.

Also printed: the peak false cue on the ticks the watchdog was fading (``fade`` < 1), the
share of ticks with a false cue, the report's perceived false-cue
share (otolith model, :class:`~motionbase.washout.perception.CueingMetrics`), the
time with any crank within 1 deg of its limit, the clamped and rate-limited tick
counts, the largest crank angle reached during the running phase, the watchdog's
faded share, and the workspace usage per axis (largest excursion as a share of the
single-axis reach, the report's figure).

``--fly SCRIPT ...`` measures JSBSim flights (``motionbase fly SCRIPT``, default
platform and washout) the same way instead of the logs, e.g. ``--fly c1723
c172_elevator_doublet`` (issue 13, item 16: the clamping and crank angles of the
default flights on the ``ceart`` geometry). ``--washout NAME`` runs either with another
washout preset (or TOML path) instead of the default.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

LOGS = ("vtol.tlog", "erle_plane_329.BIN")
NEAR_LIMIT_DEG = 1.0
AXES = ("surge", "sway", "heave", "roll", "pitch", "yaw")


def data_dir() -> Path:
    """The real-log directory: ``$MOTIONBASE_TEST_DATA`` or ``../shared/data``."""
    env = os.environ.get("MOTIONBASE_TEST_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


@dataclass
class FalseCues:
    """The figures of one run (see the module docstring)."""

    name: str
    seconds: float
    peak_false: float
    peak_axis: str
    peak_t: float
    peak_fading: float
    false_share: float
    perceived_false: np.ndarray
    near_limit_s: float
    clamped: int
    rate_limited: int
    ticks: int
    peak_crank_deg: float
    faded_share: float
    usage: np.ndarray


def false_part(aircraft_dev: np.ndarray, platform_dev: np.ndarray) -> np.ndarray:
    """The part of the platform's cue the aircraft did not have (module docstring), m/s^2."""
    same = np.sign(platform_dev) == np.sign(aircraft_dev)
    beyond = np.maximum(np.abs(platform_dev) - np.abs(aircraft_dev), 0.0)
    return np.where(same, beyond, np.abs(platform_dev))


def measure(mcap_path: Path, name: str) -> FalseCues:
    """The false-cue figures of a recording."""
    from motionbase.io.mcap_source import read_messages, read_metadata
    from motionbase.physics import STANDARD_GRAVITY
    from motionbase.report import build_report
    from motionbase.washout.perception import THRESHOLD_SPECIFIC_FORCE

    r = build_report(read_messages(mcap_path), read_metadata(mcap_path), name=name)
    level = np.array([0.0, 0.0, -STANDARD_GRAVITY])
    run = r.running
    fp = false_part(r.aircraft_f[run] - level, r.cue_f[run] - level)
    k, axis = np.unravel_index(int(np.argmax(fp)), fp.shape)
    fade = r.fade[np.searchsorted(r.tick_t, r.t[run])]
    fading = fp[fade < 1.0]
    false = fp > THRESHOLD_SPECIFIC_FORCE
    lo, hi = r.actuator_limits
    margin = np.radians(NEAR_LIMIT_DEG)
    near = ((r.actuators - lo < margin) | (hi - r.actuators < margin)).any(axis=1)
    running_ticks = r.phase == "running"
    return FalseCues(
        name=name,
        seconds=float(r.t[-1] - r.t[0]),
        peak_false=float(fp[k, axis]),
        peak_axis="xyz"[axis],
        peak_t=float(r.t[run][k]),
        peak_fading=float(fading.max()) if fading.size else 0.0,
        false_share=float(false.any(axis=1).mean()),
        perceived_false=r.metrics.false_cue_specific_force,
        near_limit_s=float(near.sum() * r.dt),
        clamped=int(r.clamped.sum()),
        rate_limited=int(r.rate_limited.sum()),
        ticks=int(r.tick_t.size),
        peak_crank_deg=float(np.degrees(np.abs(r.actuators[running_ticks]).max())),
        faded_share=float((r.fade < 1.0).mean()),
        usage=r.metrics.workspace_usage,
    )


def run_log(path: Path, out: Path, washout: str | None = None) -> float:
    """Stream ``path`` through the pipeline as ``motionbase stream --fast`` does; wall s."""
    from motionbase.app import stream

    t0 = time.perf_counter()
    stream(str(path), realtime=False, out=out, progress=False, washout=washout)
    return time.perf_counter() - t0


def fly_script(script: str, out: Path, washout: str | None = None) -> float:
    """Fly a JSBSim script as ``motionbase fly SCRIPT --out OUT`` does; wall s."""
    from motionbase.app import fly

    t0 = time.perf_counter()
    fly(script, out=out, progress=False, washout=washout)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, help="keep the recordings in this folder")
    parser.add_argument("--fly", nargs="+", metavar="SCRIPT", help="JSBSim scripts instead")
    parser.add_argument("--washout", help="washout preset or TOML path instead of the default")
    args = parser.parse_args(argv)
    import logging

    logging.getLogger("motionbase").setLevel(logging.ERROR)  # no stale-link warnings
    data = data_dir()
    missing = [n for n in LOGS if not (data / n).is_file()]
    if missing and not args.fly:
        print(
            f"bench_false_cues: {', '.join(missing)} not found in {data}; set "
            "MOTIONBASE_TEST_DATA to the folder holding the real logs (e.g. ../shared/data)",
            file=sys.stderr,
        )
        return 2
    results = []
    with tempfile.TemporaryDirectory(prefix="motionbase-false-cues-") as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for name in args.fly or LOGS:
            out = folder / (Path(name).stem + ".mcap")
            if args.fly:
                wall = fly_script(name, out, args.washout)
            else:
                wall = run_log(data / name, out, args.washout)
            results.append(measure(out, name))
            print(f"{name}: ran in {wall:.1f} s wall", file=sys.stderr)
    header = (
        f"{'log':<20}{'peak false cue':>26}{'fading':>8}{'false':>8}{'perceived false x/y/z':>24}"
        f"{'near limit':>12}{'clamped':>9}{'rate-lim':>10}{'peak crank':>12}{'faded':>7}"
    )
    print(header)
    for r in results:
        pf = "/".join(f"{100 * v:.1f}" for v in r.perceived_false)
        peak = f"{r.peak_false:.2f} m/s^2 {r.peak_axis} @{r.peak_t:.1f}s"
        print(
            f"{r.name:<20}{peak:>26}{r.peak_fading:>8.2f}{100 * r.false_share:>7.1f}%"
            f"{pf + ' %':>24}"
            f"{r.near_limit_s:>10.2f} s{r.clamped:>9d}{r.rate_limited:>10d}"
            f"{r.peak_crank_deg:>10.1f} d{100 * r.faded_share:>6.1f}%"
        )
    print(f"{'workspace usage %':<20}" + "".join(f"{a:>8}" for a in AXES))
    for r in results:
        print(f"{r.name:<20}" + "".join(f"{100 * u:>8.0f}" for u in r.usage))
    print(
        f"(false: share of running ticks with a false cue above threshold; near limit: time "
        f"with any crank within {NEAR_LIMIT_DEG:g} deg of its limit; counts over all ticks)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
