"""Behaviour of the classical washout against physics and independently computed designs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from motionbase.errors import ConfigError
from motionbase.washout import ClassicalWashout, WashoutInputError, WashoutParams

G = 9.80665
DT = 1.0 / 120.0  # the pipeline rate of the JSBSim scripts
LEVEL = np.array([0.0, 0.0, -G])


@pytest.fixture(scope="module")
def params() -> WashoutParams:
    return WashoutParams.preset("default")


def constant(n: int, f=LEVEL, w=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    return np.tile(np.asarray(f, float), (n, 1)), np.tile(np.asarray(w, float), (n, 1))


def slowest_decay(wn: float, zeta: float, wb: float | None = None) -> float:
    """Real part magnitude of the slowest pole of the (continuous) design."""
    if zeta >= 1.0:
        sigma = wn * (zeta - np.sqrt(zeta * zeta - 1.0))
    else:
        sigma = zeta * wn
    return min(sigma, wb) if wb is not None else sigma


# --- level flight ------------------------------------------------------------------------------


def test_level_flight_for_60_s_is_exactly_neutral(params):
    n = int(60.0 / DT)
    f, w = constant(n)
    wo = ClassicalWashout(params, DT)
    poses = wo.run(f, w)
    assert poses.shape == (n, 6)
    assert np.all(poses == 0.0)
    for _ in range(100):
        assert np.all(wo.step(LEVEL, np.zeros(3)) == 0.0)


# --- tilt coordination ---------------------------------------------------------------------


def test_sustained_forward_force_pitches_nose_up_rate_limited_and_surge_washes_out(params):
    n = int(60.0 / DT)
    f, w = constant(n, f=(1.0, 0.0, -G))
    poses = ClassicalWashout(params, DT).run(f, w)
    pitch, surge = poses[:, 4], poses[:, 0]
    kx = params.specific_force_gain[0]
    expected = np.arcsin(kx * 1.0 / G)
    assert expected < params.tilt_angle_limit[1]  # (roll, pitch)
    assert pitch[-1] == pytest.approx(expected, rel=1e-6)
    # nose up, never faster than the rate limit, never beyond the target
    assert np.all(np.diff(pitch) >= 0.0)
    assert np.max(np.diff(pitch)) / DT <= params.tilt_rate_limit[1] * (1 + 1e-9)
    assert pitch.max() <= expected * (1 + 1e-9)
    # surge: first forward, then back toward neutral with the design's slowest pole
    assert surge[int(0.5 / DT)] > 0.0
    peak = np.max(np.abs(surge))
    t_tilt = expected / params.tilt_rate_limit[1]  # time the tilt needs to reach its target
    sigma = slowest_decay(
        params.translational_wn[0], params.translational_zeta[0], params.translational_wb[0]
    )
    t_pred = t_tilt + 6.0 / sigma  # e^-6 ~ 0.25 %: settled to within a few % of the peak
    late = np.abs(surge[int(t_pred / DT) :])
    assert late.max() < 0.05 * peak
    assert abs(surge[-1]) < 1e-3 * peak
    # no sustained lateral, vertical or yaw cue
    assert np.all(poses[:, [1, 3, 5]] == 0.0)


@pytest.mark.parametrize("fy", [1.0, -1.0])
def test_sustained_lateral_force_rolls_toward_it_with_the_correct_sign(params, fy):
    n = int(30.0 / DT)
    f, w = constant(n, f=(0.0, fy, -G))
    poses = ClassicalWashout(params, DT).run(f, w)
    roll, pitch = poses[-1, 3], poses[-1, 4]
    # f_y > 0 rolls left wing down (negative roll) and vice versa
    assert np.sign(roll) == -np.sign(fy)
    # a cab at rest tilted by (roll, pitch) feels f_y = -g sin(roll) cos(pitch): the scaled cue
    felt_y = -G * np.sin(roll) * np.cos(pitch)
    assert felt_y == pytest.approx(params.specific_force_gain[1] * fy, rel=1e-6)
    assert np.max(np.abs(np.diff(poses[:, 3]))) / DT <= params.tilt_rate_limit[0] * (1 + 1e-9)


@pytest.mark.parametrize("fx", [1.0, -1.0])
def test_tilt_pitch_sign_matches_the_felt_gravity(params, fx):
    n = int(30.0 / DT)
    f, w = constant(n, f=(fx, 0.0, -G))
    pitch = ClassicalWashout(params, DT).run(f, w)[-1, 4]
    assert np.sign(pitch) == np.sign(fx)  # forward: nose up
    assert G * np.sin(pitch) == pytest.approx(params.specific_force_gain[0] * fx, rel=1e-6)


def per_axis_tilt() -> WashoutParams:
    """The default set with different tilt limits for roll and pitch (rate, angle, accel)."""
    return dataclasses.replace(
        WashoutParams.preset("default"),
        tilt_rate_limit_deg_s=(2.0, 3.5),
        tilt_angle_limit_deg=(5.0, 7.5),
        tilt_accel_limit_deg_s2=(5.0, 10.0),
    )


#: The default set (one value for roll and pitch) and a set with limits per tilt axis.
TILT_SETS = pytest.mark.parametrize(
    "tilt_params",
    [
        pytest.param(lambda: WashoutParams.preset("default"), id="one"),
        pytest.param(per_axis_tilt, id="per-axis"),
    ],
)


@TILT_SETS
def test_tilt_is_angle_limited(tilt_params):
    params = tilt_params()
    n = int(30.0 / DT)
    f, w = constant(n, f=(4.0, -4.0, -G))  # targets well beyond the tilt limit
    poses = ClassicalWashout(params, DT).run(f, w)
    lim = params.tilt_angle_limit  # (roll, pitch), the pose's columns 3 and 4
    assert (np.abs(poses[:, 3:5]) <= lim * (1 + 1e-12)).all()
    # the rate limit is engaged here on each axis, and holds exactly
    rates = np.abs(np.diff(poses[:, 3:5], axis=0)) / DT
    assert rates.max(axis=0) == pytest.approx(params.tilt_rate_limit, rel=1e-9)
    assert poses[-1, 4] == pytest.approx(lim[1], rel=1e-12)
    assert poses[-1, 3] == pytest.approx(lim[0], rel=1e-12)  # f_y < 0: right wing down


def test_tilt_off_about_one_axis_leaves_that_force_to_the_translational_channel():
    """A roll tilt limit of 0 turns tilt coordination off for sway only: a sustained
    sideways force gives no roll (its onset goes to the sway channel, which washes out),
    while a forward force still pitches the cab to the felt angle."""
    params = dataclasses.replace(WashoutParams.preset("default"), tilt_angle_limit_deg=(0.0, 8.0))
    n = int(60.0 / DT)
    f, w = constant(n, f=(0.5, 0.5, -G))
    poses = ClassicalWashout(params, DT).run(f, w)
    assert np.all(poses[:, 3] == 0.0)  # no roll at all
    assert np.max(np.abs(poses[:, 1])) > 1e-3  # the onset is cued by sway ...
    assert abs(poses[-1, 1]) < 1e-4  # ... and washed out
    assert G * np.sin(poses[-1, 4]) == pytest.approx(params.specific_force_gain[0] * 0.5, rel=1e-6)


def _tilt_rates(tilt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-tick tilt rate (rad/s) and its change per tick (rad/s), from rest at 0."""
    rate = np.diff(tilt, axis=0, prepend=0.0) / DT
    return rate, np.diff(rate, axis=0, prepend=0.0)


