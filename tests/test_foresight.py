"""The whole-flight plan (motionbase.washout.foresight): its models equal the scoring's, its
linearisation is first order, a step equals OSQP's solution of the same problem written
another way, and its plans keep the robot's limits and never score worse than their start."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spl

from motionbase.errors import ConfigError
from motionbase.physics import STANDARD_GRAVITY as G
from motionbase.platform.robot import load_geometry, robot_spec
from motionbase.report import robot_reach
from motionbase.washout import foresight
from motionbase.washout.mpc_params import limits_from_robot
from motionbase.washout.perception import (
    OTOLITH_K,
    canal_tf,
    otolith_tf,
    perceive,
    perceived_angular_velocity,
    perceived_specific_force,
    platform_specific_force,
)

DT = 1.0 / 30.0


@pytest.fixture(scope="module")
def ceart():
    """The ceart robot, its single-axis reach, and each axis's speed and acceleration limits."""
    name, geometry = load_geometry("ceart")
    robot = robot_spec(name).make(geometry)
    lim = limits_from_robot(robot, margin=1.0, rate_margin=1.0)
    rate = np.concatenate([lim["velocity_m_s"], np.radians(lim["angular_velocity_deg_s"])])
    acc = np.concatenate([lim["acceleration_m_s2"], np.radians(lim["angular_acceleration_deg_s2"])])
    return robot, robot_reach(robot), rate, acc


def level(n: int) -> np.ndarray:
    return np.tile([0.0, 0.0, -G], (n, 1))


def make_planner(ceart, f, w, start=None) -> foresight.ForesightPlanner:
    robot, reach, rate, acc = ceart
    start = np.zeros((len(f), 6)) if start is None else start
    return foresight.ForesightPlanner(f, w, DT, robot, reach, rate, acc, start)


def test_the_models_as_equations_are_the_scorings_filters() -> None:
    """Ta y = Mu u, solved, is what perceive (lfilter, started adapted) gives."""
    rng = np.random.default_rng(3)
    n = 400
    u = 2.0 + np.cumsum(rng.normal(size=n)) * 0.1  # not zero at the start
    num, den = otolith_tf()
    for model in ((np.asarray(num) / OTOLITH_K, den), canal_tf(6.1)):
        Ta, Mu = foresight.model_operator(*model, n, DT)
        y = spl.spsolve(Ta.tocsc(), Mu @ u)
        expected = perceive(*model, u, DT)
        assert np.allclose(y, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


def test_the_differences_are_the_scorings() -> None:
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.normal(size=50))
    D1, D2 = foresight.difference_operators(50, DT)
    assert np.allclose(D1 @ x, np.gradient(x, DT))
    pose = np.zeros((50, 6))
    pose[:, 1] = x
    # the scoring's specific force of a pure sway: its acceleration, gravity below
    assert np.allclose(D2 @ x, platform_specific_force(pose, DT)[:, 1])


def test_the_linearisation_is_first_order(ceart) -> None:
    """The cab's motion and the actuators, linearised about a tilted, turning motion: the
    error of the linear prediction falls with the square of the step."""
    n = 90
    t = np.arange(n) * DT
    pose = np.column_stack(
        [0.1 * np.sin(t), 0.05 * np.cos(2 * t), -0.03 * t / t[-1], 0.2 * np.sin(0.7 * t),
         0.15 + 0.1 * np.cos(t), 0.6 * np.sin(0.5 * t)]
    )  # fmt: skip
    planner_ = make_planner(ceart, level(n), np.zeros((n, 3)))
    K, r = planner_._linearise(pose)
    q0, J = planner_.robot.actuator_jacobian(pose)
    # smooth directions (random ones would be all acceleration): 1 cm and 0.02 rad
    phase = np.random.default_rng(6).uniform(0, 2 * np.pi, 6)
    direction = np.sin(1.3 * t[:, None] + phase) * [0.01, 0.01, 0.01, 0.02, 0.02, 0.02]
    D1, D2 = foresight.difference_operators(n, DT)
    errors = []
    for h in (1.0, 0.5):
        p = pose + h * direction
        x = {("pose", j): p[:, j] for j in range(6)}
        x |= {("rate", j): D1 @ p[:, j] for j in range(6)}
        x |= {("acc", j): D2 @ p[:, j] for j in range(6)}
        lin = np.column_stack([sum(c * x[b] for b, c in K[i].items()) + r[:, i] for i in range(6)])
        q_lin = q0 + np.einsum("nkj,nj->nk", J, p - pose)
        errors.append(
            (
                np.abs(lin - planner_.cab_motion(p)).max(),
                np.abs(q_lin - ceart[0].inverse(p)).max(),
            )
        )
    for before, after in zip(*errors, strict=True):
        assert after < 0.3 * before  # (a quarter, up to the third order)


