"""Cueing with foresight: the platform's whole trajectory planned for a flight known in
advance, a yardstick for cueing goals.

A cueing algorithm sees the flight as it happens; :class:`ForesightPlanner` sees all of it
and plans the platform's whole trajectory at once, scored as the tuner scores, inside the
robot's real limits. What it reaches a real-time cueing will hardly reach (it cannot know
what comes next), so a quality goal that even the plan misses is one to doubt
(``benchmarks/bench_foresight.py`` sets the classical washout and the MPC beside it). It
is a good plan, not the proven best: the problem is not convex, and it is solved locally
from a start motion.

The problem
-----------
The tuner's scoring (:func:`motionbase.washout.perception.cueing_metrics`): the
platform's specific force in cab axes ``R^T (p'' - (0, 0, g))``, ``p''`` by central
second differences, and its body rates from the Euler angles by :func:`numpy.gradient`,
each through the otolith or canal model (adapted to the first sample), minus the
aircraft's; the tuner's error terms ``sum(rmse_force) + mu sum(rmse_angular)``::

    minimise    sum(rmse_force) + mu sum(rmse_angular)   (+ tiny pulls, below)
    over        the poses at every sample (m, rad)
    subject to  every actuator within its limits (the robot's inverse kinematics), each
                pose axis within the single-axis reach and its speed and acceleration
                within the axis's limits; the first samples those of a start motion.

Sequential convex programming: each step linearises the cab's motion (the rotation) and
the inverse kinematics about the current plan, weights each axis's mean square error by
``1 / rmse`` (or ``mu / rmse``) of the current plan (which bounds the sum of RMS errors
from above and touches it there), and solves that quadratic programme within a trust
region around the plan. A step is kept when the measured objective falls and every pose
is reachable (the region then widens); else half of it, or a quarter, is tried (a
backtracking line search: the linearised actuators hold better nearer the plan, and the
speed, acceleration and box limits, being linear, hold anywhere between the two); when
none is kept the region is halved. The matrices are banded and sparse: each model's
difference equation (its bilinear design, as ``perceive`` filters) and each difference
operator are equality constraints, every coefficient near 1. Clarabel (an interior-point
solver) solves them: the cost is nearly flat along slow drifts of the pose, where OSQP's
first-order iterations did not converge.

The start: the models take a motion's first sample as what came before it, forever; left
free, a plan starts with a jolt of 100 m/s^2 that sets the otolith's history to its
advantage. The first :data:`HELD` samples are therefore those of a start motion (the
washout it is compared with, so that the plan starts where that washout stood, and is
never worse than it).

What it leaves out: causality (every future sample is known), and the coupling of the
actuators' speeds and accelerations between axes (each pose axis may use the actuators'
limits alone, at neutral; the pipeline's limiter holds the real ones when a plan is
flown, and counts what it cut).
"""

from __future__ import annotations

from dataclasses import dataclass
from numbers import Real
from typing import Any

import numpy as np
import scipy.sparse as sp

from motionbase.errors import ConfigError, MotionbaseError
from motionbase.physics import STANDARD_GRAVITY, body_rates_from_euler_rates, rotation_matrix
from motionbase.washout.filters import tustin_tf
from motionbase.washout.perception import (
    CANAL_TAU_L,
    OTOLITH_K,
    canal_tf,
    cueing_metrics,
    otolith_tf,
    perceived_angular_velocity,
    perceived_specific_force,
    platform_angular_velocity,
    platform_specific_force,
)

__all__ = ["ForesightPlanner", "ForesightPlan", "difference_operators", "model_operator"]