@TILT_SETS
def test_tilt_brakes_before_the_angle_limit_with_a_continuous_rate(tilt_params):
    """A force far beyond the tilt limit, held, then released: the tilt rate ramps, it is
    never cut in one tick, and the tilt slows down before the limit instead of halting on it."""
    params = tilt_params()
    on, off = int(15.0 / DT), int(15.0 / DT)
    f, w = constant(on + off, f=(4.0, -4.0, -G))  # both targets well beyond the limit
    f[on:] = LEVEL
    poses = ClassicalWashout(params, DT).run(f, w)
    tilt = poses[:, 3:5]  # no rotation input: the pose angles are the tilt
    lims, vmaxs, amaxs = params.tilt_angle_limit, params.tilt_rate_limit, params.tilt_accel_limit
    rate, jump = _tilt_rates(tilt)
    assert (np.abs(tilt) <= lims).all()  # never beyond the angle limit, not even by rounding
    assert (np.abs(rate) <= vmaxs * (1 + 1e-9)).all()
    assert (np.abs(jump) <= amaxs * DT * (1 + 1e-9)).all()  # the rate never steps
    for axis in (0, 1):  # f_y < 0 rolls right wing down (+), f_x > 0 pitches nose up (+)
        lim, vmax, amax = lims[axis], vmaxs[axis], amaxs[axis]
        x, v = tilt[:on, axis], rate[:on, axis]
        k_hold = int(np.argmax(x == lim))  # first tick exactly on the limit
        assert x[k_hold] == lim and np.all(x[k_hold:] == lim)  # then held there exactly
        # no faster than from rest at full acceleration, a cruise at the rate limit and
        # braking at full deceleration; within 1 % of the limit a second after that
        t_min = lim / vmax + vmax / amax
        assert k_hold * DT >= t_min - 3 * DT  # (discrete ramps: a tick or two early)
        assert np.argmax(x >= 0.99 * lim) * DT <= t_min + 1.0
        # it cruises at the rate limit, then slows down well before the limit (the old
        # limiter ran into it at full rate) and keeps decelerating until it rests on it
        k_cruise = int(np.argmax(v >= vmax * (1 - 1e-9)))
        assert v[k_cruise] > 0.0
        k_slow = k_cruise + int(np.argmax(v[k_cruise:] < vmax * (1 - 1e-9)))
        assert lim - x[k_slow] > 0.5 * vmax**2 / amax  # braking starts before the limit
        assert np.all(np.diff(v[k_slow : k_hold + 1]) <= 1e-12)
        assert v[k_hold] <= amax * DT  # arrives at (nearly) zero rate
    # released: back to neutral the same way, no overshoot past neutral
    assert np.all(np.abs(tilt[-1]) < 1e-12)
    assert np.all(np.sign(tilt[on:, 0]) >= 0.0) and np.all(np.sign(tilt[on:, 1]) >= 0.0)


