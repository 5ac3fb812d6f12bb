"""Perception models against their transfer functions; cueing metrics on known motions."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from motionbase.washout import (
    ClassicalWashout,
    WashoutParams,
    cueing_metrics,
    platform_angular_velocity,
    platform_specific_force,
)
from motionbase.washout.perception import (
    PerceptionInputError,
    perceived_angular_velocity,
    perceived_specific_force,
)

G = 9.80665
DT = 1.0 / 120.0


def _step_input(n: int, axis: int, amp: float) -> np.ndarray:
    u = np.zeros((n, 3))
    u[:, axis] = amp
    return u


def test_otolith_step_response_and_dc_gain_match_young_meiry():
    n = int(60.0 / DT)
    t = np.arange(n) * DT
    f = np.tile([0.0, 0.0, -G], (n, 1)) + _step_input(n, 0, 1.0)  # 1 m/s^2 forward from rest
    out = perceived_specific_force(f, DT, initial="rest")
    # K (tau_a s + 1)/((tau_L s + 1)(tau_s s + 1)), K = 0.4, tau_a 13.2, tau_L 5.33, tau_s 0.66
    ref_sys = scipy.signal.lti([0.4 * 13.2, 0.4], np.polymul([5.33, 1.0], [0.66, 1.0]))
    _, ref = scipy.signal.step(ref_sys, T=t)
    peak = np.max(np.abs(ref))
    assert np.max(np.abs(out[:, 0] - ref)) < 0.01 * peak
    assert np.all(out[:, 1:] == 0.0)  # level flight's 1 g removed, nothing on y, z
    long = perceived_specific_force(
        np.tile([0.0, 0.0, -G], (int(300 / DT), 1)) + _step_input(int(300 / DT), 2, 2.0),
        DT,
        initial="rest",
    )
    assert long[-1, 2] == pytest.approx(0.4 * 2.0, rel=1e-3)  # DC gain K
    norm = perceived_specific_force(f, DT, initial="rest", normalized=True)
    assert np.allclose(norm, out / 0.4)


@pytest.mark.parametrize("axis,tau_l", [(0, 6.1), (1, 5.3), (2, 10.2)])
def test_canal_step_response_and_gains_match_the_model(axis, tau_l):
    n = int(120.0 / DT)
    t = np.arange(n) * DT
    w = _step_input(n, axis, 0.1)
    out = perceived_angular_velocity(w, DT, initial="rest")[:, axis]
    num = [tau_l * 30.0, 0.0, 0.0]
    den = np.polymul(np.polymul([tau_l, 1.0], [0.1, 1.0]), [30.0, 1.0])
    # the discrete model sees samples joined by straight lines (bilinear transform): the
    # continuous reference gets the same input, a ramp from 0 at t = -dt to the step at t = 0
    tt = np.concatenate([[-DT], t])
    _, ref, _ = scipy.signal.lsim((num, den), np.concatenate([[0.0], np.full(n, 0.1)]), tt - tt[0])
    ref = ref[1:]
    assert np.max(np.abs(out - ref)) < 0.01 * np.max(np.abs(ref))
    # DC gain 0: a constant rate is no longer felt (adaptation)
    long = perceived_angular_velocity(_step_input(int(600 / DT), axis, 0.1), DT, initial="rest")
    assert abs(long[-1, axis]) < 1e-3 * 0.1
    # mid-band: sinusoid at 1 rad/s has the gain |H(j)| of the model
    omega = 1.0
    ts = np.arange(int(200 / DT)) * DT
    ws = np.zeros((ts.size, 3))
    ws[:, axis] = np.sin(omega * ts)
    ys = perceived_angular_velocity(ws, DT, initial="rest")[ts > 100, axis]
    _, h = scipy.signal.freqs(num, den, worN=[omega])
    assert np.max(np.abs(ys)) == pytest.approx(abs(h[0]), rel=0.01)


# --- platform motion in cab axes -----------------------------------------------------------------


def test_the_kept_model_designs_are_each_models_own():
    """The discrete models are designed once per model and rate and kept: interleaved
    rates and axes each give what a fresh design of that model gives (scipy's bilinear
    transform and lfilter, started in steady state), whatever was asked before."""
    rng = np.random.default_rng(5)
    w = rng.normal(0.0, 0.2, (600, 3))
    for dt in (DT, 1.0 / 100.0, DT, 1.0 / 30.0):
        out = perceived_angular_velocity(w, dt)
        for axis, tau_l in enumerate((6.1, 5.3, 10.2)):
            num = [tau_l * 30.0, 0.0, 0.0]
            den = np.polymul(np.polymul([tau_l, 1.0], [0.1, 1.0]), [30.0, 1.0])
            b, a = scipy.signal.bilinear(num, den, fs=1.0 / dt)
            zi = scipy.signal.lfilter_zi(b, a) * w[0, axis]
            ref = scipy.signal.lfilter(b, a, w[:, axis], zi=zi)[0]
            np.testing.assert_allclose(out[:, axis], ref, rtol=1e-12, atol=1e-15)


def test_a_tilted_cab_at_rest_feels_gravity_as_the_issue_states():
    roll, pitch = np.radians(7.0), np.radians(-4.0)
    pose = np.tile([0.0, 0.0, 0.0, roll, pitch, np.radians(20.0)], (50, 1))
    f = platform_specific_force(pose, DT)
    expected = [
        G * np.sin(pitch),
        -G * np.sin(roll) * np.cos(pitch),
        -G * np.cos(roll) * np.cos(pitch),
    ]
    assert np.allclose(f, expected, atol=1e-12)
    # nose up -> forward force; right wing down (positive roll) -> leftward force
    assert platform_specific_force(np.tile([0, 0, 0, 0, 0.1, 0], (5, 1)), DT)[0, 0] > 0
    assert platform_specific_force(np.tile([0, 0, 0, 0.1, 0, 0], (5, 1)), DT)[0, 1] < 0


def test_platform_translation_and_rates_are_measured_in_cab_axes():
    n = 600
    t = np.arange(n) * DT
    pose = np.zeros((n, 6))
    pose[:, 0] = 0.05 * np.sin(2.0 * t)  # surge
    pose[:, 5] = 0.3 * t  # constant yaw rate
    f = platform_specific_force(pose, DT)
    acc = -0.05 * 4.0 * np.sin(2.0 * t)
    yaw = pose[:, 5]
    # cab axes are yawed: base-frame acceleration (acc, 0) appears as R_z^T (acc, 0)
    assert np.allclose(f[1:-1, 0], np.cos(yaw[1:-1]) * acc[1:-1], atol=1e-4)
    assert np.allclose(f[1:-1, 1], -np.sin(yaw[1:-1]) * acc[1:-1], atol=1e-4)
    assert np.allclose(f[:, 2], -G)
    w = platform_angular_velocity(pose, DT)
    assert np.allclose(w, [0.0, 0.0, 0.3], atol=1e-9)
    # pitched 30 deg, a yaw rate shows on the roll axis: p = -sin(pitch) yaw_dot
    pose2 = pose.copy()
    pose2[:, 4] = np.radians(30.0)
    w2 = platform_angular_velocity(pose2, DT)
    assert np.allclose(w2[:, 0], -0.5 * 0.3, atol=1e-9)


# --- metrics -----------------------------------------------------------------------------------


def _smooth_motion(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A small pose trajectory and the exact specific force and rates it produces in the cab."""
    t = np.arange(n) * DT
    amp = np.array([0.03, 0.02, 0.015, 0.04, 0.03, 0.05])
    om = np.array([1.3, 0.9, 2.1, 0.7, 1.1, 0.5])
    pose = amp * np.sin(om * t[:, None])
    acc = -amp[:3] * om[:3] ** 2 * np.sin(om[:3] * t[:, None])
    rates = amp[3:] * om[3:] * np.cos(om[3:] * t[:, None])
    phi, th, psi = pose[:, 3], pose[:, 4], pose[:, 5]
    f = np.empty((n, 3))
    w = np.empty((n, 3))
    for k in range(n):
        cr, sr, cp, sp, cy, sy = (
            np.cos(phi[k]),
            np.sin(phi[k]),
            np.cos(th[k]),
            np.sin(th[k]),
            np.cos(psi[k]),
            np.sin(psi[k]),
        )
        rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        r = rz @ ry @ rx
        f[k] = r.T @ (acc[k] - [0.0, 0.0, G])
        # body rates: w = rx^T ry^T (0,0,psi') + rx^T (0,theta',0) + (phi',0,0)
        w[k] = [rates[k, 0], 0, 0] + rx.T @ [0, rates[k, 1], 0] + rx.T @ ry.T @ [0, 0, rates[k, 2]]
    return t, pose, f, w