#: Weights of a pull toward the neutral pose (per m^2 or rad^2 of mean square pose) and
#: toward smooth motion (per (m/s^2)^2 or (rad/s^2)^2 of mean square acceleration). Without
#: them the problem has no unique solution: a constant velocity added changes no
#: acceleration, a pose that alternates every sample has no central-difference rate, and
#: the discrete otolith model (a zero at the Nyquist frequency) is blind to accelerations
#: that alternate every sample, which the solver then fills with noise at the limits.
REGULARISATION = 1e-6
SMOOTHING = 1e-3
#: Samples at the start held to the start motion's (a second difference spans three).
HELD = 3
#: Smallest RMS error a reweighting divides by: force (m/s^2), rates (rad/s).
RMSE_FLOOR = np.array([1e-3, 1e-3, 1e-3, 1e-4, 1e-4, 1e-4])
#: Shares of a convex step tried in turn, until one lowers the measured objective with
#: every pose reachable (a step that leaves the workspace somewhere often does not in part).
BACKTRACK = (1.0, 0.5, 0.25)
#: Share of each actuator's range kept free at both ends (the linearisation's margin), except
#: where the start motion itself went into it.
ACTUATOR_MARGIN = 0.02


def difference_operators(n: int, dt: float) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """The finite differences of the perception metrics as sparse matrices, (n, n) each.

    Returns
    -------
    D1 : sparse matrix
        :func:`numpy.gradient` (central inside, one-sided at the ends), 1/s.
    D2 : sparse matrix
        Central second differences, the first and last rows copying their neighbours'
        (:func:`motionbase.washout.perception.platform_specific_force`), 1/s^2.
    """
    if n < 3:
        raise ConfigError(f"foresight plan: {n} samples; give at least 3")
    inner = np.arange(1, n - 1)
    rows = np.concatenate([[0, 0], np.repeat(inner, 2), [n - 1, n - 1]])
    cols = np.concatenate([[0, 1], np.column_stack([inner - 1, inner + 1]).ravel(), [n - 2, n - 1]])
    vals = np.concatenate([[-1.0, 1.0], np.tile([-0.5, 0.5], n - 2), [-1.0, 1.0]]) / dt
    D1 = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    stencil = sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n - 2, n)).tocsr() / (dt * dt)
    D2 = sp.vstack([stencil[:1], stencil, stencil[-1:]]).tocsr()
    return D1, D2


def model_operator(
    num: np.ndarray, den: np.ndarray, n: int, dt: float
) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """A perception model as banded equations ``Ta y = Mu u``, both (n, n) and sparse.

    ``y`` solves them exactly when it is ``perceive(num, den, u, dt)``
    (:func:`motionbase.washout.perception.perceive`: the bilinear design, started
    adapted to ``u[0]``, as if the input had been ``u[0]`` forever and the output its DC
    response).
    """
    b, a = tustin_tf(np.asarray(num, float), np.asarray(den, float), dt)
    order = len(a) - 1
    b = np.concatenate([b, np.zeros(order + 1 - len(b))])  # (as lfilter pads it)
    offsets = [-j for j in range(order + 1)]
    Ta = sp.diags([a[j] * np.ones(n - j) for j in range(order + 1)], offsets)
    Tb = sp.diags([b[j] * np.ones(n - j) for j in range(order + 1)], offsets)
    dc = b.sum() / a.sum()
    # the rows that reach before the first sample: those terms are u[0] and dc u[0]
    first = np.array([b[k + 1 :].sum() - dc * a[k + 1 :].sum() for k in range(min(order, n))])
    start = sp.csr_matrix((first, (np.arange(first.size), np.zeros(first.size, int))), (n, n))
    return Ta.tocsr(), (Tb + start).tocsr()


@dataclass(frozen=True)
class ForesightPlan:
    """A plan of :class:`ForesightPlanner`.

    Attributes
    ----------
    pose : ndarray, shape (N, 6)
        The platform's poses ``[x, y, z, roll, pitch, yaw]``, m and rad, base axes FRD.
    rmse : ndarray, shape (6,)
        Its perceived RMS errors as the tuner measures them: specific force x, y, z
        (m/s^2), angular velocity roll, pitch, yaw (rad/s).
    mu : float
        The weight of the angular errors, (m/s^2) per (rad/s).
    steps : int
        Convex programmes solved; ``kept`` of them improved the plan.
    kept : int
    """

    pose: np.ndarray
    rmse: np.ndarray
    mu: float
    steps: int
    kept: int

    @property
    def objective(self) -> float:
        """``sum(rmse_force) + mu * sum(rmse_angular)``."""
        return _objective(self.rmse, self.mu)


