"""The safety stage's limiter: limits hold for any target sequence, and it still converges."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from motionbase.physics import smoothstep
from motionbase.safety import (
    RATE_LIMITED,
    UNSAFE_TARGET,
    ActuatorLimits,
    InputLimits,
    input_problem,
    limit_command,
    limit_kernel,
)

DT = 1 / 120
LIMITS = ActuatorLimits.broadcast(6, -1.0, 1.0, 3.0, 30.0)
TOL = 1e-9

targets = st.lists(
    st.lists(
        st.one_of(
            st.floats(-1.0, 1.0),
            st.floats(-1e6, 1e6),
            st.sampled_from([math.nan, math.inf, -math.inf]),
        ),
        min_size=6,
        max_size=6,
    ),
    min_size=1,
    max_size=120,
)


def drive(seq, q0=None):
    q = np.zeros(6) if q0 is None else np.asarray(q0, float)
    v = np.zeros(6)
    prev = q
    qs, vs, statuses = [q], [v], []
    for target in seq:
        q, v, status = limit_command(q, v, prev, np.asarray(target, float), DT, LIMITS)
        prev = q if status & UNSAFE_TARGET else np.asarray(target, float)
        qs.append(q)
        vs.append(v)
        statuses.append(status)
    return np.array(qs), np.array(vs), statuses


@settings(max_examples=150, deadline=None)
@given(targets)
def test_any_target_sequence_stays_finite_in_limits_speed_and_acceleration(seq):
    qs, _, _ = drive(seq)
    assert np.isfinite(qs).all()
    assert (qs >= LIMITS.lower - TOL).all() and (qs <= LIMITS.upper + TOL).all()
    speed = np.diff(qs, axis=0) / DT  # measured from the commands themselves
    assert (np.abs(speed) <= LIMITS.max_speed + 1e-6).all()
    accel = np.diff(np.vstack([np.zeros(6), speed]), axis=0) / DT
    assert (np.abs(accel) <= LIMITS.max_accel + 1e-4).all()


@settings(max_examples=60, deadline=None)
@given(targets)
def test_the_kernel_updating_its_state_in_place_equals_separate_outputs(seq):
    # the pipeline's limit stage passes the state's q and v as both input and output
    lim = (LIMITS.lower, LIMITS.upper, LIMITS.max_speed, LIMITS.max_accel)
    qs, vs, statuses = drive(seq)
    q, v, prev = np.zeros(6), np.zeros(6), np.zeros(6)
    for k, target in enumerate(seq):
        target = np.asarray(target, float)
        status = limit_kernel(q, v, prev, target, DT, *lim, q, v)
        assert status == statuses[k]
        assert np.array_equal(q, qs[k + 1]) and np.array_equal(v, vs[k + 1])
        prev = q.copy() if status & UNSAFE_TARGET else target


def test_unsafe_target_holds_the_whole_vector():
    q0 = np.full(6, 0.2)
    target = np.array([0.3, 0.3, np.nan, 0.3, 0.3, 0.3])
    q, v, status = limit_command(q0, np.zeros(6), q0, target, DT, LIMITS)
    assert status & UNSAFE_TARGET
    assert np.array_equal(q, q0)  # no leg moves alone
    target = np.array([0.3, 0.3, 0.3, 5.0, 0.3, 0.3])  # one leg beyond its limit
    q, v, status = limit_command(q0, np.zeros(6), q0, target, DT, LIMITS)
    assert status & UNSAFE_TARGET and np.array_equal(q, q0)


def test_step_target_is_reached_without_overshoot_in_the_time_physics_predicts():
    # A trapezoidal profile from 0 to 0.9 rad at vmax 3, amax 30: accelerate for 0.1 s
    # (0.15 rad), cruise, decelerate for 0.1 s: total 0.9/3 + 0.1 = 0.4 s.
    seq = [np.full(6, 0.9)] * 120
    qs, _, statuses = drive(seq)
    assert (qs <= 0.9 + 1e-12).all()  # never beyond the target
    assert np.all(np.diff(qs[:, 0]) >= -1e-12)  # monotonic (to rounding)
    reached = np.argmax(np.all(np.abs(qs - 0.9) < 1e-12, axis=1)) * DT
    assert 0.4 - 2 * DT <= reached <= 0.4 + 4 * DT
    assert statuses[0] & RATE_LIMITED
    assert statuses[-1] == 0


def test_a_smooth_moving_target_within_the_limits_is_tracked_exactly():
    # 0.25 (1 - cos(pi t)) starts at rest: peak speed 0.79 rad/s, peak acceleration 2.5 rad/s^2
    t = np.arange(0, 4, DT)
    seq = [np.full(6, 0.25 * (1 - np.cos(np.pi * tk))) for tk in t]
    qs, _, statuses = drive(seq)
    assert np.allclose(qs[1:], np.array(seq), atol=1e-12)
    assert sum(s & RATE_LIMITED for s in statuses) == 0


def test_a_target_that_stops_at_the_limit_is_not_overshot():
    # the target runs into the upper limit at full speed and stops there
    seq = [np.full(6, min(1.0, -0.5 + 2.5 * k * DT)) for k in range(200)]
    qs, _, _ = drive(seq)
    assert qs.max() <= 1.0 and np.isclose(qs[-1, 0], 1.0)


def test_small_moves_pass_through_unchanged():
    q, v, status = limit_command(
        np.zeros(6), np.zeros(6), np.zeros(6), np.full(6, 1e-3), DT, LIMITS
    )
    # 1e-3 rad in one tick at rest needs 0.12 rad/s and 14.4 rad/s^2: within limits
    assert status == 0 and np.array_equal(q, np.full(6, 1e-3))


def test_input_validation_names_the_problem():
    lim = InputLimits()
    g = np.array([0.0, 0.0, -9.80665])
    z = np.zeros(3)
    assert input_problem(0.0, g, z, z, None, lim) is None
    assert "specific force" in input_problem(0.0, np.array([np.nan, 0, 0]), z, z, None, lim)
    assert "specific force" in input_problem(0.0, np.array([1e6, 0, 0]), z, z, None, lim)
    assert "angular velocity" in input_problem(0.0, g, np.array([0, 0, 1e3]), z, None, lim)
    assert "attitude" in input_problem(0.0, g, z, np.array([1e3, 0, 0]), None, lim)
    assert "time" in input_problem(1.0, g, z, z, 1.0, lim)
    assert "time" in input_problem(math.nan, g, z, z, None, lim)


def test_smoothstep_is_a_c1_ramp():
    assert smoothstep(-1) == 0 and smoothstep(0) == 0 and smoothstep(1) == 1 and smoothstep(2) == 1
    assert smoothstep(0.5) == 0.5
    xs = np.linspace(0, 1, 1001)
    ys = np.array([smoothstep(x) for x in xs])
    assert np.all(np.diff(ys) >= 0)
    slope = np.diff(ys) / np.diff(xs)
    assert slope[0] < 0.01 and slope[-1] < 0.01  # zero slope at both ends