@settings(max_examples=40, deadline=None)
@given(
    arrays(np.float64, (24, 2), elements=st.floats(-6.0, 6.0)),
    st.integers(1, 120),
)
def test_tilt_limits_hold_for_any_specific_force_history(levels, hold):
    """Piecewise-constant forces (jumps of either sign, held for ``hold`` ticks): the tilt
    never leaves the angle limit and its rate never exceeds the rate limit or steps by
    more than the acceleration limit allows, each axis within its own limits."""
    params = per_axis_tilt()
    fxy = np.repeat(levels, hold, axis=0)
    f = np.column_stack([fxy, np.full(len(fxy), -G)])
    poses = ClassicalWashout(params, DT).run(f, np.zeros_like(f))
    tilt = poses[:, 3:5]
    rate, jump = _tilt_rates(tilt)
    assert (np.abs(tilt) <= params.tilt_angle_limit).all()
    assert (np.abs(rate) <= params.tilt_rate_limit * (1 + 1e-9)).all()
    assert (np.abs(jump) <= params.tilt_accel_limit * DT * (1 + 1e-9)).all()


# --- heave ---------------------------------------------------------------------------------


@pytest.mark.parametrize("method,dt", [("tustin", DT), ("zoh", 1.0 / 1000.0)])
def test_heave_step_matches_the_continuous_transfer_function(params, method, dt):
    p = dataclasses.replace(params, method=method)
    amp = 1.0  # 1 m/s^2 upward: f_z = -g - 1
    n = int(20.0 / dt)
    f, w = constant(n, f=(0.0, 0.0, -G - amp))
    z = ClassicalWashout(p, dt).run(f, w)[:, 2]
    wn, zeta, wb = p.translational_wn[2], p.translational_zeta[2], p.translational_wb[2]
    k = p.specific_force_gain[2]
    # a_z = f_z + g = -amp (upward in FRD); z/a = s/((s^2 + 2 zeta wn s + wn^2)(s + wb))
    den = np.polymul([1.0, 2.0 * zeta * wn, wn * wn], [1.0, wb])
    t = np.arange(n) * dt
    _, ref = scipy.signal.step(([k * -amp, 0.0], den), T=t)
    peak = np.max(np.abs(ref))
    assert np.min(z) < 0.0  # heave up is negative z
    assert np.max(np.abs(z - ref)) < 0.01 * peak
    assert np.all(np.abs(f[:, :2]) == 0.0)


# --- rotation ------------------------------------------------------------------------------


