"""The platform never gives a cue the aircraft did not have (issue 13, item 18).

The cue is computed here, independently of :mod:`motionbase.washout.perception`, from the
poses the pipeline says the actuators realise: the cab's specific force
``R^T (x'' - (0, 0, g))`` (central second differences of the position, scipy's rotation
for ``R``, base axes FRD) and its body rates (finite differences of the rotation). The
watchdog's fades, a time jump, a stretch of rejected samples, the workspace clamp and the
limiter must add nothing the aircraft did not give: on the synthetic manoeuvres below the
aircraft never rotates, so the only rotation a correct platform makes is tilt
coordination, within the washout's tilt-rate limit; and its specific force never exceeds
the aircraft's own on any axis.

The real-log tests stream the two real MAVLink logs with the defaults of
``motionbase stream`` and require the cranks to stay off their limits; they need the
folder given by ``MOTIONBASE_TEST_DATA`` and are skipped, with that reason, without it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from motionbase.app import load_config
from motionbase.pipeline import Pipeline
from motionbase.state import AircraftState

G = 9.80665
RATE = 100.0
DT = 1.0 / RATE
#: The synthetic tests' washout: the SIMONA set (specific-force gains 0.5), whose cue stays
#: under the aircraft's with room to spare, so that what is measured is the fades, not the
#: washout. (The `ceart` default, tuned_ceart, renders sway at nearly its whole size: after
#: the time jump's restart from level flight its cue can overshoot the aircraft's sway.)
WASHOUT = "default"


def cab_specific_force(poses: np.ndarray, dt: float) -> np.ndarray:
    """Specific force in cab axes, m/s^2, (N-2, 3): R^T (x'' - (0, 0, g)) at the inner samples."""
    acc = (poses[2:, :3] - 2.0 * poses[1:-1, :3] + poses[:-2, :3]) / dt**2
    rot = Rotation.from_euler("ZYX", poses[1:-1, [5, 4, 3]])  # yaw, pitch, roll (intrinsic)
    return rot.inv().apply(acc - np.array([0.0, 0.0, G]))


def cab_body_rates(poses: np.ndarray, dt: float) -> np.ndarray:
    """Body rates of the cab, rad/s, (N-1, 3), from the relative rotation of consecutive poses."""
    rot = Rotation.from_euler("ZYX", poses[:, [5, 4, 3]])
    return (rot[:-1].inv() * rot[1:]).as_rotvec() / dt


def fly(pipeline: Pipeline, ticks) -> list:
    """Step ``pipeline`` through (t, f, w, fresh) ticks; return the outputs."""
    out = []
    for t, f, w, fresh in ticks:
        out.append(pipeline.step(AircraftState(t, f, w, (0.0, 0.0, 0.0)), fresh=fresh))
    return out


def manoeuvre(t: float) -> np.ndarray:
    """A turning, accelerating aircraft that never rotates: sustained forces and a wobble
    (within the default washout's reach: it is the fades that are under test)."""
    on = min(1.0, t / 3.0)
    return np.array(
        [
            1.6 * on + 0.4 * math.sin(1.3 * t),
            -1.6 * on + 0.3 * math.sin(0.9 * t + 1.0),
            -G - 1.0 * on + 0.3 * math.sin(1.7 * t),
        ]
    )


def check_no_false_cue(outputs: list, aircraft_f: np.ndarray, tilt_rate_limit: np.ndarray) -> None:
    """The cab's cue stays within what the aircraft (which never rotates) gave.

    ``tilt_rate_limit``: the washout's (roll, pitch), rad/s. With no yaw the cab's body rates
    are ``p = roll rate``, ``q = pitch rate cos(roll)``, ``r = -pitch rate sin(roll)``."""
    run = np.array([o.phase == "running" for o in outputs])
    poses = np.array([o.platform_pose for o in outputs])[run]
    dev_air = np.abs(aircraft_f[run] - np.array([0.0, 0.0, -G])).max(axis=0)
    dev_cab = np.abs(cab_specific_force(poses, DT) - np.array([0.0, 0.0, -G]))
    worst = dev_cab.max(axis=0)
    assert (worst <= dev_air).all(), f"cab cue {worst} m/s^2 beyond the aircraft's {dev_air}"
    rates = np.abs(cab_body_rates(poses, DT)).max(axis=0)
    # the aircraft never rotates: only the tilt moves the cab, within its rate limits
    limit = np.append(tilt_rate_limit, tilt_rate_limit[1])
    assert (rates <= limit * (1 + 1e-6)).all(), (
        f"cab rotates at {np.degrees(rates)} deg/s; the aircraft does not rotate and the tilt "
        f"may reach {np.degrees(tilt_rate_limit)} deg/s"
    )
    assert not any(o.rate_limited or o.held for o in outputs if o.phase == "running")


def test_a_source_going_stale_mid_manoeuvre_adds_no_cue():
    """Stale for a moment (the fade turns back before it ends), then for good, then fresh."""
    config = load_config(rate_hz=RATE, washout=WASHOUT)
    pipeline = Pipeline(config)
    ticks, held = [], None
    for k in range(int(30.0 * RATE)):
        t = k * DT
        stale = 10.0 <= t < 10.4 or 14.0 <= t < 19.0  # the source holds its last sample
        if not stale or held is None:
            held = manoeuvre(t)
        ticks.append((t, held.copy(), np.zeros(3), not stale))
    outputs = fly(pipeline, ticks)
    assert pipeline.health.watchdog_fades == 2
    assert min(o.fade for o in outputs) == 0.0  # the long stretch faded out completely
    aircraft = np.array([f for _, f, _, _ in ticks])
    check_no_false_cue(outputs, aircraft, config.cueing_params.tilt_rate_limit)
    # faded out, the tilt (about 5 deg both ways, which a hold would keep) goes back to level
    # within its rate limit; the translation washes out with the washout's own high-pass
    before = next(o for o in outputs if o.t >= 14.0)
    at_end_of_gap = next(o for o in outputs if o.t >= 18.99)
    assert np.degrees(np.abs(before.platform_pose[3:5])).min() > 3.0
    assert np.degrees(np.abs(at_end_of_gap.platform_pose[3:]).max()) < 0.1


def test_a_time_jump_mid_manoeuvre_adds_no_cue():
    """A forward jump of the source's clock (a replay's gap, a reloaded aircraft)."""
    config = load_config(rate_hz=RATE, washout=WASHOUT)
    pipeline = Pipeline(config)
    ticks = []
    for k in range(int(25.0 * RATE)):
        t = k * DT + (30.0 if k * DT >= 12.0 else 0.0)
        ticks.append((t, manoeuvre(k * DT), np.zeros(3), True))
    outputs = fly(pipeline, ticks)
    assert pipeline.health.time_jumps == 1
    aircraft = np.array([f for _, f, _, _ in ticks])
    check_no_false_cue(outputs, aircraft, config.cueing_params.tilt_rate_limit)


def test_rejected_samples_do_not_hold_the_platform_in_the_manoeuvre():
    """A source that keeps sending garbage (fresh, but every sample rejected) is treated as
    stale after the stale timeout: the washout is not driven by the held sample for ever."""
    config = load_config(rate_hz=RATE, washout=WASHOUT)
    pipeline = Pipeline(config)
    ticks = []
    for k in range(int(30.0 * RATE)):
        t = k * DT
        f = manoeuvre(t) if t < 12.0 else np.array([math.nan, 0.0, -G])
        ticks.append((t, f, np.zeros(3), True))
    outputs = fly(pipeline, ticks)
    assert pipeline.health.rejected_inputs == int(18.0 * RATE)
    assert pipeline.health.watchdog_fades == 1
    assert outputs[-1].fade == 0.0
    # back at neutral, level flight's pose (the held sample would keep it tilted by ~5 deg)
    assert np.degrees(np.abs(outputs[int(11.9 * RATE)].platform_pose[3:5])).min() > 3.0
    assert np.abs(outputs[-1].platform_pose[:3]).max() < 0.01
    assert np.degrees(np.abs(outputs[-1].platform_pose[3:]).max()) < 0.01
    held = np.array([o.state.specific_force for o in outputs])
    aircraft = np.where(np.isfinite(held), held, manoeuvre(12.0 - DT))  # what was held
    check_no_false_cue(outputs, aircraft, config.cueing_params.tilt_rate_limit)


# --------------------------------------------------------------------------- real logs


@pytest.mark.parametrize("name", ["vtol.tlog", "erle_plane_329.BIN"])
def test_real_logs_keep_the_cranks_off_their_limits(name, flight_data, streamed):
    """``motionbase stream --mavlink LOG --fast`` with its defaults: no crank comes within
    5 deg of its limit, nothing is clamped, and the limiter never has to act while running
    (so it cannot add a cue)."""
    from motionbase.io.mcap_source import McapSource, read_messages
    from motionbase.pipeline import PipelineConfig

    _, out = streamed(flight_data / name)
    msgs = read_messages(out)
    config = PipelineConfig.from_dict(McapSource(out).metadata["pipeline_config"])
    poses = msgs["/platform/pose"]
    angles = np.array([m["angles"] for m in msgs["/platform/actuators"]])
    running = np.array([m["phase"] == "running" for m in poses])
    assert running.sum() > 0.9 * len(poses)
    lo, hi = np.asarray(config.geometry.angle_min), np.asarray(config.geometry.angle_max)
    margin = np.radians(5.0)
    run_angles = angles[running]
    closest = np.degrees(min((run_angles - lo).min(), (hi - run_angles).min()))
    assert closest >= 5.0, f"{name}: a crank came within {closest:.2f} deg of its limit"
    assert ((run_angles >= lo + margin) & (run_angles <= hi - margin)).all()
    assert not any(m["clamped"] for m in poses), f"{name}: the workspace clamp acted"
    limited = sum(m["rate_limited"] or m["held"] for m, r in zip(poses, running, strict=True) if r)
    assert limited == 0, f"{name}: the limiter changed {limited} commands while running"