def test_a_gentle_surge_is_rendered_almost_perfectly(ceart) -> None:
    """A surge acceleration the platform can make (0.5 m/s^2 at 2 rad/s, faded in and out:
    0.16 m of travel from rest to rest) is planned so that the pilot feels it: the error is
    under 2 % of a platform standing still's, and hardly a rotation is felt."""
    n = 600
    t = np.arange(n) * DT
    f = level(n)
    f[:, 0] = 0.5 * np.sin(2.0 * t) * np.sin(np.pi * t / (n * DT)) ** 2
    planner_ = make_planner(ceart, f, np.zeros((n, 3)))
    plan = planner_.plan(20.0, steps=4, trust=(0.2, 0.05))
    still = planner_.measured(np.zeros((n, 6)))
    assert still[0] > 0.3
    assert plan.rmse[0] < 0.02 * still[0]
    assert np.degrees(plan.rmse[3:]).sum() < 0.2
    assert np.allclose(plan.rmse, planner_.measured(plan.pose))


def test_a_step_that_leaves_the_workspace_is_kept_in_part(ceart, monkeypatch) -> None:
    """A convex step twice as long as a good one, so that it leaves the workspace: the
    plan keeps half of it, which is the good plan, instead of throwing it all away."""
    robot = ceart[0]
    n = 600
    t = np.arange(n) * DT
    f = level(n)
    f[:, 0] = 0.5 * np.sin(2.0 * t) * np.sin(np.pi * t / (n * DT)) ** 2
    planner_ = make_planner(ceart, f, np.zeros((n, 3)))
    good = planner_.plan(20.0, steps=4, trust=(0.2, 0.05)).pose
    start = planner_.start
    too_far = start + 2.0 * (good - start)
    assert not np.all(robot.reachable(too_far))  # (what the test is about)
    monkeypatch.setattr(planner_, "_step", lambda pose, weights, trust: too_far)
    plan = planner_.plan(20.0, steps=1)
    assert plan.kept == 1
    np.testing.assert_allclose(plan.pose, good, atol=1e-12)


def test_plans_keep_the_limits_and_the_start_and_never_lose(ceart) -> None:
    """A hard flight (a 4 g pull, a sustained sway force, a fast roll) from a washout-like
    start: every pose reachable, every axis's speed and acceleration within its limits, the
    start held, and the objective no worse than the start's."""
    robot, reach, rate, acc = ceart
    n = 450
    t = np.arange(n) * DT
    f = level(n)
    f[:, 2] -= 3.0 * G * np.exp(-(((t - 5.0) / 1.0) ** 2))
    f[:, 1] = 3.0 * (t > 3.0)
    w = np.zeros((n, 3))
    w[:, 0] = np.radians(60.0) * ((t > 8.0) & (t < 10.0))
    start = np.zeros((n, 6))
    start[:, 3] = np.radians(5.0) * np.clip(t - 3.0, 0.0, 1.0)  # a washout tilting into it
    planner_ = make_planner(ceart, f, w, start)
    plan = planner_.plan(20.0, steps=3)
    assert plan.kept >= 1
    assert np.all(robot.reachable(plan.pose))
    D1, D2 = foresight.difference_operators(n, DT)
    assert (np.abs(D1 @ plan.pose) <= rate * (1 + 1e-4) + 1e-6).all()
    assert (np.abs(D2 @ plan.pose) <= acc * (1 + 1e-4) + 1e-6).all()
    assert np.allclose(plan.pose[: foresight.HELD], start[: foresight.HELD], atol=1e-6)
    before = planner_.measured(start)
    assert plan.objective < before[:3].sum() + 20.0 * before[3:].sum()