def test_a_platform_that_reproduces_the_motion_exactly_has_near_zero_error():
    t, pose, f, w = _smooth_motion(int(60.0 / DT))
    m = cueing_metrics(t, f, w, pose, DT)
    assert np.all(m.rmse_specific_force < 2e-3)  # finite differences only
    assert np.all(m.rmse_angular_velocity < 1e-4)
    assert np.all(m.correlation_specific_force > 0.999)
    assert np.all(m.correlation_angular_velocity > 0.999)
    assert np.all(m.false_cue_specific_force == 0.0)
    assert np.all(m.false_cue_angular_velocity == 0.0)
    # DESIGN.md: surge reach 0.30 m back (the larger share of +-3 cm), 0.36 m forward
    assert m.workspace_usage[0] == pytest.approx(0.03 / 0.30, rel=1e-3)
    assert m.duration == pytest.approx(60.0, abs=2 * DT)
    text = m.summary()
    assert "RMSE" in text and "workspace usage" in text
    assert set(m.to_dict()) >= {"rmse_specific_force", "workspace_usage"}


def test_a_reversed_platform_motion_gives_false_cues_and_negative_correlation():
    t, pose, f, w = _smooth_motion(int(60.0 / DT))
    bigger = pose * 4.0
    m = cueing_metrics(t, -0.0 * f + np.array([0, 0, -G]), -0.0 * w, bigger, DT)
    # the aircraft does nothing: every perceived platform cue above threshold is false
    assert np.max(m.false_cue_specific_force) > 0.1
    assert np.max(m.false_cue_angular_velocity) > 0.1
    _, pose_r, _, _ = _smooth_motion(int(60.0 / DT))
    m2 = cueing_metrics(t, f, w, -4.0 * pose_r, DT)
    assert np.all(m2.correlation_angular_velocity < -0.9)


