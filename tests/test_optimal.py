"""The whole-flight optimum (motionbase.washout.optimal): its model equals the scoring's,
its plans keep the platform's limits, and on a small problem it equals a solution found by
scipy.optimize."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import scipy.signal

from motionbase.errors import ConfigError
from motionbase.physics import STANDARD_GRAVITY as G
from motionbase.washout import optimal
from motionbase.washout.perception import (
    CEART_REACH,
    OTOLITH_K,
    canal_tf,
    otolith_tf,
    perceive,
    perceived_angular_velocity,
    platform_specific_force,
)

DT = 1.0 / 30.0
# generous per-axis limits (m/s, rad/s; m/s^2, rad/s^2): inactive unless a test says
RATE = np.array([1.0, 1.0, 0.5, 1.5, 1.5, 3.0])
ACCEL = np.array([10.0, 10.0, 5.0, 15.0, 15.0, 30.0])


def level(n: int) -> np.ndarray:
    return np.tile([0.0, 0.0, -G], (n, 1))


def test_the_models_as_equations_are_the_scorings_filters() -> None:
    """Ta y = Mu u, solved, is what perceive (lfilter, started adapted) gives."""
    import scipy.sparse.linalg as spl

    rng = np.random.default_rng(3)
    n = 400
    u = 2.0 + np.cumsum(rng.normal(size=n)) * 0.1  # not zero at the start
    num, den = otolith_tf()
    for model in ((np.asarray(num) / OTOLITH_K, den), canal_tf(6.1)):
        Ta, Mu = optimal.model_operator(*model, n, DT)
        y = spl.spsolve(Ta.tocsc(), Mu @ u)
        expected = perceive(*model, u, DT)
        assert np.allclose(y, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


def test_the_differences_are_the_scorings() -> None:
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.normal(size=50))
    D1, D2 = optimal.difference_operators(50, DT)
    assert np.allclose(D1 @ x, np.gradient(x, DT))
    pose = np.zeros((50, 6))
    pose[:, 1] = x
    # the scoring's specific force of a pure sway: its acceleration, gravity below
    assert np.allclose(D2 @ x, platform_specific_force(pose, DT)[:, 1])


def test_a_gentle_surge_is_rendered_almost_perfectly() -> None:
    """A surge acceleration the platform can make (0.5 m/s^2 at 2 rad/s, faded in and out:
    0.16 m of travel from rest to rest) is planned so that the pilot feels it: the error is
    under 1 % of a platform standing still's."""
    n = 600
    t = np.arange(n) * DT
    f = level(n)
    f[:, 0] = 0.5 * np.sin(2.0 * t) * np.sin(np.pi * t / (n * DT)) ** 2
    w = np.zeros((n, 3))
    bound = optimal.MotionBound(f, w, DT, CEART_REACH, RATE, ACCEL)
    plan = bound.trade_off(20.0)
    still = bound.measured(np.zeros((n, 6)))
    measured = bound.measured(plan.pose)
    assert still[0] > 0.3
    assert measured[0] < 0.01 * still[0]
    assert np.degrees(measured[3:]).sum() < 0.2  # and hardly a rotation felt


def test_plans_keep_the_box_the_limits_and_the_start() -> None:
    """A hard flight (a 4 g pull, a sustained sway force, a fast roll): every pose inside
    the reach, every axis's speed and acceleration within its limits, the start held."""
    n = 450
    t = np.arange(n) * DT
    f = level(n)
    f[:, 2] -= 3.0 * G * np.exp(-(((t - 5.0) / 1.0) ** 2))
    f[:, 1] = 3.0 * (t > 3.0)
    w = np.zeros((n, 3))
    w[:, 0] = np.radians(60.0) * ((t > 8.0) & (t < 10.0))
    start = np.zeros((n, 6))
    start[:, 3] = 0.02  # a washout that stood rolled when the scoring started
    rate, accel = RATE / 2, ACCEL / 2
    bound = optimal.MotionBound(f, w, DT, CEART_REACH, rate, accel, start=start)
    plan = bound.trade_off(20.0, iterations=3)
    tol = 1e-6
    assert (plan.pose >= CEART_REACH[0] - tol).all() and (plan.pose <= CEART_REACH[1] + tol).all()
    D1, D2 = optimal.difference_operators(n, DT)
    assert (np.abs(D1 @ plan.pose) <= rate * (1 + 1e-5) + tol).all()
    assert (np.abs(D2 @ plan.pose) <= accel * (1 + 1e-5) + tol).all()
    assert np.allclose(plan.pose[: optimal.HELD], start[: optimal.HELD], atol=1e-6)


