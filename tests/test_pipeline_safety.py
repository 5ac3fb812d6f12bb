"""The whole pipeline under attack: nothing bad ever reaches an actuator, for every robot.

Hypothesis drives the real :class:`~motionbase.pipeline.Pipeline` (shipped presets, the
three robots, both cueings) with arbitrary sequences of good, non-finite and absurd
aircraft samples, time gaps and jumps (forward and backward), stale stretches, stops and
E-stops at random ticks. Every command must be finite, inside the angle limits, and within
the speed and acceleration limits measured from the commands themselves (finite
differences, starting from park at rest), and a stop must end parked within a time
computed from the limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from motionbase.app import load_config
from motionbase.pipeline import Pipeline, PipelineConfig, RunSummary, run, with_overrides
from motionbase.state import AircraftState

G = 9.80665
LEVEL = ([0.0, 0.0, -G], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])

# rounding only: the commands are differences of doubles of order 1 rad
SPEED_TOL = 1e-9  # rad/s
ACCEL_TOL = 1e-6  # rad/s^2


def _config(planar: bool, rate_hz: float = 120.0) -> PipelineConfig:
    return load_config(planar=planar, rate_hz=rate_hz)


CONFIGS = {
    (planar, rate): _config(planar, rate) for planar in (False, True) for rate in (60.0, 120.0)
}


def check_commands(pipeline: Pipeline, angles: list[np.ndarray]) -> None:
    """Finite, in the angle limits, speed and acceleration limits from park at rest."""
    lim = pipeline.robot.limits
    dt = pipeline.dt
    park = pipeline.robot.park_angles
    q = np.array([park, park, *angles])  # at rest at park before the first tick
    assert np.isfinite(q).all(), "non-finite actuator command"
    assert (q >= lim.lower).all() and (q <= lim.upper).all(), "command outside the angle limits"
    v = np.diff(q, axis=0) / dt
    excess_v = np.abs(v) - lim.max_speed
    assert excess_v.max() <= SPEED_TOL, f"speed limit exceeded by {excess_v.max():.3g} rad/s"
    a = np.diff(v, axis=0) / dt
    excess_a = np.abs(a) - lim.max_accel
    assert excess_a.max() <= ACCEL_TOL, f"acceleration limit exceeded by {excess_a.max():.3g}"


def park_bound_s(pipeline: Pipeline, soft: bool) -> float:
    """Longest time to park from anywhere, computed from the limits alone.

    From any speed the actuator stops within vmax/amax; it then crosses at most the
    whole range (plus what it travelled while braking) on a trapezoidal profile,
    which takes distance/vmax + vmax/amax. A soft stop first blends the target to
    park over ``soft_start_s``; an E-stop heads for park at once.
    """
    lim = pipeline.robot.limits
    vmax, amax = lim.max_speed, lim.max_accel
    span = lim.upper - lim.lower + vmax**2 / (2 * amax)
    t = float(np.max(vmax / amax + span / vmax + vmax / amax))
    if soft:
        t += pipeline.config.soft_start_s
    return t + 3 * pipeline.dt


# --------------------------------------------------------------------------- strategies

finite3 = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3)


@dataclass(frozen=True)
class Tick:
    kind: str  # "good", "bad", "back", "none"
    force: tuple[float, ...] = (0.0, 0.0, -G)
    rates: tuple[float, ...] = (0.0, 0.0, 0.0)
    attitude: tuple[float, ...] = (0.0, 0.0, 0.0)
    jump_s: float = 0.0  # forward time jump before this tick
    back_s: float = 0.0  # for "back": how far before the previous tick
    bad_time: bool = False  # "bad" with a non-finite time
    stale: bool = False
    action: str = ""  # "", "stop", "estop"


NASTY = [math.nan, math.inf, -math.inf, 1e6, -1e6, 1e3, -1e300]


@st.composite
def good_tick(draw, strength: float = 1.0) -> Tick:
    f = draw(finite3)
    w = draw(finite3)
    att = draw(finite3)
    return Tick(
        "good",
        force=(60 * strength * f[0], 60 * strength * f[1], -G + 60 * strength * f[2]),
        rates=tuple(8 * strength * x for x in w),
        attitude=tuple(3 * x for x in att),
    )


@st.composite
def bad_tick(draw) -> Tick:
    base = draw(good_tick())
    which = draw(st.sampled_from(["force", "rates", "attitude", "time"]))
    if which == "time":
        return Tick("bad", base.force, base.rates, base.attitude, bad_time=True)
    vec = list(getattr(base, which))
    vec[draw(st.integers(0, 2))] = draw(st.sampled_from(NASTY))
    if which == "attitude" and all(math.isfinite(x) and abs(x) < 1e3 for x in vec):
        vec[0] = 1e3  # an angle of 1e3 rad
    if which == "rates" and all(math.isfinite(x) and abs(x) < 1e3 for x in vec):
        vec[0] = 1e3
    return Tick(**{**base.__dict__, "kind": "bad", which: tuple(vec)})


@st.composite
def tick(draw) -> Tick:
    t = draw(
        st.one_of(
            good_tick(),
            good_tick(),
            bad_tick(),
            st.builds(Tick, kind=st.just("back"), back_s=st.floats(0.0, 5.0)),
            st.just(Tick("none")),
        )
    )
    jump = draw(st.sampled_from([0.0, 0.0, 0.0, 0.0, 0.3, 0.6, 5.0, 1e4]))
    stale = draw(st.booleans()) and draw(st.booleans())
    action = draw(st.sampled_from(["", "", "", "", "", "", "", "", "", "stop", "estop"]))
    return Tick(**{**t.__dict__, "jump_s": jump, "stale": stale, "action": action})


def stretches(inner, max_len: int):
    """Runs of the same tick repeated (so stale stretches, ramps and fades have time to act)."""
    return st.lists(
        st.tuples(inner, st.integers(1, 60)),
        min_size=1,
        max_size=max_len,
    ).map(lambda runs: [t for t, n in runs for _ in range(n)])


def drive(pipeline: Pipeline, ticks: list[Tick]) -> tuple[list, int]:
    """Feed the ticks; return the outputs and the number of samples that must be rejected."""
    dt = pipeline.dt
    clock = 0.0  # time of the latest tick the pipeline saw (its output time)
    newest = -math.inf  # time of the latest accepted sample: a sample must be later
    outputs = []
    must_reject = 0
    started = False
    for k in ticks:
        if k.action == "stop":
            pipeline.stop()
        elif k.action == "estop":
            pipeline.estop()
        nxt = clock + dt + k.jump_s if started else 0.0
        if k.kind == "none":
            state = None
        elif k.kind == "back":
            # back to the latest tick's time or before it: rejected when that is no later
            # than the latest accepted sample (the held ticks' times are a guess, which a
            # new sample may tie)
            state = AircraftState(clock - k.back_s, *LEVEL) if started else None
            if state is not None:
                rejected = state.t < 0.0 or state.t <= newest
                must_reject += rejected
                newest = newest if rejected else state.t
        else:
            t = math.nan if k.bad_time else nxt
            state = AircraftState(t, k.force, k.rates, k.attitude)
            must_reject += k.kind == "bad"
            newest = newest if k.kind == "bad" else t
        out = pipeline.step(state, fresh=not k.stale)
        outputs.append(out)
        clock = out.t
        started = True
    return outputs, must_reject


def park(pipeline: Pipeline, soft: bool = True) -> list:
    """Stop and tick on held samples until parked; fail past the bound from the limits."""
    pipeline.stop()
    outputs = []
    bound = park_bound_s(pipeline, soft=soft)
    for _ in range(int(math.ceil(bound / pipeline.dt)) + 1):
        if pipeline.parked:
            break
        outputs.append(pipeline.step(None))
    assert pipeline.parked, f"not parked within {bound:.2f} s of the stop"
    assert np.array_equal(
        outputs[-1].angles if outputs else pipeline.command, pipeline.robot.park_angles
    )
    return outputs


# --------------------------------------------------------------------------- fuzzing


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ticks=stretches(tick(), 12), rate=st.sampled_from([60.0, 120.0]), data=st.data())
def test_any_input_sequence_gives_safe_commands_and_parks(planar, ticks, rate, data):
    check_any_input_sequence(Pipeline(CONFIGS[(planar, rate)]), ticks)


# the other robot and the other cueing: the Stewart platform (leg lengths, m) with the
# classical washout, the 6-RUS with the model-predictive cueing (about a millisecond a tick)
OTHER_CONFIGS = {
    "stewart6": {r: load_config(platform="stewart6", rate_hz=r) for r in (60.0, 120.0)},
    "mpc": {r: load_config(cueing="mpc", rate_hz=r) for r in (60.0, 120.0)},
}


@pytest.mark.parametrize("which", ["stewart6", "mpc"])
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ticks=stretches(tick(), 12), rate=st.sampled_from([60.0, 120.0]))
def test_any_input_sequence_is_safe_on_the_stewart_platform_and_with_mpc(which, ticks, rate):
    check_any_input_sequence(Pipeline(OTHER_CONFIGS[which][rate]), ticks)


def check_any_input_sequence(pipeline: Pipeline, ticks: list[Tick]) -> None:
    """Drive ``ticks``, stop, park: safe commands, the right counts, finite outputs."""
    planar = pipeline.config.planar
    outputs, must_reject = drive(pipeline, ticks)
    outputs += park(pipeline)
    check_commands(pipeline, [o.angles for o in outputs])
    h = pipeline.health
    assert h.rejected_inputs == must_reject
    assert h.samples == len(outputs)
    assert h.estops == sum(k.action == "estop" for k in ticks)
    # output time strictly increases whatever the source's clock did
    t = np.array([o.t for o in outputs])
    assert np.isfinite(t).all() and (np.diff(t) > 0).all()
    # every logged pose and washout output is finite too
    assert all(np.isfinite(o.platform_pose).all() for o in outputs)
    assert all(np.isfinite(o.washout_pose).all() for o in outputs)
    if planar:
        rrr3 = pipeline.robot.kin
        servo = np.array([o.servo_deg for o in outputs])
        assert np.array_equal(servo, rrr3.to_servo(np.array([o.angles for o in outputs])))


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    good=st.lists(good_tick(strength=0.05), min_size=1, max_size=40),
    bad=st.lists(st.one_of(bad_tick(), st.just(Tick("back", back_s=0.0))), max_size=40),
    order=st.randoms(use_true_random=False),
)
def test_rejected_samples_never_reach_the_washout(planar, good, bad, order):
    """A run with bad samples equals the run where each is replaced by a hold of the last good one.

    The hold is built here, independently: the last valid sample again, at the next tick's
    time. Inputs are gentle (no clamping), so the two runs see the same washout history only
    if no rejected number ever entered it.
    """
    seq = [("good", k) for k in good] + [("bad", k) for k in bad]
    order.shuffle(seq)
    seq.insert(0, ("good", good[0]))  # a valid sample first, so there is something to hold
    config = CONFIGS[(planar, 120.0)]
    a, b = Pipeline(config), Pipeline(config)
    dt = config.dt
    last = None
    for i, (kind, k) in enumerate(seq):
        t = i * dt
        if kind == "good":
            state = AircraftState(t, k.force, k.rates, k.attitude)
            last = state
            hold = state
        elif k.kind == "back":
            # the time did not advance: the latest accepted sample's again (a copy)
            state = AircraftState(last.t, k.force, k.rates, k.attitude)
            hold = AircraftState(t, last.specific_force, last.angular_velocity, last.attitude)
        else:
            state = AircraftState(math.nan if k.bad_time else t, k.force, k.rates, k.attitude)
            hold = AircraftState(t, last.specific_force, last.angular_velocity, last.attitude)
        oa, ob = a.step(state), b.step(hold)
        assert oa.t == pytest.approx(ob.t, abs=1e-12)  # a held tick's time is the pipeline's
        assert np.array_equal(oa.washout_pose, ob.washout_pose)
        assert np.array_equal(oa.angles, ob.angles)
        assert oa.accepted == (kind == "good")
    assert a.health.rejected_inputs == len(bad)
    assert b.health.rejected_inputs == 0
    assert a.health.clamps == b.health.clamps == 0


# --------------------------------------------------------------------------- ramps


def _full_motion(pipeline: Pipeline, seconds: float, t0: float = 0.0) -> list:
    """Strong sinusoidal manoeuvring (in every axis) that drives the platform to its limits."""
    out = []
    dt = pipeline.dt
    for i in range(int(seconds / dt)):
        t = t0 + i * dt
        s = math.sin(2 * math.pi * 0.7 * t)
        c = math.cos(2 * math.pi * 0.45 * t)
        state = AircraftState(t, [25 * s, 25 * c, -G + 20 * s], [4 * c, 4 * s, 4 * c], [0, 0, 0])
        out.append(pipeline.step(state))
    return out


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_soft_start_ramps_from_park_within_the_limits(planar):
    pipeline = Pipeline(CONFIGS[(planar, 120.0)])
    cfg = pipeline.config
    out = _full_motion(pipeline, cfg.soft_start_s + 3.0)
    check_commands(pipeline, [o.angles for o in out])
    phases = [o.phase for o in out]
    n_start = phases.index("running")
    # the blend takes soft_start_s (to a tick), then it runs
    assert abs(n_start * pipeline.dt - cfg.soft_start_s) <= 1.5 * pipeline.dt
    assert set(phases[:n_start]) == {"starting"}
    # the first command is a small step away from park, not a jump to the live pose
    first = out[0].angles - pipeline.robot.park_angles
    assert np.abs(first).max() <= pipeline.robot.limits.max_accel.max() * pipeline.dt**2 + 1e-12


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
@pytest.mark.parametrize("kind", ["stop", "estop"])
def test_stop_and_estop_from_full_motion_park_within_limits_in_bounded_time(planar, kind):
    pipeline = Pipeline(CONFIGS[(planar, 120.0)])
    out = _full_motion(pipeline, pipeline.config.soft_start_s + 4.0)
    moving = np.abs(pipeline.speed).max()
    assert moving > 0.05  # it was really moving when stopped
    if kind == "estop":
        pipeline.estop()
    # the source keeps going (held samples would do the same): the stop must still win
    t0 = out[-1].t + pipeline.dt
    bound = park_bound_s(pipeline, soft=kind == "stop")
    after = []
    for i in range(int(bound / pipeline.dt) + 2):
        if kind == "stop" and i == 0:
            pipeline.stop()
        if pipeline.parked:
            break
        after += _full_motion(pipeline, pipeline.dt, t0 + i * pipeline.dt)
    assert pipeline.parked, f"{kind}: not parked within {bound:.2f} s"
    assert np.array_equal(after[-1].angles, pipeline.robot.park_angles)
    assert after[-1].phase == "parked"
    check_commands(pipeline, [o.angles for o in out + after])
    assert pipeline.health.estops == (kind == "estop")


def _level(pipeline: Pipeline, ticks: int) -> list:
    return [pipeline.step(AircraftState(i * pipeline.dt, *LEVEL)) for i in range(ticks)]


def _accelerations(pipeline: Pipeline, angles: list[np.ndarray]) -> np.ndarray:
    park = pipeline.robot.park_angles
    q = np.array([park, park, *angles])  # at rest at park before the first tick
    return np.diff(q, n=2, axis=0) / pipeline.dt**2


@pytest.mark.parametrize("platform", ["rus6", "stewart6"])
@pytest.mark.parametrize("share", [0.05, 0.3, 0.5, 0.8, 0.97])
def test_a_stop_during_the_soft_start_turns_back_as_gently_as_it_started(platform, share):
    """A stop that comes while the platform is still rising from park (the end of a short
    flight, a signal in the first seconds) must not reverse at once: the blend is then at
    up to 1.5 times its mean rate, and turning it in one tick made the safety limiter
    stop the actuators at their full acceleration limit (30 rad/s^2 on ceart, against 3.4
    for the start). The way back must need no limiter and be no harsher than the start."""
    pipeline = Pipeline(load_config(platform=platform, rate_hz=120.0))
    dt, soft = pipeline.dt, pipeline.config.soft_start_s
    start = _level(pipeline, int(soft / dt) + 30)
    assert start[-1].phase == "running"
    assert np.abs(start[-1].angles - pipeline.robot.park_angles).max() > 0.1  # it rose
    start_peak = np.abs(_accelerations(pipeline, [o.angles for o in start])).max()

    pipeline.reset()
    n = int(round(share * soft / dt))
    out = _level(pipeline, n)
    assert out[-1].phase == "starting"
    pipeline.stop()
    back = []
    t = out[-1].t
    for _ in range(int(2 * soft / dt)):
        if pipeline.parked:
            break
        t += dt
        back.append(pipeline.step(AircraftState(t, *LEVEL)))
    assert pipeline.parked, "not parked within twice the soft-start time"
    assert not any(o.rate_limited for o in back), "the limiter had to act on the way back"
    check_commands(pipeline, [o.angles for o in out + back])
    peak = np.abs(_accelerations(pipeline, [o.angles for o in out + back])[n:]).max()
    # the blend's own acceleration is the start's; the kinematics' curvature may add a little
    assert peak <= 1.25 * start_peak, f"way back {peak:.2f} rad/s^2 against {start_peak:.2f}"


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_estop_during_a_soft_stop_and_a_second_estop_still_park(planar):
    pipeline = Pipeline(CONFIGS[(planar, 120.0)])
    out = _full_motion(pipeline, pipeline.config.soft_start_s + 1.0)
    pipeline.stop()
    out += [pipeline.step(None) for _ in range(20)]
    pipeline.estop()
    out += [pipeline.step(None) for _ in range(5)]
    pipeline.estop()
    out += park(pipeline, soft=False)
    check_commands(pipeline, [o.angles for o in out])
    assert pipeline.health.estops == 2


# --------------------------------------------------------------------------- run loop


class ListSource:
    """A finite in-memory source (optionally marking samples stale)."""

    def __init__(self, states, fresh=None) -> None:
        self.states = list(states)
        self.flags = list(fresh) if fresh is not None else [True] * len(self.states)
        self.fresh = True

    def __iter__(self):
        for s, f in zip(self.states, self.flags, strict=True):
            self.fresh = f
            yield s


class Recorder:
    def __init__(self) -> None:
        self.outputs = []

    def write(self, out) -> None:
        self.outputs.append(out)


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_run_counts_every_safety_event_in_health(planar):
    """Rejected inputs, clamps, rate limiting, watchdog fades and E-stops are all counted."""
    config = CONFIGS[(planar, 120.0)]
    pipeline = Pipeline(config)
    dt = config.dt
    states, fresh = [], []
    n = int(8.0 / dt)
    for i in range(n):
        t = i * dt
        s = math.sin(2 * math.pi * 0.3 * t)
        f = [40 * s, 40 * s, -G]
        w = [3 * s, 3 * s, 6 * s]
        if i in (300, 301, 302):
            f = [math.nan, 0.0, -G]
        if i == 400:
            w = [1e3, 0.0, 0.0]
        states.append(AircraftState(t, f, w))
        fresh.append(not (500 <= i < 560 or 700 <= i < 720))
    sink = Recorder()
    stop_at = 900

    def progress(out):
        if len(sink.outputs) == stop_at:
            stop.set("test", estop=True)

    from motionbase.pipeline import StopRequest

    stop = StopRequest()
    summary = run(pipeline, ListSource(states, fresh), [sink], stop=stop, progress=progress)
    h = pipeline.health
    assert isinstance(summary, RunSummary)
    assert h.rejected_inputs == 4
    assert h.watchdog_fades == 2
    assert h.estops == 1
    assert h.clamps == sum(o.clamped for o in sink.outputs) > 0
    assert h.rate_limited == sum(o.rate_limited for o in sink.outputs) > 0
    assert pipeline.parked and summary.stopped_by == "test"
    check_commands(pipeline, [o.angles for o in sink.outputs])


def test_a_long_stall_restarts_the_input_from_level_flight_and_fades_it_back_in():
    config = with_overrides(CONFIGS[(False, 120.0)], stale_timeout_s=0.5)
    pipeline = Pipeline(config)
    out = _full_motion(pipeline, 4.0)
    jumped = _full_motion(pipeline, 1.0, t0=out[-1].t + 30.0)
    assert pipeline.health.time_jumps == 1
    assert jumped[0].fade == pytest.approx(config.dt / config.fade_s)
    check_commands(pipeline, [o.angles for o in out + jumped])


class PacedListSource(ListSource):
    """Delivers each sample at its own time on the wall clock (like a --realtime source), and
    says so (``paces_itself``, ``due_time``): the loop does not pace it again."""

    rate_hz = 120.0
    duration_s = None
    paces_itself = True
    due_time = None

    def describe(self) -> dict:
        return {"kind": "paced test source"}

    def __iter__(self):
        import time

        start = time.monotonic()
        t0 = self.states[0].t
        for s, f in zip(self.states, self.flags, strict=True):
            if math.isfinite(s.t):
                self.due_time = start + (s.t - t0)
            wait = self.due_time - time.monotonic() if self.due_time is not None else 0.0
            if wait > 0:
                time.sleep(wait)
            self.fresh = f
            yield s


def test_health_record_in_the_log_counts_every_event_and_the_worst_overrun(tmp_path):
    """The last ``/health`` record agrees with the per-tick flags of the same log, counts the
    SIGTERM E-stop (delivered to this very process), and measures a forced loop overrun."""
    import os
    import signal
    import time

    from motionbase import app
    from motionbase.io.mcap_source import read_messages

    # the SIMONA set: the flight makes it clamp (the tuned default is sized never to)
    config = load_config(rate_hz=120.0, washout="default")
    dt = config.dt
    states, fresh = [], []
    for i in range(int(2.5 / dt)):
        t = i * dt
        s = math.sin(2 * math.pi * 0.5 * t)
        f = [60 * s, 60 * s, -G]
        if i in (40, 41):
            f = [math.inf, 0.0, -G]
        w = [1e3, 0.0, 0.0] if i == 50 else [4 * s, 4 * s, 8 * s]
        t_i = t - 5 * dt if i == 60 else t  # one sample back in time
        states.append(AircraftState(t_i, f, w))
        fresh.append(not (100 <= i < 110 or 150 <= i < 160))
    slow_tick = 120

    def on_output(out) -> None:
        on_output.n += 1
        if on_output.n == slow_tick:
            time.sleep(3 * dt)  # a loop overrun of at least 2 dt
        if on_output.n == int(2.0 / dt):
            os.kill(os.getpid(), signal.SIGTERM)  # app._drive turns it into a stop

    on_output.n = 0
    out = tmp_path / "health.mcap"
    result = app._drive(
        "test",
        config,
        PacedListSource(states, fresh),
        out,
        paced=True,
        progress=False,
        on_output=on_output,
    )
    assert result.summary.stopped_by == "SIGTERM"
    msgs = read_messages(out)
    health = msgs["/health"][-1]
    logged_states = msgs["/aircraft/state"]
    poses = msgs["/platform/pose"]
    flags = [m["fresh"] for m in logged_states]
    assert health["rejected_inputs"] == sum(not m["accepted"] for m in logged_states) == 4
    assert health["clamps"] == sum(m["clamped"] for m in poses) > 0
    assert health["rate_limited"] == sum(m["rate_limited"] for m in poses) > 0
    fades = sum(a and not b for a, b in zip([True, *flags], flags, strict=False))
    assert health["watchdog_fades"] == fades == 2
    assert health["estops"] == 0  # SIGTERM parks at the soft-start pace: a stop, not an E-stop
    assert health["worst_overrun_s"] >= 2 * dt - 1e-4
    assert health["overruns"] >= 1 and health["overruns_off_cpu"] >= 1  # the sleeping tick
    # the same tick's command came at least 2 dt after its sample was due
    assert health["late_commands"] >= 1 and health["worst_late_s"] >= 2 * dt - 1e-4
    assert health["samples"] == len(poses)
    assert poses[-1]["phase"] == "parked"
    # health records come at the first tick of every second of source time (park ticks'
    # times are sums of dt: a record may come one tick after the whole second)
    t_health = [m["t"] for m in msgs["/health"]]
    assert np.diff(t_health).max() <= 1.0 + dt + 1e-9 and t_health[-1] == poses[-1]["t"]


def test_overruns_tell_a_waiting_loop_from_a_computing_one():
    """A tick that sleeps past its period is late while off the CPU; one that computes past
    it is late on the CPU. Both are counted; only the first as ``overruns_off_cpu``."""
    import time

    config = CONFIGS[(False, 120.0)]
    dt = config.dt
    states = [AircraftState(i * dt, [0.0, 0.0, -G], [0.0, 0.0, 0.0]) for i in range(60)]

    class SlowSink:
        n = 0

        def write(self, out) -> None:
            self.n += 1
            if self.n == 20:
                time.sleep(3 * dt)  # waiting: the thread's CPU time stays far below dt
            elif self.n == 40:
                cpu0 = time.thread_time()
                while time.thread_time() - cpu0 < 3 * dt:  # computing: 3 dt of CPU time
                    pass

    pipeline = Pipeline(config)
    run(pipeline, PacedListSource(states, [True] * len(states)), [SlowSink()], paced=True)
    h = pipeline.health
    assert h.overruns >= 2
    assert h.overruns_off_cpu >= 1  # the sleeping tick
    assert h.overruns - h.overruns_off_cpu >= 1  # the computing tick
    assert h.worst_overrun_s >= 2 * dt - 1e-4


def spy_on_the_schedule(monkeypatch) -> list[tuple[float, float]]:
    """Record the loop's schedule: each paced tick's due time and when its wait returned
    (monotonic s), around the real :func:`~motionbase.pacing.wait_until`."""
    import motionbase.pipeline as pipeline_module

    real = pipeline_module.wait_until
    schedule: list[tuple[float, float]] = []

    def recorded(due, *, busy=False, clock):
        real(due, busy=busy, clock=clock)
        schedule.append((due, clock()))

    monkeypatch.setattr(pipeline_module, "wait_until", recorded)
    return schedule


def check_schedule(schedule: list[tuple[float, float]], dt: float) -> None:
    """Never ahead of the schedule; after a late tick the next one at least half a period
    after it (no burst to catch up). From the loop's own times, so a stall of the machine
    between the wait and the tick (a virtual machine's host taking the processor) cannot
    make two ticks look close: the rule is on when the wait returned, not on when a test
    saw the tick."""
    assert len(schedule) > 10
    due, woke = np.array(schedule).T
    assert (woke >= due - 1e-4).all()  # (0.1 ms: the clocks' and the sleep's resolution)
    assert (due[1:] - woke[:-1] >= dt / 2 - 1e-9).all()


@pytest.mark.parametrize("busy_wait", [False, True], ids=["sleeping", "busy-waiting"])
def test_paced_park_ticks_keep_the_period(busy_wait: bool, monkeypatch):
    """After the source ends, the park ramp ticks on the loop's schedule, one period apart on
    the wall clock, whether the loop sleeps or busy-waits between them: never ahead of it,
    and after a late tick never closer than half a period (no burst to catch up); the
    platform ends parked."""
    config = CONFIGS[(False, 120.0)]
    dt = config.dt
    states = [AircraftState(i * dt, [1.0, 0.0, -G], [0.0, 0.2, 0.0]) for i in range(120)]

    class Clocked:
        def __init__(self) -> None:
            self.last = None

        def write(self, out) -> None:
            self.last = out

    sink = Clocked()
    pipeline = Pipeline(config)
    park_ticks = 0  # the steps without a sample of the source's
    step = pipeline.step

    def counted_step(state, fresh=True):
        nonlocal park_ticks
        park_ticks += state is None
        return step(state, fresh)

    pipeline.step = counted_step  # (the loop calls the instance's step)
    schedule = spy_on_the_schedule(monkeypatch)  # (the source paces itself: park ticks only)
    run(
        pipeline,
        PacedListSource(states, [True] * len(states)),
        [sink],
        paced=True,
        busy_wait=busy_wait,
    )
    assert sink.last is not None and sink.last.phase == "parked"
    assert len(schedule) == park_ticks > 10
    check_schedule(schedule, dt)
    # one period apart: each park tick due at least a period after the one before (read from
    # the loop's own schedule: a stall of this machine between a wait and the step cannot
    # move it, as it moved the steps' wall-clock times this test read before)
    due = np.array(schedule)[:, 0]
    assert (np.diff(due) >= dt - 1e-9).all()


# --------------------------------------------------------------------------- the loop's clock


class WallClockSink:
    """Records when each tick reached the sinks (monotonic s); can stall once."""

    def __init__(self, stall_at: int = -1, stall_s: float = 0.0) -> None:
        self.walls: list[float] = []
        self.outputs = []
        self.stall_at, self.stall_s = stall_at, stall_s

    def write(self, out) -> None:
        import time

        self.walls.append(time.monotonic())
        self.outputs.append(out)
        if len(self.walls) == self.stall_at:
            time.sleep(self.stall_s)


def test_a_paced_run_keeps_time_on_the_loops_clock_never_on_the_samples(monkeypatch):
    """A source that does not pace itself (a replay): the loop paces it at the pipeline's rate
    whatever the samples' times say (a jump of 1e6 s and a gap of 10 s are time jumps for the
    validation stage, not waits); after a stall it never bursts to catch up; a command that
    reached the sinks late is counted from its due time."""
    import threading

    config = CONFIGS[(False, 120.0)]
    dt = config.dt
    times = [k * dt for k in range(240)]
    times = times[:80] + [t + 1e6 for t in times[80:160]] + [t + 1e6 + 10.0 for t in times[160:]]
    states = [AircraftState(t, [2.0, 1.0, -G], [0.1, 0.1, 0.0]) for t in times]
    pipeline = Pipeline(config)
    stall = 0.3  # s, at tick 120: the sink stalls (a disk, the machine)
    sink = WallClockSink(stall_at=120, stall_s=stall)
    done = threading.Event()

    schedule = spy_on_the_schedule(monkeypatch)

    def go() -> None:
        run(pipeline, ListSource(states), [sink], paced=True)
        done.set()

    threading.Thread(target=go, daemon=True).start()
    assert done.wait(120), "the run waited on the samples' times"  # a watchdog, not a bound
    h = pipeline.health
    assert h.time_jumps == 2 and h.rejected_inputs == 0
    assert [o.state for o in sink.outputs[: len(states)]] == states  # every sample, in order
    assert sink.outputs[-1].phase == "parked"
    # never ahead of the schedule, and no burst to catch up after the stall
    assert len(schedule) == len(sink.walls)
    check_schedule(schedule, dt)
    due = np.array(schedule)[:, 0]
    assert np.diff(due).max() > stall  # the schedule restarted after the stall
    # every tick due at least a period after the one before, the one after the stall the
    # stall later: the run took the samples' period and the stall, whatever their times say
    # (on the loop's own schedule, which a stall of this machine elsewhere cannot shorten)
    assert (np.diff(due) >= dt - 1e-9).all()
    assert due[-1] - due[0] >= (len(due) - 2) * dt + stall
    assert h.late_commands >= 1 and h.worst_late_s >= stall - 2 * dt


def test_a_stop_before_the_first_tick_moves_nothing_and_reads_no_sample():
    from motionbase.pipeline import StopRequest

    class Untouchable:
        def __iter__(self):  # a generator: reading its first sample raises
            raise AssertionError("the source was read after a stop")
            yield

    for planar in (False, True):
        pipeline = Pipeline(CONFIGS[(planar, 120.0)])
        stop = StopRequest()
        stop.set("SIGINT")
        sink = Recorder()
        summary = run(pipeline, Untouchable(), [sink], stop=stop, paced=True)
        assert len(sink.outputs) == 1 and sink.outputs[0].phase == "parked"
        assert np.array_equal(sink.outputs[0].angles, pipeline.robot.park_angles)
        assert summary.stopped_by == "SIGINT" and summary.running_samples == 0
        assert pipeline.health.estops == 0


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_a_time_no_log_can_hold_is_rejected_and_held(planar):
    """A log time is 64-bit nanoseconds: a sample time outside 0..MAX_SAMPLE_TIME_S (finite but
    huge, or negative) is rejected like any invalid sample and never becomes an output time."""
    from motionbase.safety import MAX_SAMPLE_TIME_S

    pipeline = Pipeline(CONFIGS[(planar, 120.0)])
    assert 2**63 / 1e9 > MAX_SAMPLE_TIME_S + 1e6  # room for the ticks after the last sample
    step = pipeline.step
    level = AircraftState(0.5, *LEVEL)
    assert step(level).accepted
    for t in (2e10, -1.0, MAX_SAMPLE_TIME_S * (1 + 1e-9), 1e300):
        out = step(AircraftState(t, *LEVEL))
        assert not out.accepted and 0.5 < out.t < 1.0
        assert "outside" in pipeline.health.last_rejection
    assert step(AircraftState(MAX_SAMPLE_TIME_S, *LEVEL)).accepted  # the bound itself is fine
    assert pipeline.health.rejected_inputs == 4
