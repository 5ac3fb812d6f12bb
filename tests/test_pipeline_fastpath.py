"""The fused 6-RUS tick gives bit for bit what the stage-by-stage reference path gives.

:meth:`Pipeline.step` runs a 6-RUS tick in one compiled kernel;
:meth:`Pipeline.step_reference` runs the same stages one by one in Python (the
washout object, the robot's clamp and inverse, :func:`safety.limit_command`). Two
pipelines, one on each path, are driven by the same fuzzed sequences (good, non-finite
and absurd samples, time going back, forward jumps, stale stretches, park ticks, stops
and E-stops, inputs strong enough to clamp and rate-limit) and every field of every
output, the health counters and the whole internal state must be identical. A third
pipeline switches path at random ticks (the paths share one state).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from motionbase.app import load_config
from motionbase.pipeline import _S_VNEW, Pipeline, PipelineOutput, with_overrides
from motionbase.state import AircraftState

G = 9.80665
NASTY = [math.nan, math.inf, -math.inf, 1e6, -1e6, 1e3]

CONFIGS = {
    "default-120": load_config(rate_hz=120.0),
    "default-60": load_config(rate_hz=60.0),
    # short fade and soft start, so the ramps end inside the fuzzed sequences
    "quick-ramps": with_overrides(
        load_config(rate_hz=100.0), soft_start_s=0.1, fade_s=0.05, stale_timeout_s=0.05
    ),
}


def assert_same_output(a: PipelineOutput, b: PipelineOutput, k: int) -> None:
    for name in PipelineOutput._fields:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert isinstance(x, np.ndarray) and isinstance(y, np.ndarray), (k, name)
            assert x.dtype == y.dtype and x.shape == y.shape, (k, name)
            # bit for bit (NaN never appears in outputs, but compare bits anyway)
            assert x.tobytes() == y.tobytes(), (k, name, x, y)
        elif name == "state":
            assert x is y, (k, name)
        else:
            assert type(x) is type(y), (k, name, type(x), type(y))
            assert x == y, (k, name, x, y)


def assert_same_state(a: Pipeline, b: Pipeline) -> None:
    assert a.health == b.health
    live = _S_VNEW  # the rest of the vector is the kernel's scratch
    assert a._s[:live].tobytes() == b._s[:live].tobytes()
    assert a.washout._st.tobytes() == b.washout._st.tobytes()
    assert a.phase == b.phase and a.parked == b.parked


# --------------------------------------------------------------------------- strategies

unit = st.floats(-1.0, 1.0)


@st.composite
def event(draw):
    """One tick: (kind, force, rates, attitude, dt factor, stale, action)."""
    strength = draw(st.sampled_from([0.0, 0.05, 0.3, 1.0, 3.0]))
    f = [draw(unit) * 60 * strength for _ in range(3)]
    f[2] -= G
    w = [draw(unit) * 6 * strength for _ in range(3)]
    att = [draw(unit) * 3 for _ in range(3)]
    kind = draw(st.sampled_from(["good"] * 6 + ["nasty", "nan-time", "back", "none", "same"]))
    if kind == "nasty":
        vec = draw(st.sampled_from([f, w, att]))
        vec[draw(st.integers(0, 2))] = draw(st.sampled_from(NASTY))
    gap = draw(st.sampled_from([1.0] * 8 + [0.5, 3.0, 30.0, 1e5]))
    stale = draw(st.booleans()) and draw(st.booleans())
    action = draw(st.sampled_from([""] * 14 + ["stop", "estop"]))
    return kind, tuple(f), tuple(w), tuple(att), gap, stale, action


def runs(max_len: int):
    return st.lists(st.tuples(event(), st.integers(1, 40)), min_size=1, max_size=max_len).map(
        lambda rs: [e for e, n in rs for _ in range(n)]
    )


def make_states(events, dt: float):
    """(state or None, fresh, action) per tick; time advances by gap * dt on good ticks."""
    clock = 0.0
    out = []
    for kind, f, w, att, gap, stale, action in events:
        nxt = clock + gap * dt
        if kind == "none":
            state = None
        elif kind == "nan-time":
            state = AircraftState(math.nan, f, w, att)
        elif kind == "back":
            state = AircraftState(clock - 2.5 * dt, f, w, att)
        elif kind == "same":
            state = AircraftState(clock, f, w, att)
        else:
            state = AircraftState(nxt, f, w, att, angular_acceleration=(0.1, 0.2, 0.3))
            clock = nxt
        out.append((state, not stale, action))
    return out


def drive(pipelines, ticks, choose=None):
    """Step every pipeline with the same ticks; compare outputs tick by tick."""
    for k, (state, fresh, action) in enumerate(ticks):
        outs = []
        for i, p in enumerate(pipelines):
            if action == "stop":
                p.stop()
            elif action == "estop":
                p.estop()
            if choose is not None and i == len(pipelines) - 1:
                step = p.step if choose[k % len(choose)] else p.step_reference
            else:
                step = p.step
            outs.append(step(state, fresh))
        for o in outs[1:]:
            assert_same_output(outs[0], o, k)
    for p in pipelines[1:]:
        assert_same_state(pipelines[0], p)


# --------------------------------------------------------------------------- tests


@pytest.mark.parametrize("name", list(CONFIGS))
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(events=runs(10), choose=st.lists(st.booleans(), min_size=1, max_size=16))
def test_fused_tick_is_bit_identical_to_the_reference(name, events, choose):
    config = CONFIGS[name]
    ref = Pipeline(config, fast=False)
    fast = Pipeline(config)
    mixed = Pipeline(config)
    ticks = make_states(events, config.dt)
    # then the park ramp on held samples, as run() does after the source ends
    ticks += [(None, True, "stop")] + [(None, True, "")] * int(2.5 / config.dt)
    drive([ref, fast, mixed], ticks, choose)


def test_the_fuzzing_reaches_every_rare_path():
    """The paths the fused kernel hands back to Python all occur in one strong run."""
    config = CONFIGS["quick-ramps"]
    rng = np.random.default_rng(7)
    ref, fast = Pipeline(config, fast=False), Pipeline(config)
    events = []
    for k in range(3000):
        s = 3.0 if (k // 200) % 2 else 0.3
        if k % 100 == 0:  # forces held for 1 s: sustained enough to reach the clamp
            f_held, w_held = rng.uniform(-60, 60, 3), rng.uniform(-6, 6, 3)
        f = tuple(f_held * s + (0, 0, -G))
        w = tuple(w_held * s)
        kind = "nasty" if k % 97 == 5 else ("back" if k % 89 == 3 else "good")
        if kind == "nasty":
            f = (math.nan, f[1], f[2])
        # after a sample back in time the source catches up (else every later sample repeats
        # the pipeline's time and is rejected, and a long rejected stretch fades the input out)
        gap = 30.0 if k % 331 == 7 else (2.0 if k % 89 == 4 else 1.0)
        action = "estop" if k == 2500 else ("stop" if k == 1500 else "")
        events.append((kind, f, w, (0.0, 0.0, 0.0), gap, (k // 50) % 7 == 3, action))
    ticks = make_states(events, config.dt)
    drive([ref, fast], ticks)
    h = fast.health
    assert h.rejected_inputs and h.time_jumps and h.watchdog_fades and h.estops
    assert h.clamps > 100, "strong inputs must reach the workspace clamp"
    assert h.rate_limited > 0, "the E-stop and the jumps must meet the speed limits"


def test_planar_robot_takes_the_reference_path():
    config = load_config(planar=True, rate_hz=120.0)
    a, b = Pipeline(config, fast=False), Pipeline(config)
    ticks = [
        (AircraftState(k / 120, (np.sin(k / 30.0), 0.5, -G), (0.0, 0.0, 0.3)), True, "")
        for k in range(1, 400)
    ]
    drive([a, b], ticks)
    assert b.step(None).servo_deg is not None