def test_reweighting_never_raises_the_objective() -> None:
    rng = np.random.default_rng(5)
    n = 300
    f = level(n) + scipy.signal.lfilter([0.05], [1, -0.95], rng.normal(size=(n, 3)), axis=0)
    w = scipy.signal.lfilter([0.005], [1, -0.95], rng.normal(size=(n, 3)), axis=0)
    bound = optimal.MotionBound(f, w, DT, CEART_REACH, RATE, ACCEL)
    first = bound.solve(np.array([1.0, 1.0, 1.0, 400.0, 400.0, 400.0]))
    best = bound.trade_off(20.0)

    def objective(rmse: np.ndarray) -> float:
        return rmse[:3].sum() + 20.0 * rmse[3:].sum()

    assert objective(best.rmse) <= objective(first.rmse) + 1e-9


def test_the_yaw_plan_equals_scipys_bounded_least_squares() -> None:
    """An independent solution: the yaw plan (the canal's error, the pulls toward smooth
    motion and neutral, the yaw box, the first samples held) as a dense bounded least-squares
    problem for scipy.optimize.lsq_linear, with limits loose enough not to act."""
    n = 240
    t = np.arange(n) * DT
    w = np.zeros((n, 3))
    w[:, 2] = np.radians(30.0) * np.sin(0.8 * t) * (t > 1.0)  # asks for more than +-49 deg
    f = level(n)
    reach = CEART_REACH.copy()
    bound = optimal.MotionBound(f, w, DT, reach, RATE * 10, ACCEL * 10, tol=1e-10)
    plan = bound.solve(np.ones(6))

    # the canal as a matrix: the scoring's filter applied to each unit input
    num, den = canal_tf(10.2)
    L = np.column_stack([perceive(num, den, np.eye(n)[:, k], DT) for k in range(n)])
    D1, D2 = (D.toarray() for D in optimal.difference_operators(n, DT))
    felt = perceived_angular_velocity(w, DT)[:, 2]
    A = np.vstack(
        [
            L @ D1,
            np.sqrt(optimal.SMOOTHING) * D2,
            np.sqrt(optimal.REGULARISATION) * np.eye(n),
        ]
    )
    b = np.concatenate([felt, np.zeros(2 * n)])
    lo = np.full(n, reach[0, 5])
    hi = np.full(n, reach[1, 5])
    lo[: optimal.HELD], hi[: optimal.HELD] = -1e-12, 1e-12  # held at neutral
    ref = scipy.optimize.lsq_linear(A, b, bounds=(lo, hi), tol=1e-12, max_iter=5000)
    assert ref.success
    assert np.abs(ref.x).max() > 0.9 * reach[1, 5]  # the box acts
    assert np.allclose(plan.pose[:, 5], ref.x, atol=2e-4)
    expected = np.sqrt(np.mean((L @ D1 @ ref.x - felt) ** 2))
    assert plan.rmse[5] == pytest.approx(expected, rel=1e-3)


def test_bad_input_is_refused() -> None:
    n = 10
    f, w = level(n), np.zeros((n, 3))
    with pytest.raises(ConfigError, match="finite"):
        optimal.MotionBound(f * np.nan, w, DT, CEART_REACH, RATE, ACCEL)
    with pytest.raises(ConfigError, match="reach"):
        optimal.MotionBound(f, w, DT, -CEART_REACH, RATE, ACCEL)
    with pytest.raises(ConfigError, match="limits"):
        optimal.MotionBound(f, w, DT, CEART_REACH, -RATE, ACCEL)
    with pytest.raises(ConfigError, match="start"):
        optimal.MotionBound(f, w, DT, CEART_REACH, RATE, ACCEL, start=np.zeros((n, 3)))
    bound = optimal.MotionBound(f, w, DT, CEART_REACH, RATE, ACCEL)
    with pytest.raises(ConfigError, match="weights"):
        bound.solve(np.zeros(6))
    with pytest.raises(ConfigError, match="mu"):
        bound.trade_off(-1.0)