def test_tilt_coordination_is_perceived_as_sustained_specific_force():
    """The platform's tilt must count as specific force: a washout run shows it."""
    n = int(40.0 / DT)
    t = np.arange(n) * DT
    f = np.tile([0.0, 0.0, -G], (n, 1))
    f[int(2.0 / DT) :, 0] += 1.0  # sustained forward specific force from t = 2 s
    w = np.zeros((n, 3))
    params = WashoutParams.preset("default")
    pose = ClassicalWashout(params, DT).run(f, w)
    cab = platform_specific_force(pose, DT)
    # at the end the platform is still, tilted: it renders K_x * 1 m/s^2 by gravity
    assert cab[-1, 0] == pytest.approx(params.specific_force_gain[0] * 1.0, rel=1e-3)
    m = cueing_metrics(t, f, w, pose, DT)
    assert m.correlation_specific_force[0] > 0.7  # same shape: onset, then sustained


def test_bad_inputs_are_rejected_with_a_clear_error():
    t, pose, f, w = _smooth_motion(100)
    with pytest.raises(PerceptionInputError, match="same length"):
        cueing_metrics(t, f[:50], w, pose, DT)
    with pytest.raises(PerceptionInputError, match=r"shape \(N, 6\)"):
        cueing_metrics(t, f, w, pose[:, :3], DT)
    with pytest.raises(PerceptionInputError, match="non-finite"):
        cueing_metrics(t, f * np.nan, w, pose, DT)
    with pytest.raises(PerceptionInputError, match="dt"):
        cueing_metrics(t, f, w, pose, 0.0)
