"""The best motion a platform could make for a flight known in advance: a yardstick for
cueing.

A cueing algorithm sees the flight as it happens; :class:`MotionBound` sees all of it and
plans the platform's whole trajectory at once, with the model the MPC plans with
(:mod:`motionbase.washout.mpc`) and the scoring the tuner scores with. Where it cannot
reach a quality goal, no cueing on that platform will (up to the assumptions below), so
it tells a goal the platform can meet from one it cannot (``benchmarks/bench_bound.py``
sets the classical washout and the MPC against it).

The problem
-----------
The tuner's scoring (:func:`motionbase.washout.perception.cueing_metrics`): the
platform's specific force in cab axes ``R^T (p'' - (0, 0, g))``, ``p''`` by central
second differences, and its body rates from the Euler angles by :func:`numpy.gradient`,
each through the otolith or canal model (adapted to the first sample), minus the
aircraft's. For weights ``c_i`` on the six axes' errors (x, y, z force; roll, pitch,
yaw rate)::

    minimise    sum_i c_i mean(e_i^2)   (+ tiny pulls toward neutral and smooth motion)
    over        the poses at every sample (m, rad)
    subject to  each pose axis inside the single-axis reach, its speed and acceleration
                inside the axis's limits; the first samples those of a start motion.

Roll and pitch are linearised (small angles, as in the MPC's model); the errors are then
linear in the poses and the problem splits in three quadratic programmes:

1. *yaw*: the yaw rate alone (``r = psi'``);
2. *heave*: ``f_z = z''``;
3. *horizontal*, with the yaw of step 1 kept exactly (it turns the translational
   accelerations into the cab, and yaw angles of 40 deg are the rule in a rudder kick)::

       f_x = cos(psi) x'' + sin(psi) y'' + g theta,   p = phi' - psi' theta,
       f_y = -sin(psi) x'' + cos(psi) y'' - g phi,    q = theta' + psi' phi.

Each model's difference equation (its bilinear design,
:func:`~motionbase.washout.filters.tustin_tf`, as ``perceive`` filters) is an equality
constraint, so the matrices are banded and sparse. Clarabel (an interior-point solver)
solves them: the cost is nearly flat along slow drifts of the pose, where OSQP's
first-order iterations did not converge. :meth:`MotionBound.trade_off` minimises the
tuner's *sum* of per-axis RMS errors, plus ``mu`` times the angular ones, by reweighting.

What it leaves out
------------------
- roll and pitch linearised: :meth:`MotionBound.measured` scores the plan with the
  tuner's own (nonlinear) metrics, which is the figure to quote; the two differ most in
  heave, where a tilt of 20 deg lightens the cab by 0.6 m/s^2;
- the workspace beyond a box: any combination of poses inside the single-axis reach is
  allowed, and each axis may use the actuators' whole speed and acceleration alone;
- causality: every future sample is known.

The start: the models take a motion's first sample as what came before it, forever; left
free, the plan starts with a jolt of 100 m/s^2 that sets the otolith's history to its
advantage. The first :data:`HELD` samples are therefore those of a start motion (the
washout it is compared with: the plan starts where that washout stood), the neutral pose
at rest by default.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from motionbase.errors import ConfigError, MotionbaseError
from motionbase.physics import STANDARD_GRAVITY
from motionbase.washout.filters import tustin_tf
from motionbase.washout.perception import (
    CANAL_TAU_L,
    OTOLITH_K,
    canal_tf,
    cueing_metrics,
    otolith_tf,
    perceived_angular_velocity,
    perceived_specific_force,
)

__all__ = ["MotionBound", "OptimalMotion", "difference_operators", "model_operator"]

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
        raise ConfigError(f"motion bound: {n} samples; give at least 3")
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
class OptimalMotion:
    """A plan of :class:`MotionBound`.

    Attributes
    ----------
    pose : ndarray, shape (N, 6)
        The platform's poses ``[x, y, z, roll, pitch, yaw]``, m and rad, base axes FRD.
    rmse : ndarray, shape (6,)
        Its perceived RMS errors as the plan's (linearised) model predicts them: specific
        force x, y, z (m/s^2), angular velocity roll, pitch, yaw (rad/s).
    weights : ndarray, shape (6,)
        The weights ``c`` it was solved for.
    """

    pose: np.ndarray
    rmse: np.ndarray
    weights: np.ndarray


class MotionBound:
    """The best platform motion for one flight known in advance.

    Parameters
    ----------
    f : ndarray, shape (N, 3)
        The aircraft's specific force at the pilot, m/s^2, body axes FRD.
    w : ndarray, shape (N, 3)
        Its body rates, rad/s.
    dt : float
        Sample period, s.
    reach : ndarray, shape (2, 6)
        Lower (< 0) and upper (> 0) bound of each pose axis, m and rad
        (:func:`motionbase.report.robot_reach`).
    rate_limit, accel_limit : ndarray, shape (6,)
        Largest speed (m/s, rad/s) and acceleration (m/s^2, rad/s^2) of each pose axis
        (:func:`motionbase.washout.mpc_params.limits_from_robot`: the actuators' limits
        through the inverse kinematics at neutral).
    start : ndarray, shape (N, 6), optional
        A motion whose first :data:`HELD` poses every plan keeps (default: neutral).
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
        reach: np.ndarray,
        rate_limit: np.ndarray,
        accel_limit: np.ndarray,
        *,
        start: np.ndarray | None = None,
        g: float = STANDARD_GRAVITY,
        tol: float = 1e-7,
    ) -> None:
        import clarabel

        f = np.asarray(f, dtype=float)
        w = np.asarray(w, dtype=float)
        n = f.shape[0]
        if f.shape != (n, 3) or w.shape != (n, 3):
            raise ConfigError(f"motion bound: f and w must be (N, 3), got {f.shape}, {w.shape}")
        if not (np.isfinite(f).all() and np.isfinite(w).all()):
            raise ConfigError("motion bound: f and w must be finite")
        self.reach = np.asarray(reach, dtype=float)
        if (
            self.reach.shape != (2, 6)
            or not (self.reach[0] < 0).all()
            or not (self.reach[1] > 0).all()
        ):
            raise ConfigError("motion bound: reach must be (2, 6), lower < 0 < upper")
        self.rate_limit = np.asarray(rate_limit, dtype=float).reshape(6)
        self.accel_limit = np.asarray(accel_limit, dtype=float).reshape(6)
        if not ((self.rate_limit > 0).all() and (self.accel_limit > 0).all()):
            raise ConfigError("motion bound: rate and acceleration limits must be > 0")
        self.start = np.zeros((n, 6)) if start is None else np.asarray(start, dtype=float)
        if self.start.shape != (n, 6):
            raise ConfigError(f"motion bound: start must be ({n}, 6), got {self.start.shape}")
        self.n, self.dt, self.g = n, float(dt), float(g)
        self.f, self.w = f, w
        self._D1, self._D2 = difference_operators(n, dt)
        num, den = otolith_tf()
        otolith = model_operator(np.asarray(num) / OTOLITH_K, den, n, dt)
        self._models = [otolith] * 3 + [model_operator(*canal_tf(t), n, dt) for t in CANAL_TAU_L]
        # what the aircraft's pilot feels, by the scoring's own functions
        felt_f = perceived_specific_force(f, dt, normalized=True, g=g)
        self._felt = np.column_stack([felt_f, perceived_angular_velocity(w, dt)])
        self._settings = clarabel.DefaultSettings()
        self._settings.verbose = False
        for key in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
            setattr(self._settings, key, tol)
        self._alone: dict[int, tuple[np.ndarray, float]] = {}  # yaw, heave: one plan each

    def _qp(
        self,
        poses: list[int],
        errors: list[tuple[int, dict[tuple[str, int], sp.spmatrix]]],
        weights: dict[int, float],
    ) -> tuple[dict[int, np.ndarray], dict[int, float]]:
        """Plan the pose axes ``poses`` (0-5) for ``errors``, ``(i, {(kind, j): K})``: error
        ``i`` is the model of axis ``i`` applied to ``sum K x`` minus what the aircraft's
        pilot feels, ``x`` the pose (``kind`` ``"pose"``), rate (``"rate"``) or
        acceleration (``"acc"``) of axis ``j``. Returns (pose per axis, predicted RMS error
        per axis).

        Each axis's rate and acceleration are variables of their own, tied to its poses by
        the difference equations (times dt and dt^2, so every coefficient is about 1): the
        limits are then bounds and the cost diagonal, which the solver needs to converge.
        """
        import clarabel

        n, dt = self.n, self.dt
        blocks = [(kind, j) for j in poses for kind in ("pose", "rate", "acc")]
        blocks += [("error", i) for i, _ in errors]
        at = {b: k for k, b in enumerate(blocks)}

        def row(pieces: dict[tuple[str, int], sp.spmatrix]) -> sp.csr_matrix:
            height = next(iter(pieces.values())).shape[0]
            empty = sp.csr_matrix((height, n))
            return sp.hstack([pieces.get(b, empty) for b in blocks], format="csr")

        eye = sp.identity(n, format="csr")
        rows, rhs = [], []
        for j in poses:  # dt v = dt D1 p, dt^2 a = dt^2 D2 p
            rows.append(row({("rate", j): dt * eye, ("pose", j): -dt * self._D1}))
            rows.append(row({("acc", j): dt * dt * eye, ("pose", j): -dt * dt * self._D2}))
            rhs += [np.zeros(n), np.zeros(n)]
        for i, terms in errors:  # Ta (e_i + felt_i) = Mu (sum K x)
            Ta, Mu = self._models[i]
            rows.append(row({("error", i): Ta} | {b: -(Mu @ K) for b, K in terms.items()}))
            rhs.append(-(Ta @ self._felt[:, i]))
        held = sp.csr_matrix((np.ones(HELD), (np.arange(HELD), np.arange(HELD))), (HELD, n))
        for j in poses:
            rows.append(row({("pose", j): held}))
            rhs.append(self.start[:HELD, j])
        equations = sum(len(v) for v in rhs)
        for j in poses:  # box, speed, acceleration:  x + s = upper, -x + s = -lower
            for kind, lo, hi in (
                ("pose", self.reach[0, j], self.reach[1, j]),
                ("rate", -self.rate_limit[j], self.rate_limit[j]),
                ("acc", -self.accel_limit[j], self.accel_limit[j]),
            ):
                rows += [row({(kind, j): eye}), row({(kind, j): -eye})]
                rhs += [np.full(n, hi), np.full(n, -lo)]
        A = sp.vstack(rows, format="csc")
        b = np.concatenate(rhs)
        cones = [clarabel.ZeroConeT(equations), clarabel.NonnegativeConeT(len(b) - equations)]

        def weight(kind: str, k: int) -> float:
            if kind == "error":
                return weights[k]
            return {"acc": SMOOTHING, "pose": REGULARISATION}.get(kind, 0.0)

        diag = np.concatenate([np.full(n, weight(kind, k) * 2.0 / n) for kind, k in blocks])
        P = sp.diags(diag, format="csc")  # (the means: 1/n; the half: 2)
        solver = clarabel.DefaultSolver(P, np.zeros(P.shape[0]), A, b, cones, self._settings)
        sol = solver.solve()
        if str(sol.status) not in ("Solved", "AlmostSolved"):
            raise MotionbaseError(f"motion bound: the solver stopped: {sol.status}")
        x = np.asarray(sol.x)
        part = {bl: x[k * n : (k + 1) * n] for bl, k in at.items()}
        return (
            {j: np.clip(part[("pose", j)], self.reach[0, j], self.reach[1, j]) for j in poses},
            {i: float(np.sqrt(np.mean(part[("error", i)] ** 2))) for i, _ in errors},
        )

    def _single(self, axis: int, kind: str) -> tuple[np.ndarray, float]:
        """Yaw and heave: one error each, so one plan whatever the weights."""
        if axis not in self._alone:
            eye = sp.identity(self.n)
            poses, rmse = self._qp([axis], [(axis, {(kind, axis): eye})], {axis: 1.0})
            self._alone[axis] = (poses[axis], rmse[axis])
        return self._alone[axis]

    def solve(self, weights: np.ndarray) -> OptimalMotion:
        """The plan for the weights ``c`` on the six axes' mean square errors.

        Parameters
        ----------
        weights : array_like, shape (6,)
            ``c`` for x, y, z force ((m/s^2)^-2) and roll, pitch, yaw rate ((rad/s)^-2),
            each > 0. Heave and yaw are planned alone, so their weights change nothing.

        Raises
        ------
        MotionbaseError
            The solver did not converge.
        """
        c = np.asarray(weights, dtype=float).reshape(-1)
        if c.shape != (6,) or not (np.isfinite(c).all() and (c > 0).all()):
            raise ConfigError(f"motion bound: six weights > 0, got {np.asarray(weights)}")
        n, g = self.n, self.g
        pose = np.zeros((n, 6))
        rmse = np.zeros(6)
        pose[:, 5], rmse[5] = self._single(5, "rate")
        pose[:, 2], rmse[2] = self._single(2, "acc")
        psi = pose[:, 5]
        cos, sin = sp.diags(np.cos(psi)), sp.diags(np.sin(psi))
        yaw_rate, eye = sp.diags(self._D1 @ psi), sp.identity(n)
        errors = [
            (0, {("acc", 0): cos, ("acc", 1): sin, ("pose", 4): g * eye}),
            (1, {("acc", 0): -sin, ("acc", 1): cos, ("pose", 3): -g * eye}),
            (3, {("rate", 3): eye, ("pose", 4): -yaw_rate}),
            (4, {("rate", 4): eye, ("pose", 3): yaw_rate}),
        ]
        poses, err = self._qp([0, 1, 3, 4], errors, {i: c[i] for i in (0, 1, 3, 4)})
        for j, x in poses.items():
            pose[:, j] = x
        for i, e in err.items():
            rmse[i] = e
        return OptimalMotion(pose, rmse, c)

    def trade_off(self, mu: float, *, iterations: int = 6) -> OptimalMotion:
        """The plan that minimises the tuner's error terms,
        ``sum(rmse_force) + mu * sum(rmse_angular)``, as its model predicts them.

        By reweighting :meth:`solve`: each step weights an axis's mean square error by
        ``1 / rmse`` (forces) or ``mu / rmse`` (rates) of the last plan, which bounds the
        sum of RMS errors from above and touches it at the last plan, so the sum never
        rises from step to step.

        Parameters
        ----------
        mu : float
            (m/s^2) per (rad/s), > 0; the tuner weighs the angular errors with
            :data:`motionbase.tuning.WEIGHT_ANGULAR`, 20.
        iterations : int
            Plans solved (the first with weights ``1`` and ``mu^2``).
        """
        if not (np.isfinite(mu) and mu > 0):
            raise ConfigError(f"motion bound: mu must be > 0, got {mu!r}")
        scale = np.array([1.0, 1.0, 1.0, mu, mu, mu])
        c = scale**2
        best = None
        for _ in range(iterations):
            plan = self.solve(c)
            if best is None or _objective(plan.rmse, mu) < _objective(best.rmse, mu):
                best = plan
            c = scale / np.maximum(plan.rmse, 1e-6)
        return best

    def measured(self, pose: np.ndarray) -> np.ndarray:
        """The perceived RMS errors of ``pose`` as the tuner measures them (nonlinear),
        (6,): force x, y, z (m/s^2), rates roll, pitch, yaw (rad/s)."""
        t = np.arange(self.n) * self.dt
        m = cueing_metrics(t, self.f, self.w, pose, self.dt, reach=self.reach, g=self.g)
        return np.concatenate([m.rmse_specific_force, m.rmse_angular_velocity])


def _objective(rmse: np.ndarray, mu: float) -> float:
    return float(np.sum(rmse[:3]) + mu * np.sum(rmse[3:]))
