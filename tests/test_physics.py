"""The shared maths of motionbase.physics against independent computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motionbase import physics
from motionbase.physics import (
    body_rates_from_euler_rates,
    brake_speed,
    euler_zyx_from_quaternion,
    quaternion_from_euler_zyx,
    rotation_matrix,
    smoothstep,
    track_toward,
)

angle = st.floats(-math.pi, math.pi)
pitch = st.floats(-1.5, 1.5)


def _axis(k: int, a: float) -> np.ndarray:
    """Rotation by ``a`` about base axis ``k`` (0 x, 1 y, 2 z), written out by hand."""
    c, s = math.cos(a), math.sin(a)
    m = np.eye(3)
    i, j = [(1, 2), (0, 2), (0, 1)][k]
    m[i, i] = m[j, j] = c
    m[i, j], m[j, i] = (-s, s) if k != 1 else (s, -s)
    return m


@given(angle, pitch, angle)
def test_rotation_matrix_is_rz_ry_rx(roll: float, pitch_: float, yaw: float) -> None:
    expected = _axis(2, yaw) @ _axis(1, pitch_) @ _axis(0, roll)
    np.testing.assert_allclose(rotation_matrix([roll, pitch_, yaw]), expected, atol=1e-12)


def test_a_nose_up_pitch_raises_the_nose_in_frd() -> None:
    """FRD: pitch up turns the body's forward axis toward -z (up)."""
    nose = rotation_matrix([0.0, 0.3, 0.0]) @ np.array([1.0, 0.0, 0.0])
    assert nose[2] < 0 and nose[0] > 0


def _matrix_of_quaternion(x: float, y: float, z: float, w: float) -> np.ndarray:
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@given(angle, pitch, angle)
def test_quaternions_match_the_rotation_and_invert(roll: float, pitch_: float, yaw: float) -> None:
    q = quaternion_from_euler_zyx(roll, pitch_, yaw)
    assert math.isclose(math.hypot(*q), 1.0, rel_tol=1e-12)
    np.testing.assert_allclose(
        _matrix_of_quaternion(*q), rotation_matrix([roll, pitch_, yaw]), atol=1e-12
    )
    back = euler_zyx_from_quaternion(*q)
    np.testing.assert_allclose(
        rotation_matrix(back), rotation_matrix([roll, pitch_, yaw]), atol=1e-9
    )
    np.testing.assert_allclose(back[1], pitch_, atol=1e-9)
    # a scaled quaternion is the same rotation (normalised first)
    np.testing.assert_allclose(euler_zyx_from_quaternion(*(1.05 * np.array(q))), back, atol=1e-12)


@given(angle, pitch, angle, st.tuples(*[st.floats(-3.0, 3.0)] * 3))
def test_body_rates_are_those_of_the_rotating_frame(
    roll: float, pitch_: float, yaw: float, rates: tuple[float, float, float]
) -> None:
    """skew(p, q, r) = R^T dR/dt, by central differences of the Euler angles."""
    h = 1e-6
    a = np.array([roll, pitch_, yaw])
    d = np.array(rates)
    dR = (rotation_matrix(a + h * d) - rotation_matrix(a - h * d)) / (2 * h)
    omega = rotation_matrix(a).T @ dR
    expected = (omega[2, 1], omega[0, 2], omega[1, 0])
    got = body_rates_from_euler_rates(roll, pitch_, *rates)
    np.testing.assert_allclose(got, expected, atol=1e-6)
    arrays = body_rates_from_euler_rates(*(np.full(4, v) for v in (roll, pitch_, *rates)))
    np.testing.assert_allclose(np.array(arrays)[:, 0], got, rtol=0, atol=1e-15)


@settings(deadline=None)  # the first call compiles
@given(st.floats(1e-6, 2.0), st.floats(0.01, 50.0), st.sampled_from([1 / 60, 1 / 120, 1e-3]))
def test_brake_speed_is_the_speed_that_stops_in_the_distance(
    dist: float, accel: float, dt: float
) -> None:
    """From the returned speed, braking by u = a dt per tick covers exactly ``dist``."""
    u = accel * dt
    v = brake_speed(dist, u, dt)
    assert v > 0
    covered, speed = 0.0, v
    while speed > 0.0:
        covered += speed * dt
        speed -= u
    assert covered == pytest.approx(dist, rel=1e-9, abs=1e-15)
    assert brake_speed(-dist, u, dt) == 0.0 and brake_speed(0.0, u, dt) == 0.0


@settings(deadline=None)
@given(
    st.lists(st.floats(-3.0, 3.0), min_size=2, max_size=60),
    st.sampled_from([(1.0, 0.5, 4.0), (np.inf, 0.5, 4.0), (1.0, np.inf, 4.0), (1.0, 0.5, np.inf)]),
    st.sampled_from([0.0, 1.0]),
)
def test_track_toward_keeps_every_limit_it_is_given(targets, limits, glide) -> None:
    """Speed, acceleration and position limits hold, measured from the positions; an infinite
    limit (no position bound, no speed or acceleration limit) never gives a NaN; a target
    held long enough is reached exactly."""
    bound, vmax, amax = limits
    dt = 0.01
    u = amax * dt
    k = glide * amax / vmax if np.isfinite(amax) and np.isfinite(vmax) else 0.0
    clipped = [min(max(x, -bound), bound) for x in targets]
    q, v, prev = 0.0, 0.0, 0.0
    path = [0.0]
    for x in clipped + [clipped[-1]] * 2000:  # then held until it settles
        new, limited = track_toward(q, v, prev, x, dt, -bound, bound, vmax, u, k)
        assert math.isfinite(new) and -bound <= new <= bound
        assert limited or new == x  # not limited: on the target
        v, q, prev = (new - q) / dt, new, x
        path.append(q)
    speeds = np.diff(path) / dt
    assert np.abs(speeds).max() <= vmax * (1 + 1e-12)
    assert np.abs(np.diff(np.r_[0.0, speeds])).max() <= amax * dt * (1 + 1e-9) + 1e-9
    assert q == clipped[-1]


def test_smoothstep_is_a_c1_ramp_in_python_and_compiled_code() -> None:
    import numba

    @numba.njit
    def ramp(xs):
        return np.array([smoothstep(x) for x in xs])

    xs = np.linspace(-0.5, 1.5, 2001)
    ys = ramp(xs)
    np.testing.assert_array_equal(ys, [smoothstep(x) for x in xs])
    np.testing.assert_allclose(
        ys, np.clip(3 * np.clip(xs, 0, 1) ** 2 - 2 * np.clip(xs, 0, 1) ** 3, 0, 1)
    )
    assert smoothstep(0.5) == 0.5 and smoothstep(-1.0) == 0.0 and smoothstep(2.0) == 1.0


def test_one_gravity_and_one_set_of_bounds() -> None:
    """Every user takes them from here: the pipeline's defaults, the washout, the sources."""
    from motionbase.safety import InputLimits
    from motionbase.washout import WashoutParams

    assert physics.STANDARD_GRAVITY == 9.80665  # the standard's value (CGPM 1901)
    lim = InputLimits()
    assert (lim.max_specific_force, lim.max_angular_velocity, lim.max_attitude) == (
        physics.MAX_SPECIFIC_FORCE,
        physics.MAX_ANGULAR_VELOCITY,
        physics.MAX_ATTITUDE,
    )
    assert WashoutParams.preset("default").g == physics.STANDARD_GRAVITY  # no g in the file