def test_sustained_roll_rate_washes_out(params):
    n = int(60.0 / DT)
    f, w = constant(n, w=(np.radians(10.0), 0.0, 0.0))
    poses = ClassicalWashout(params, DT).run(f, w)
    roll = poses[:, 3]
    peak = np.max(np.abs(roll))
    assert peak > 0.0 and roll[np.argmax(np.abs(roll))] > 0.0  # first with the aircraft
    assert abs(roll[-1]) < 1e-3 * peak
    assert np.all(poses[:, [0, 4, 5]] == 0.0)
    # the roll tilts gravity into the cab's y axis; the translational channel answers with a
    # transient rightward acceleration that cancels it (a_y = g sin(roll)), then washes out
    assert poses[np.argmax(np.abs(poses[:, 1])), 1] > 0.0
    assert np.max(np.abs(poses[-1, :3])) < 1e-4


def test_coordinated_turn_gives_no_sustained_lateral_cue(params):
    n = int(80.0 / DT)
    t = np.arange(n) * DT
    bank = np.radians(30.0)
    roll_in = 2.0  # s
    p_rate = np.where(t < roll_in, bank / roll_in, 0.0)
    phi = np.minimum(t / roll_in, 1.0) * bank
    v = 50.0  # m/s true airspeed
    omega = G * np.tan(phi) / v  # turn rate
    w = np.column_stack([p_rate, omega * np.sin(phi), omega * np.cos(phi)])
    f = np.column_stack([np.zeros(n), np.zeros(n), -G / np.cos(phi)])  # f_y = 0
    wo = ClassicalWashout(params, DT)
    poses = wo.run(f, w)
    assert np.all(wo.state.tilt == 0.0)  # no lateral force, no lateral tilt
    # (a transient sway is expected: the translational channel compensates the gravity
    # that the rotational channel's roll tilts into the cab, Reid & Nahon's L_IS f_s + g)
    # the roll cue of the entry washes out: no sustained bank of the cab
    end = slice(int(70.0 / DT), None)
    assert np.max(np.abs(poses[end, 3])) < np.radians(0.1)
    assert np.max(np.abs(poses[end, 1])) < 1e-3
    felt_y = -G * np.sin(poses[end, 3]) * np.cos(poses[end, 4])
    assert np.max(np.abs(felt_y)) < 0.02  # well under the 0.17 m/s^2 threshold


# --- frequency response --------------------------------------------------------------------


def _fit(y: np.ndarray, t: np.ndarray, omega: float) -> complex:
    basis = np.column_stack([np.sin(omega * t), np.cos(omega * t), np.ones_like(t)])
    (a, b, _), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return complex(a, b)  # y ~ a sin + b cos = Im[(a + jb) e^{jwt}]


def _continuous_design(params: WashoutParams, channel: str) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator (descending powers of s) of each channel's design."""
    lw, lz = params.tilt_wn, params.tilt_zeta
    lp_den = np.array([1.0, 2 * lz * lw, lw * lw])
    if channel in ("x", "y", "z"):
        i = "xyz".index(channel)
        wn, zeta = params.translational_wn[i], params.translational_zeta[i]
        wb = params.translational_wb[i]
        k = params.specific_force_gain[i]
        den = np.polymul([1.0, 2 * zeta * wn, wn * wn], [1.0, wb])
        if channel == "z":
            return np.array([k, 0.0]), den
        # tilt coordination removes the low-passed part: a = K f (1 - LP(s))
        one_minus_lp = np.array([1.0, 2 * lz * lw, 0.0])
        return k * np.polymul([1.0, 0.0], one_minus_lp), np.polymul(den, lp_den)
    if channel == "tilt_pitch":  # pitch = asin(K f_lx / g) ~ K/g LP(s) f_x
        return np.array([params.specific_force_gain[0] / G * lw * lw]), lp_den
    i = ("roll", "pitch", "yaw").index(channel)
    wn, zeta = params.rotational_wn[i], params.rotational_zeta[i]
    return np.array([params.angular_velocity_gain[i], 0.0]), np.array([1.0, 2 * zeta * wn, wn * wn])


def _freqs_reference(params: WashoutParams, channel: str, omega: float) -> complex:
    num, den = _continuous_design(params, channel)
    _, h = scipy.signal.freqs(num, den, worN=[omega])
    return complex(h[0])


CHANNELS = {
    # channel: (input column 0..5 of [f, w], pose column, amplitude)
    "x": (0, 0, 0.5),
    "y": (1, 1, 0.5),
    "z": (2, 2, 0.5),
    "tilt_pitch": (0, 4, 0.5),
    "roll": (3, 3, 0.02),
    "pitch": (4, 4, 0.02),
    "yaw": (5, 5, 0.02),
}