def test_a_start_at_the_edge_of_the_reach_is_planned_from(ceart) -> None:
    """A washout that stood pitched up to 99.5 % of the reach, a crank at the end of its
    range (inside the planner's margin): the plan still starts there, and improves on it."""
    robot, reach, rate, acc = ceart
    n = 150
    start = np.zeros((n, 6))
    start[:, 4] = 0.995 * reach[1, 4]
    planner_ = make_planner(ceart, level(n), np.zeros((n, 3)), start)
    plan = planner_.plan(20.0, steps=3)
    assert plan.kept >= 1  # (level flight: standing pitched up is a false cue to undo)
    assert np.all(robot.reachable(plan.pose))
    before = planner_.measured(start)
    assert plan.objective < before[:3].sum() + 20.0 * before[3:].sum()
    assert plan.pose[-1, 4] < start[-1, 4]


def test_a_step_equals_osqps_solution_of_the_same_problem(ceart) -> None:
    """An independent solution of one convex step: the same linearised problem written over
    the poses alone, each model as the matrix of the scoring's own filter (perceive applied
    to unit inputs), dense, solved by OSQP; Clarabel's plan has OSQP's objective."""
    robot, reach, rate, acc = ceart
    n = 16
    t = np.arange(n) * DT
    f = level(n)
    f[:, 0] = 1.5 * np.sin(3.0 * t)
    f[:, 2] -= 2.0 * np.sin(2.0 * t)
    w = np.zeros((n, 3))
    w[:, 1] = 0.3 * np.sin(4.0 * t)
    planner_ = make_planner(ceart, f, w)
    pose0 = np.zeros((n, 6))
    weights = np.array([1.0, 2.0, 1.5, 300.0, 400.0, 500.0])
    trust = np.full(6, 0.05)
    planned = planner_._step(pose0, weights, trust)

    K, r = planner_._linearise(pose0)
    q0, J = planner_.robot.actuator_jacobian(pose0)
    D1, D2 = (D.toarray() for D in foresight.difference_operators(n, DT))
    felt = np.column_stack(
        [perceived_specific_force(f, DT, normalized=True), perceived_angular_velocity(w, DT)]
    )
    num, den = otolith_tf()
    models = [(np.asarray(num) / OTOLITH_K, den)] * 3 + [canal_tf(tau) for tau in (6.1, 5.3, 10.2)]
    # v = the poses, axis after axis; each kind of variable as a matrix of v
    pick = [np.kron(np.eye(6)[j], np.eye(n)) for j in range(6)]
    of = {("pose", j): pick[j] for j in range(6)}
    of |= {("rate", j): D1 @ pick[j] for j in range(6)}
    of |= {("acc", j): D2 @ pick[j] for j in range(6)}
    rows, rhs = [], []
    for i in range(6):  # sqrt(w / n) (L (M v + r) - felt)
        L = np.column_stack([perceive(*models[i], e, DT) for e in np.eye(n)])
        M = sum(np.diag(c) @ of[b] for b, c in K[i].items())
        rows.append(np.sqrt(weights[i] / n) * L @ M)
        rhs.append(np.sqrt(weights[i] / n) * (felt[:, i] - L @ r[:, i]))
    for j in range(6):
        rows.append(np.sqrt(foresight.SMOOTHING / n) * of[("acc", j)])
        rows.append(np.sqrt(foresight.REGULARISATION / n) * of[("pose", j)])
        rhs += [np.zeros(n), np.zeros(n)]
    A, b = np.vstack(rows), np.concatenate(rhs)

    def objective(v: np.ndarray) -> float:
        return float(np.sum((A @ v - b) ** 2))

    lo = np.repeat(np.maximum(reach[0], -trust), n)
    hi = np.repeat(np.minimum(reach[1], trust), n)
    held = (np.arange(6 * n) % n) < foresight.HELD
    lo[held] = hi[held] = 0.0
    G, h = [], []  # G v <= h
    for j in range(6):
        for D, limit in ((of[("rate", j)], rate[j]), (of[("acc", j)], acc[j])):
            G += [D, -D]
            h += [np.full(n, limit)] * 2
    span = robot.limits.upper - robot.limits.lower
    for k in range(robot.n):  # q0 + J v within the limits less the margin
        Jk = np.hstack([np.diag(J[:, k, j]) for j in range(6)])
        G += [Jk, -Jk]
        h += [
            robot.limits.upper[k] - foresight.ACTUATOR_MARGIN * span[k] - q0[:, k],
            q0[:, k] - robot.limits.lower[k] - foresight.ACTUATOR_MARGIN * span[k],
        ]
    G, h = np.vstack(G), np.concatenate(h)
    import osqp
    import scipy.sparse as sp

    solver = osqp.OSQP()
    solver.setup(
        sp.csc_matrix(np.triu(2.0 * A.T @ A)), -2.0 * A.T @ b,
        sp.csc_matrix(np.vstack([G, np.eye(6 * n)])),
        np.concatenate([np.full(len(h), -np.inf), lo]), np.concatenate([h, hi]),
        eps_abs=1e-10, eps_rel=1e-10, max_iter=200_000, polishing=True, verbose=False,
    )  # fmt: skip
    ref = solver.solve(raise_error=False)
    assert ref.info.status == "solved", ref.info.status
    ours = objective(planned.T.ravel())
    assert ours == pytest.approx(objective(ref.x), rel=1e-5)
    assert np.abs(planned.T.ravel() - ref.x).max() < 1e-3