class ForesightPlanner:
    """A platform motion planned for one flight known in advance (a local optimum).

    Parameters
    ----------
    f : ndarray, shape (N, 3)
        The aircraft's specific force at the pilot, m/s^2, body axes FRD.
    w : ndarray, shape (N, 3)
        Its body rates, rad/s.
    dt : float
        Sample period, s (> 0, finite).
    robot : Robot
        A 6-DOF robot plug-in (:mod:`motionbase.platform.robot`): its ``inverse``,
        ``reachable`` and actuator ``limits``.
    reach : ndarray, shape (2, 6)
        Lower (< 0) and upper (> 0) bound of each pose axis, m and rad
        (:func:`motionbase.report.robot_reach`).
    rate_limit, accel_limit : ndarray, shape (6,)
        Largest speed (m/s, rad/s) and acceleration (m/s^2, rad/s^2) of each pose axis
        (:func:`motionbase.washout.mpc_params.limits_from_robot`: the actuators' limits
        through the inverse kinematics at neutral).
    start : ndarray, shape (N, 6)
        The motion a plan starts from and keeps the first :data:`HELD` poses of
        (reachable, those within the speed and acceleration limits: a washout's realised
        poses).
    g : float
        Gravity, m/s^2.
    tol : float
        Clarabel's tolerances (duality gap, feasibility).
    """

    def __init__(
        self,
        f: np.ndarray,
        w: np.ndarray,
        dt: float,
        robot: Any,
        reach: np.ndarray,
        rate_limit: np.ndarray,
        accel_limit: np.ndarray,
        start: np.ndarray,
        *,
        g: float = STANDARD_GRAVITY,
        tol: float = 1e-7,
    ) -> None:
        import clarabel

        f = np.asarray(f, dtype=float)
        w = np.asarray(w, dtype=float)
        n = f.shape[0]
        if f.shape != (n, 3) or w.shape != (n, 3):
            raise ConfigError(f"foresight plan: f and w must be (N, 3), got {f.shape}, {w.shape}")
        if not (np.isfinite(f).all() and np.isfinite(w).all()):
            raise ConfigError("foresight plan: f and w must be finite")
        if not (isinstance(dt, Real) and 0 < dt < np.inf):
            raise ConfigError(f"foresight plan: dt must be > 0 s and finite, got {dt!r}")
        self.reach = np.asarray(reach, dtype=float)
        if (
            self.reach.shape != (2, 6)
            or not (self.reach[0] < 0).all()
            or not (self.reach[1] > 0).all()
        ):
            raise ConfigError("foresight plan: reach must be (2, 6), lower < 0 < upper")
        self.rate_limit = np.asarray(rate_limit, dtype=float).reshape(6)
        self.accel_limit = np.asarray(accel_limit, dtype=float).reshape(6)
        if not ((self.rate_limit > 0).all() and (self.accel_limit > 0).all()):
            raise ConfigError("foresight plan: rate and acceleration limits must be > 0")
        self.start = np.asarray(start, dtype=float)
        if self.start.shape != (n, 6) or not np.all(robot.reachable(self.start)):
            raise ConfigError(f"foresight plan: start must be ({n}, 6) reachable poses")
        self.robot = robot
        self.n, self.dt, self.g = n, float(dt), float(g)
        self.f, self.w = f, w
        self._D1, self._D2 = difference_operators(n, dt)
        # the speeds and accelerations of the first rows come from the held poses alone: past
        # a limit there, every convex step is infeasible, and the plan was the start, silently
        early = slice(0, HELD - 1)
        if (np.abs(self._D1 @ self.start)[early] > self.rate_limit * (1 + 1e-6)).any() or (
            np.abs(self._D2 @ self.start)[early] > self.accel_limit * (1 + 1e-6)
        ).any():
            raise ConfigError(
                f"foresight plan: the start's first {HELD} poses, which every plan keeps, "
                "pass a pose axis's speed or acceleration limit; no plan can keep them"
            )
        num, den = otolith_tf()
        otolith = model_operator(np.asarray(num) / OTOLITH_K, den, n, dt)
        self._models = [otolith] * 3 + [model_operator(*canal_tf(t), n, dt) for t in CANAL_TAU_L]
        # what the aircraft's pilot feels, by the scoring's own functions
        felt_f = perceived_specific_force(f, dt, normalized=True, g=g)
        self._felt = np.column_stack([felt_f, perceived_angular_velocity(w, dt)])
        lim = robot.limits
        span = np.asarray(lim.upper) - np.asarray(lim.lower)
        # the actuators' bounds at each sample: the limits less the margin, widened to the
        # start's own positions where it went into the margin (it must stay feasible)
        q_start = np.asarray(robot.inverse(self.start), dtype=float)
        self._q_lo = np.minimum(np.asarray(lim.lower) + ACTUATOR_MARGIN * span, q_start)
        self._q_hi = np.maximum(np.asarray(lim.upper) - ACTUATOR_MARGIN * span, q_start)
        self._settings = clarabel.DefaultSettings()
        self._settings.verbose = False
        for key in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
            setattr(self._settings, key, tol)
        self._settings.max_iter = 500

    # -- the models --------------------------------------------------------------------
    def cab_motion(self, pose: np.ndarray) -> np.ndarray:
        """What the platform does in cab axes, (N, 6): specific force minus level flight's
        (m/s^2) and body rates (rad/s), by the scoring's own functions."""
        force = platform_specific_force(pose, self.dt, self.g) + np.array([0.0, 0.0, self.g])
        return np.column_stack([force, platform_angular_velocity(pose, self.dt)])

    def measured(self, pose: np.ndarray) -> np.ndarray:
        """The perceived RMS errors of ``pose`` as the tuner measures them, (6,): force
        x, y, z (m/s^2), rates roll, pitch, yaw (rad/s)."""
        t = np.arange(self.n) * self.dt
        m = cueing_metrics(t, self.f, self.w, pose, self.dt, reach=self.reach, g=self.g)
        return np.concatenate([m.rmse_specific_force, m.rmse_angular_velocity])

    def _linearise(self, pose: np.ndarray) -> tuple[list[dict[tuple[str, int], Any]], np.ndarray]:
        """``cab_motion(p) ~ sum K x + r`` about ``pose``: ``K[i]`` maps ``(kind, j)`` (the
        pose, rate or acceleration of axis ``j``) to per-sample coefficients (N,);
        ``r`` (N, 6). The rotation's derivatives by central differences."""
        n, h = self.n, 1e-6
        ang = pose[:, 3:]
        acc = self._D2 @ pose[:, :3] - np.array([0.0, 0.0, self.g])
        rates = self._D1 @ ang
        Rt = np.swapaxes(rotation_matrix(ang), 1, 2)  # cab <- base
        K: list[dict[tuple[str, int], Any]] = [{} for _ in range(6)]
        for j in range(3):
            step = np.zeros(3)
            step[j] = h
            dRt = np.swapaxes(rotation_matrix(ang + step) - rotation_matrix(ang - step), 1, 2)
            dF = np.einsum("nij,nj->ni", dRt, acc) / (2 * h)  # d force / d angle j
            unit = np.zeros((n, 3))
            unit[:, j] = 1.0
            E = _body_rates(ang, unit)  # d rates / d Euler rate j
            dW = (_body_rates(ang + step, rates) - _body_rates(ang - step, rates)) / (2 * h)
            for i in range(3):
                K[i][("acc", j)] = Rt[:, i, j]
                K[i][("pose", 3 + j)] = dF[:, i]
                K[3 + i][("rate", 3 + j)] = E[:, i]
                if j < 2:  # (the rates do not depend on yaw)
                    K[3 + i][("pose", 3 + j)] = dW[:, i]
        x = {("pose", j): pose[:, j] for j in range(6)}
        x |= {("rate", j): self._D1 @ pose[:, j] for j in range(6)}
        x |= {("acc", j): self._D2 @ pose[:, j] for j in range(6)}
        base = self.cab_motion(pose)
        r = np.column_stack([base[:, i] - sum(c * x[b] for b, c in K[i].items()) for i in range(6)])
        return K, r

    # -- one convex programme ------------------------------------------------------------
    def _step(self, pose: np.ndarray, weights: np.ndarray, trust: np.ndarray) -> np.ndarray:
        """Minimise ``sum_i weights_i mean(e_i^2)`` with the models linearised about
        ``pose``, each pose axis within ``trust`` (6,) of it: the new poses (N, 6).

        Variables: each axis's poses, rates and accelerations (tied by the difference
        equations times dt and dt^2, so that every coefficient is about 1: the limits are
        bounds and the cost diagonal, which the solver needs to converge), and the six
        errors.
        """
        import clarabel

        n, dt = self.n, self.dt
        K, r = self._linearise(pose)
        q0, J = self.robot.actuator_jacobian(pose)
        blocks = [(kind, j) for j in range(6) for kind in ("pose", "rate", "acc")]
        blocks += [("error", i) for i in range(6)]
        at = {b: k for k, b in enumerate(blocks)}

        def row(pieces: dict[tuple[str, int], sp.spmatrix]) -> sp.csr_matrix:
            height = next(iter(pieces.values())).shape[0]
            empty = sp.csr_matrix((height, n))
            return sp.hstack([pieces.get(b, empty) for b in blocks], format="csr")

        eye = sp.identity(n, format="csr")
        rows, rhs = [], []
        for j in range(6):  # dt v = dt D1 p, dt^2 a = dt^2 D2 p
            rows.append(row({("rate", j): dt * eye, ("pose", j): -dt * self._D1}))
            rows.append(row({("acc", j): dt * dt * eye, ("pose", j): -dt * dt * self._D2}))
            rhs += [np.zeros(n), np.zeros(n)]
        for i in range(6):  # Ta (e_i + felt_i) = Mu (sum K x + r_i)
            Ta, Mu = self._models[i]
            pieces = {("error", i): Ta} | {b: -(Mu @ sp.diags(c)) for b, c in K[i].items()}
            rows.append(row(pieces))
            rhs.append(Mu @ r[:, i] - Ta @ self._felt[:, i])
        held = sp.csr_matrix((np.ones(HELD), (np.arange(HELD), np.arange(HELD))), (HELD, n))
        for j in range(6):
            rows.append(row({("pose", j): held}))
            rhs.append(self.start[:HELD, j])
        equations = sum(len(v) for v in rhs)
        for j in range(6):  # box and trust region, speed, acceleration: x + s = hi, -x + s = -lo
            for kind, lo, hi in (
                ("pose", np.maximum(self.reach[0, j], pose[:, j] - trust[j]),
                 np.minimum(self.reach[1, j], pose[:, j] + trust[j])),
                ("rate", np.full(n, -self.rate_limit[j]), np.full(n, self.rate_limit[j])),
                ("acc", np.full(n, -self.accel_limit[j]), np.full(n, self.accel_limit[j])),
            ):  # fmt: skip
                rows += [row({(kind, j): eye}), row({(kind, j): -eye})]
                rhs += [hi, -lo]
        for k in range(q0.shape[1]):  # actuator k: q0 + J (p - pose) within its limits
            lin = {("pose", j): sp.diags(J[:, k, j]) for j in range(6)}
            offset = q0[:, k] - np.einsum("nj,nj->n", J[:, k, :], pose)
            rows += [row(lin), row({b: -m for b, m in lin.items()})]
            rhs += [self._q_hi[:, k] - offset, offset - self._q_lo[:, k]]
        A = sp.vstack(rows, format="csc")
        b = np.concatenate(rhs)
        cones = [clarabel.ZeroConeT(equations), clarabel.NonnegativeConeT(len(b) - equations)]
        weight = {"acc": SMOOTHING, "pose": REGULARISATION}
        diag = np.concatenate(
            [
                np.full(n, weights[k] if kind == "error" else weight.get(kind, 0.0))
                for kind, k in blocks
            ]
        )
        P = sp.diags(diag * (2.0 / n), format="csc")  # (the means: 1/n; the half: 2)
        sol = clarabel.DefaultSolver(P, np.zeros(P.shape[0]), A, b, cones, self._settings).solve()
        x = np.asarray(sol.x)
        if str(sol.status) not in ("Solved", "AlmostSolved") or not np.isfinite(x).all():
            raise MotionbaseError(f"foresight plan: the solver stopped: {sol.status}")
        new = np.column_stack(
            [x[at[("pose", j)] * n : (at[("pose", j)] + 1) * n] for j in range(6)]
        )
        return np.clip(new, self.reach[0], self.reach[1])

    # -- the search ----------------------------------------------------------------------
    def plan(
        self,
        mu: float,
        *,
        steps: int = 8,
        trust: tuple[float, float] = (0.05, 0.05),
    ) -> ForesightPlan:
        """The plan that minimises ``sum(rmse_force) + mu * sum(rmse_angular)`` (measured),
        from the start motion (see the module notes).

        Parameters
        ----------
        mu : float
            (m/s^2) per (rad/s), > 0; the tuner weighs the angular errors with
            :data:`motionbase.tuning.WEIGHT_ANGULAR`, 20.
        steps : int
            Convex programmes at most.
        trust : (float, float)
            First half-width of the trust region: translations (m), rotations (rad). A
            step kept whole widens it by half (up to four times this), a step kept in part
            (:data:`BACKTRACK`) leaves it, a step not kept halves it.
        """
        if not (np.isfinite(mu) and mu > 0):
            raise ConfigError(f"foresight plan: mu must be > 0, got {mu!r}")
        scale = np.array([1.0, 1.0, 1.0, mu, mu, mu])
        region = np.repeat(np.asarray(trust, dtype=float), 3)
        cap = 4 * region  # (a kept step widens the region by half, up to this)
        pose = self.start.copy()
        rmse = self.measured(pose)
        done = kept = 0
        while done < steps and region.max() > 1e-4:
            # (an error near zero would weigh its axis without bound and stall the solver)
            weights = scale / np.maximum(rmse, RMSE_FLOOR)
            done += 1
            try:
                candidate = self._step(pose, weights, region)
            except MotionbaseError:
                region = region / 2
                continue
            for share in BACKTRACK:
                trial = candidate if share == 1.0 else pose + share * (candidate - pose)
                new = self.measured(trial)
                if _objective(new, mu) < _objective(rmse, mu) and np.all(
                    self.robot.reachable(trial)
                ):
                    pose, rmse, kept = trial, new, kept + 1
                    if share == 1.0:
                        region = np.minimum(region * 1.5, cap)
                    break
            else:
                region = region / 2
        return ForesightPlan(pose, rmse, float(mu), done, kept)


def _body_rates(ang: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Body rates (N, 3) of Euler angles ``ang`` turning at Euler rates ``rates`` (N, 3)."""
    p, q, r = body_rates_from_euler_rates(
        ang[:, 0], ang[:, 1], rates[:, 0], rates[:, 1], rates[:, 2]
    )
    return np.column_stack([p, q, r])


def _objective(rmse: np.ndarray, mu: float) -> float:
    return float(np.sum(rmse[:3]) + mu * np.sum(rmse[3:]))