@pytest.mark.parametrize("omega", [0.1, 1.0, 10.0])
@pytest.mark.parametrize("channel", list(CHANNELS))
def test_sinusoid_gain_and_phase_match_the_continuous_design(params, channel, omega):
    col_in, col_out, amp = CHANNELS[channel]
    period = 2 * np.pi / omega
    settle = 60.0
    t_end = settle + max(2, int(np.ceil(20.0 / period))) * period
    n = int(np.round(t_end / DT))
    t = np.arange(n) * DT
    inp = np.zeros((n, 6))
    inp[:, :3] = LEVEL
    inp[:, col_in] += amp * np.sin(omega * t)
    y = ClassicalWashout(params, DT).run(inp[:, :3], inp[:, 3:])[:, col_out]
    keep = t >= t_end - (max(2, int(np.ceil(20.0 / period)))) * period
    measured = _fit(y[keep], t[keep], omega) / amp
    ref = _freqs_reference(params, channel, omega)
    assert abs(measured) == pytest.approx(abs(ref), rel=0.02)
    dphase = np.degrees(np.angle(measured / ref))
    assert abs(dphase) < 2.0


# --- streaming, batch, robustness ------------------------------------------------------------


def _random_inputs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    f = LEVEL + rng.normal(0.0, 2.0, (n, 3)).cumsum(axis=0) * 0.05
    w = rng.normal(0.0, 0.3, (n, 3)).cumsum(axis=0) * 0.02
    return f, w


def test_streaming_equals_batch_bit_for_bit(params):
    rng = np.random.default_rng(3)
    f, w = _random_inputs(rng, 3000)
    batch = ClassicalWashout(params, DT).run(f, w)
    streamer = ClassicalWashout(params, DT)
    stream = np.array([streamer.step(f[k], w[k]) for k in range(len(f))])
    assert np.array_equal(batch, stream)
    chunked = ClassicalWashout(params, DT)
    parts = [chunked.run(f[a : a + 700], w[a : a + 700]) for a in range(0, len(f), 700)]
    assert np.array_equal(np.vstack(parts), batch)
    assert np.array_equal(chunked.state.to_vector(), streamer.state.to_vector())


def _box_clamp(limits: np.ndarray):
    """Scale the whole pose toward neutral until every axis is inside +-limits."""

    def clamp(pose: np.ndarray) -> np.ndarray:
        ratio = np.max(np.abs(pose) / limits)
        return pose / ratio if ratio > 1.0 else pose

    return clamp


def test_streaming_equals_batch_with_a_clamp(params):
    rng = np.random.default_rng(4)
    f, w = _random_inputs(rng, 1500)
    clamp = _box_clamp(np.array([0.02, 0.02, 0.02, 0.02, 0.02, 0.05]))
    batch = ClassicalWashout(params, DT).run(f, w, clamp=clamp)
    wo = ClassicalWashout(params, DT)
    stream = np.empty_like(batch)
    n_tracked = 0
    for k in range(len(f)):
        pose = wo.step(f[k], w[k])
        stream[k] = pose
        achieved = clamp(pose)
        if not np.array_equal(achieved, pose):
            wo.track(achieved)
            n_tracked += 1
    assert n_tracked > 100
    assert np.array_equal(batch, stream)