def test_bad_input_is_refused(ceart) -> None:
    robot, reach, rate, acc = ceart
    n = 10
    f, w, start = level(n), np.zeros((n, 3)), np.zeros((n, 6))
    with pytest.raises(ConfigError, match="finite"):
        foresight.ForesightPlanner(f * np.nan, w, DT, robot, reach, rate, acc, start)
    with pytest.raises(ConfigError, match="reach"):
        foresight.ForesightPlanner(f, w, DT, robot, -reach, rate, acc, start)
    with pytest.raises(ConfigError, match="limits"):
        foresight.ForesightPlanner(f, w, DT, robot, reach, -rate, acc, start)
    with pytest.raises(ConfigError, match="start"):
        foresight.ForesightPlanner(f, w, DT, robot, reach, rate, acc, np.zeros((n, 3)))
    for dt in (0.0, -DT, np.inf, np.nan):  # (0 and inf were a ZeroDivisionError)
        with pytest.raises(ConfigError, match="dt must be > 0 s and finite"):
            foresight.ForesightPlanner(f, w, dt, robot, reach, rate, acc, start)
    jump = np.zeros((n, 6))
    jump[2:, 0] = 0.1  # 0.1 m in one sample (3 m/s) among the held poses: the plan was the
    with pytest.raises(ConfigError, match="speed or acceleration limit"):  # start, silently
        foresight.ForesightPlanner(f, w, DT, robot, reach, rate, acc, jump)
    far = np.zeros((n, 6))
    far[:, 0] = 5.0  # 5 m forward: not reachable
    with pytest.raises(ConfigError, match="reachable"):
        foresight.ForesightPlanner(f, w, DT, robot, reach, rate, acc, far)
    with pytest.raises(ConfigError, match="mu"):
        make_planner((robot, reach, rate, acc), f, w).plan(-1.0)