def test_anti_windup_returns_to_neutral_without_extra_overshoot(params):
    on, off = 40.0, 60.0
    n_on, n_off = int(on / DT), int(off / DT)
    f = np.tile(LEVEL, (n_on + n_off, 1))
    w = np.zeros((n_on + n_off, 3))
    f[:n_on] += [3.0, -3.0, -2.0]  # large sustained forces on every axis
    w[:n_on] = np.radians([20.0, 15.0, 25.0])  # and large sustained rates
    free = ClassicalWashout(params, DT).run(f, w)
    limits = 0.3 * np.max(np.abs(free), axis=0)  # a clamp that cuts hard
    clamp = _box_clamp(limits)
    wo = ClassicalWashout(params, DT)
    out = wo.run(f, w, clamp=clamp)
    achieved = np.array([clamp(p) for p in out])
    assert np.mean(np.any(out != achieved, axis=1)) > 0.05  # the clamp was really active
    # the filter output does not wind up beyond the limit: one step past it at most
    step_size = np.max(np.abs(np.diff(free, axis=0)), axis=0)
    assert np.all(np.max(np.abs(out), axis=0) <= limits + 2 * step_size + 1e-12)
    # after the input is removed: back to neutral, no overshoot beyond the free run's
    rel = slice(n_on, None)
    assert np.all(
        np.max(np.abs(achieved[rel]), axis=0) <= np.max(np.abs(free[rel]), axis=0) + 1e-12
    )
    # promptly: within the time the free run needs to settle to 1 % of its excursion,
    # counted from when the clamp lets go (the box clamp scales the whole pose, so it keeps
    # acting for several seconds after the input is removed, while the slower axes are still
    # beyond their limits; until then the pose is the clamp's, not the filter's)
    scale = np.max(np.abs(free[rel]), axis=0)
    settled_free = np.all(np.abs(free[rel]) <= 0.01 * scale, axis=1)
    t_free = np.argmax(settled_free & np.flip(np.cumprod(np.flip(settled_free)) > 0)) * DT
    k_released = int(np.max(np.nonzero(np.any(out != achieved, axis=1))[0]))
    assert k_released >= n_on
    k_check = k_released + int((t_free * 1.5 + 5.0) / DT)
    assert k_check < len(f)
    assert np.all(np.abs(achieved[k_check:]) <= 0.01 * scale)
    assert np.all(np.abs(achieved[-1]) <= 1e-3 * scale)  # no sticking


@settings(max_examples=60, deadline=None)
@given(
    arrays(
        np.float64,
        (40, 6),
        elements=st.floats(-1e300, 1e300, allow_nan=False, allow_infinity=False),
    )
)
def test_random_and_extreme_finite_inputs_never_give_nan_or_inf(data):
    wo = ClassicalWashout(WashoutParams.preset("default"), DT)
    poses = wo.run(data[:, :3], data[:, 3:])
    assert np.isfinite(poses).all()
    assert np.isfinite(wo.state.to_vector()).all()


def test_extreme_constant_and_alternating_inputs_stay_finite(params):
    big = np.finfo(float).max
    for f0, w0 in [(big, big), (-big, -big), (1e6, 1e3), (-1e6, -1e3)]:
        n = 2000
        sign = np.where(np.arange(n) % 7 < 3, 1.0, -1.0)[:, None]
        f = np.full((n, 3), f0) * sign
        w = np.full((n, 3), w0) * sign[::-1]
        poses = ClassicalWashout(params, DT).run(f, w)
        assert np.isfinite(poses).all()


# --- API contract --------------------------------------------------------------------------


def test_reset_state_and_bad_input(params):
    wo = ClassicalWashout(params, DT)
    for _ in range(300):
        wo.step([1.0, 0.5, -G - 0.5], [0.1, 0.0, 0.05])
    s = wo.state
    assert s.tilt[1] > 0.0 and s.tilt[0] < 0.0
    with pytest.raises(ValueError):
        s.pose[0] = 1.0  # read-only snapshot
    before = wo.state.to_vector()
    with pytest.raises(WashoutInputError, match="non-finite"):
        wo.step([np.nan, 0.0, -G], [0.0, 0.0, 0.0])
    with pytest.raises(WashoutInputError, match="3 numbers"):
        wo.step([0.0, -G], [0.0, 0.0, 0.0])
    with pytest.raises(WashoutInputError, match=r"\(N, 3\)"):
        wo.run(np.zeros((5, 2)), np.zeros((5, 3)))
    with pytest.raises(WashoutInputError, match="sample 2"):
        wo.run(
            np.tile(LEVEL, (4, 1)) + [[0, 0, 0], [0, 0, 0], [np.inf, 0, 0], [0, 0, 0]],
            np.zeros((4, 3)),
        )
    assert np.array_equal(wo.state.to_vector(), before)
    wo.reset()
    assert np.all(wo.state.to_vector() == 0.0)
    wo.state = s
    assert np.array_equal(wo.state.to_vector(), s.to_vector())
    with pytest.raises(WashoutInputError):
        wo.track([0.0] * 5)


def test_bad_sample_period_is_a_config_error(params):
    with pytest.raises(ConfigError, match="dt"):
        ClassicalWashout(params, 0.0)
    with pytest.raises(ConfigError, match="Nyquist"):
        ClassicalWashout(params, 2.0)  # 2 rad/s tilt filter at 0.5 Hz sampling


# --- input low-pass (telemetry) ------------------------------------------------------------


def test_input_lowpass_is_off_in_the_default_and_on_in_the_telemetry_preset(params):
    assert params.input_lowpass_wn == 0.0
    assert WashoutParams.preset("gentle").input_lowpass_wn == 0.0
    assert WashoutParams.preset("telemetry").input_lowpass_wn > 0.0


def test_level_flight_stays_exactly_neutral_with_the_input_lowpass():
    p = WashoutParams.preset("telemetry")
    f, w = constant(int(30.0 / DT))
    assert np.all(ClassicalWashout(p, DT).run(f, w) == 0.0)


@pytest.mark.parametrize("method,dt", [("tustin", DT), ("zoh", 1.0 / 1000.0)])
def test_heave_step_through_the_input_lowpass_matches_the_continuous_design(params, method, dt):
    wn_in = 8.0
    p = dataclasses.replace(params, method=method, input_lowpass_wn=wn_in)
    amp = 1.0
    n = int(20.0 / dt)
    f, w = constant(n, f=(0.0, 0.0, -G - amp))
    z = ClassicalWashout(p, dt).run(f, w)[:, 2]
    wn, zeta, wb = p.translational_wn[2], p.translational_zeta[2], p.translational_wb[2]
    k = p.specific_force_gain[2]
    # z/a = wn_in^2/(s + wn_in)^2 * s/((s^2 + 2 zeta wn s + wn^2)(s + wb))
    den = np.polymul(
        np.polymul([1.0, 2.0 * zeta * wn, wn * wn], [1.0, wb]), [1.0, 2.0 * wn_in, wn_in**2]
    )
    t = np.arange(n) * dt
    _, ref = scipy.signal.step(([k * -amp * wn_in**2, 0.0], den), T=t)
    peak = np.max(np.abs(ref))
    assert np.max(np.abs(z - ref)) < 0.01 * peak
    # and the low-pass delays it: the plain washout's response leads
    plain = ClassicalWashout(dataclasses.replace(p, input_lowpass_wn=0.0), dt).run(f, w)[:, 2]
    assert np.argmin(plain) < np.argmin(z)


def test_input_lowpass_keeps_the_sustained_tilt():
    p = WashoutParams.preset("telemetry")
    f, w = constant(int(40.0 / DT), f=(1.0, -0.8, -G))
    pose = ClassicalWashout(p, DT).run(f, w)[-1]
    k = p.specific_force_gain
    pitch = np.arcsin(k[0] * 1.0 / G)
    roll = -np.arcsin(k[1] * -0.8 / (G * np.cos(pitch)))
    np.testing.assert_allclose(pose[3:5], [roll, pitch], atol=1e-9)


def test_input_lowpass_turns_a_held_staircase_of_rates_into_ramps():
    """Telemetry at 4 Hz held at 100 Hz: without the low-pass each step of the roll rate is a
    step of the platform's roll rate (the rotational high-pass passes it; the trapezoidal
    rule spreads it over two ticks: an angular acceleration spike); with it the rate changes
    by at most what the low-pass's step response allows per tick, about
    gain * step * wn * dt / e (its steepest slope)."""
    dt = 0.01
    rng = np.random.default_rng(3)
    levels = np.radians(rng.uniform(-15.0, 15.0, 60))  # within the 20 deg/s saturation
    w = np.zeros((levels.size * 25, 3))
    w[:, 0] = np.repeat(levels, 25)
    f = np.tile(LEVEL, (w.shape[0], 1))
    p = WashoutParams.preset("telemetry")
    k = p.angular_velocity_gain[0]
    step = np.max(np.abs(np.diff(levels)))
    jump = {}
    for wn in (0.0, p.input_lowpass_wn):
        roll = ClassicalWashout(dataclasses.replace(p, input_lowpass_wn=wn), dt).run(f, w)[:, 3]
        rate = np.diff(roll) / dt
        jump[wn] = np.max(np.abs(np.diff(rate)))
    assert jump[0.0] > 0.45 * k * step  # the plain washout passes the step (in two ticks)
    wn = p.input_lowpass_wn
    # steepest slope of the low-pass step response, plus the high-pass's own decay per tick
    bound = k * step * (wn * dt / np.e) * 1.1 + 2.0 * max(p.rotational_wn) * k * step * dt
    assert jump[wn] <= bound
    assert jump[wn] < 0.1 * jump[0.0]
