"""Model-predictive motion cueing (``--cueing mpc``): the platform's motion optimised over a
horizon with the vestibular models in the prediction, inside the platform's limits.

The model (linear, small angles)
--------------------------------
Eight double integrators, driven by their accelerations ``a`` (the QP's variables):
surge ``x``, sway ``y``, heave ``z``, the *tilt* of roll and pitch ``phi_t, theta_t``, the
*rotational* part of roll and pitch ``phi_r, theta_r`` and yaw ``psi``. The pose sent is
``[x, y, z, phi_t + phi_r, theta_t + theta_r, psi]`` (m, rad, base axes FRD). Its specific
force in cab axes, linearised (``R^T (p'' - (0, 0, g))`` of
:mod:`motionbase.washout.perception` at small angles), as a deviation from level flight::

    f = (x'' + g theta,  y'' - g phi,  z'')

and its body rates ``(phi', theta', psi')``. Tilt coordination is not a filter here: a
sustained ``f_x`` is cheapest to render by ``g theta``, and the optimiser finds it.

The error states: the otolith (normalised, DC gain 1) and semicircular-canal transfer
functions of :mod:`motionbase.washout.perception` (:func:`~.perception.otolith_tf`,
:func:`~.perception.canal_tf`, per axis) realised in state space and driven by the
platform's signal *minus the aircraft's*; being linear, their outputs are the perceived
platform motion minus the perceived aircraft motion, the errors the tuner scores. State
(31): 8 positions, 8 rates, 3 x 2 otolith states, 3 x 3 canal states; exogenous input: the
aircraft's specific-force deviation ``f - (0, 0, -g)`` and body rates (6).

The prediction (condensed QP)
-----------------------------
``N`` steps, the first one tick (``dt``) long, the others ``step_s`` (the horizon is
``dt + (N - 1) step_s``); the accelerations are held over each step and the model is
discretised exactly (zero-order hold, :func:`scipy.linalg.expm`). The first step's
acceleration is applied for one tick and the problem solved again the next tick. Cost
(each term times its step's length, so it approximates an integral)::

    sum_k h_k ( |W_f e_f|^2 + |W_w e_w|^2 + |W_p p|^2 + |W_v v|^2 + |W_a a|^2 )
      + sum_k |W_j (a_k - a_{k-1})|^2 / h_k

(jerk ``a_{-1}``: the acceleration applied last tick). Constraints at every step: the pose
box and the pose rates (total roll and pitch); the pose half a step ahead at its rate
(``p + v step_s / 2`` in the box: a glide onto a bound, never across it between grid
points); the tilt's angle and rate (the perception thresholds); the pose and tilt
accelerations. At the last step every rate is zero to within a tick's worth of
acceleration (the platform can stop inside its limits within the horizon: the braking
constraint). The Hessian and the constraint matrix do not change from tick to tick; the
linear term and the bounds do, so OSQP factorises once and each tick is a warm-started solve.

The reference over the horizon
------------------------------
The reference is the aircraft's specific-force deviation from level flight and its body
rates, each limited and scaled per axis (``[reference]``: a force no platform renders
would otherwise hold the platform at its limit for a gain too small to feel). Real-time
mode (the default): the current sample, held over the horizon, or decaying toward level
flight with the time constant ``[reference] decay_s``.
Preview mode (offline, :meth:`MpcCueing.set_preview`): the recorded future of the
reference, sample ``k + round(tau / dt)`` for a step starting ``tau`` s ahead.

False cues (``[weights] false_cue`` > 0)
---------------------------------------
The perceived platform motion at step ``k``, ``y_k = C (Phi_k w + Gam_k U)`` with ``w = z -
z_air`` (the model's state less that of the same model driven by the aircraft alone, so the
aircraft's part cancels), is held by soft constraints, one slack ``s`` per step and axis:
``y <= thr + s`` unless the aircraft's predicted perceived motion ``y_air`` is above ``thr``,
and ``y >= -thr - s`` unless it is below ``-thr`` (``thr``: the perception thresholds of
:mod:`motionbase.washout.perception`). Cost ``false_cue * h_k * s^2``. A cue beyond the
threshold where the aircraft gives none, or against the aircraft's, is a false cue, as the
tuner counts them; a stronger cue in the aircraft's direction is not. ``y_air`` is the
reference over the horizon through the same filters: its recorded future in preview mode,
the held (or decaying) sample in real time.

Failure and lateness
--------------------
The solver has ``max_iter`` iterations and ``time_limit_ms`` per tick. A classical washout
(``solver.fallback``) runs alongside every tick. When OSQP does not return *solved* (or
*solved inaccurate*), the MPC follows the rest of its last plan (feasible by construction)
and the pose sent blends toward the fallback's, with a smoothstep over ``blend_s`` (1.25
``blend_s`` from rest: the blend's pace ramps up and turns smoothly, so that a solver
failing now and then does not shake the pose); when it solves again the pose blends back.
:attr:`MpcCueing.info` holds the last tick's solver status, iterations and solve time;
:attr:`MpcCueing.counts` the ticks solved and fallen back.

The solver's tolerance can leave the model a hair outside a limit. Each tick therefore ends
with the model's tilt inside its angle and rate limits and its pose inside the box: a tilt
outside, which its acceleration limit (a perception threshold) cannot bring back within a
tick, made every later programme infeasible until the old plan brought it back.

Anti-windup: :meth:`MpcCueing.track` moves the model's pose to the one the platform got
(roll and pitch differences into the rotational part), stops the rates pointing further
out, and tells the fallback washout the same.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.linalg
import scipy.signal
import scipy.sparse as sp

from motionbase.errors import ConfigError
from motionbase.physics import smoothstep
from motionbase.washout.cueing import Cueing
from motionbase.washout.mpc_params import MpcParams
from motionbase.washout.perception import (
    CANAL_TAU_L,
    OTOLITH_K,
    THRESHOLD_ANGULAR_VELOCITY,
    THRESHOLD_SPECIFIC_FORCE,
    canal_tf,
    otolith_tf,
)

__all__ = ["MpcCueing", "MpcInfo", "MpcModel", "build_model", "check_reach"]

#: The eight double integrators, in state order.
DOFS = ("x", "y", "z", "roll_tilt", "pitch_tilt", "roll_rot", "pitch_rot", "yaw")
ND = 8  # dofs
NU = 8  # inputs: their accelerations
NX = 31  # states
NE = 6  # exogenous: aircraft f deviation (3), body rates (3)
_OTO = 16  # first otolith state
_CAN = 22  # first canal state
#: Pose axis of each dof, and the tilt dofs.
_POSE_OF = np.array([0, 1, 2, 3, 4, 3, 4, 5])
_TILT = (3, 4)
#: Statuses whose solution is used.
_OK = ("solved", "solved inaccurate")


@dataclass(frozen=True)
class MpcModel:
    """The continuous model and the condensed prediction of one configuration.

    Attributes
    ----------
    A, B, E, C : ndarray
        Continuous model ``z' = A z + B a + E d``, error outputs ``e = C z`` (6: perceived
        specific force x y z, m/s^2; perceived angular velocity roll pitch yaw, rad/s).
    h : ndarray, shape (N,)
        Step lengths, s.
    Ad, Bd, Ed : ndarray
        Discrete model of one tick (the first step).
    Phi, Gam, Lam : ndarray
        Condensed prediction: the states at steps 1..N, stacked, ``Z = Phi z0 + Gam U +
        Lam D`` (U: accelerations of steps 0..N-1; D: exogenous inputs per step).
    P : ndarray
        Hessian of the cost in U (dense, symmetric).
    Fz, Fd, Fu : ndarray
        Linear term ``q = Fz z0 + Fd D + Fu a_prev``.
    A_con : ndarray
        Constraint rows in U; their bounds are ``lo - S z0`` and ``hi - S z0`` with ``S =
        Sz`` (:attr:`lo`, :attr:`hi`).
    Sz : ndarray
        Free response of the constrained quantities.
    lo, hi : ndarray
        Their bounds.
    """

    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    C: np.ndarray
    h: np.ndarray
    Ad: np.ndarray
    Bd: np.ndarray
    Ed: np.ndarray
    Phi: np.ndarray
    Gam: np.ndarray
    Lam: np.ndarray
    P: np.ndarray
    Fz: np.ndarray
    Fd: np.ndarray
    Fu: np.ndarray
    A_con: np.ndarray
    Sz: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @property
    def steps(self) -> int:
        return len(self.h)


def _continuous(g: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    A = np.zeros((NX, NX))
    B = np.zeros((NX, NU))
    E = np.zeros((NX, NE))
    C = np.zeros((6, NX))
    A[:ND, ND : 2 * ND] = np.eye(ND)
    B[ND : 2 * ND, :] = np.eye(NU)
    num, den = otolith_tf()
    ao, bo, co, _ = scipy.signal.tf2ss(num / OTOLITH_K, den)
    for i in range(3):
        s = slice(_OTO + 2 * i, _OTO + 2 * i + 2)
        A[s, s] = ao
        b = bo[:, 0]
        # the signal: a_i (+ g theta for x, - g phi for y) - aircraft f_i
        B[s, i] += b
        if i == 0:
            A[s, 4] += g * b  # pitch tilt
            A[s, 6] += g * b  # pitch rot
        elif i == 1:
            A[s, 3] -= g * b
            A[s, 5] -= g * b
        E[s, i] = -b
        C[i, s] = co[0]
    for i in range(3):
        num, den = canal_tf(CANAL_TAU_L[i])
        ac, bc, cc, _ = scipy.signal.tf2ss(num, den)
        s = slice(_CAN + 3 * i, _CAN + 3 * i + 3)
        A[s, s] = ac
        b = bc[:, 0]
        rates = (ND + 3, ND + 5) if i == 0 else (ND + 4, ND + 6) if i == 1 else (ND + 7,)
        for r in rates:
            A[s, r] += b
        E[s, 3 + i] = -b
        C[3 + i, s] = cc[0]
    return A, B, E, C


def _discretise(A: np.ndarray, B: np.ndarray, E: np.ndarray, h: float):
    n, m, k = A.shape[0], B.shape[1], E.shape[1]
    M = np.zeros((n + m + k, n + m + k))
    M[:n, :n] = A
    M[:n, n : n + m] = B
    M[:n, n + m :] = E
    X = scipy.linalg.expm(M * h)
    return X[:n, :n], X[:n, n : n + m], X[:n, n + m :]


def build_model(params: MpcParams, dt: float) -> MpcModel:
    """The condensed prediction, cost and constraints for ``params`` at tick ``dt`` (s)."""
    N = params.steps
    h = np.full(N, params.step_s)
    h[0] = dt
    A, B, E, C = _continuous(params.gravity)
    disc = [_discretise(A, B, E, hk) for hk in ((dt, params.step_s) if N > 1 else (dt,))]
    Phi = np.zeros((N * NX, NX))
    Gam = np.zeros((N * NX, N * NU))
    Lam = np.zeros((N * NX, N * NE))
    phi, gam, lam = np.eye(NX), np.zeros((NX, N * NU)), np.zeros((NX, N * NE))
    for k in range(N):
        Ad, Bd, Ed = disc[0 if k == 0 else 1]
        phi, gam, lam = Ad @ phi, Ad @ gam, Ad @ lam
        gam[:, k * NU : (k + 1) * NU] += Bd
        lam[:, k * NE : (k + 1) * NE] += Ed
        r = slice(k * NX, (k + 1) * NX)
        Phi[r], Gam[r], Lam[r] = phi, gam, lam

    # -- cost: stage weights on the states (errors, positions, rates) and on the inputs
    p = params
    w_pos = np.array([*p.w_position[:3], p.w_tilt[0], p.w_tilt[0], *p.w_position[3:]])
    w_vel = np.array([*p.w_velocity[:3], p.w_tilt[1], p.w_tilt[1], *p.w_velocity[3:]])
    w_acc = np.array([*p.w_acceleration[:3], p.w_tilt[2], p.w_tilt[2], *p.w_acceleration[3:]])
    w_jerk = np.array([*p.w_jerk[:3], p.w_tilt[3], p.w_tilt[3], *p.w_jerk[3:]])
    Qx = C.T @ np.diag([*p.w_specific_force, *p.w_angular_velocity]) @ C
    Qx[:ND, :ND] += np.diag(w_pos)
    Qx[ND : 2 * ND, ND : 2 * ND] += np.diag(w_vel)
    Qbar = scipy.linalg.block_diag(*[h[k] * Qx for k in range(N)])
    R = np.diag(np.concatenate([h[k] * w_acc for k in range(N)]))
    # jerk: (a_k - a_{k-1}) / h_k weighted by h_k, a_{-1} the last applied
    Dm = np.eye(N * NU) - np.eye(N * NU, k=-NU)
    Jw = np.diag(np.concatenate([w_jerk / h[k] for k in range(N)]))
    GQ = Gam.T @ Qbar
    P = GQ @ Gam + R + Dm.T @ Jw @ Dm
    P = 0.5 * (P + P.T)
    E0 = np.zeros((N * NU, NU))
    E0[:NU] = np.eye(NU)
    Fz = GQ @ Phi
    Fd = GQ @ Lam
    Fu = -Dm.T @ Jw @ E0

    # -- constraints: per step, on the states: total pose (6), total rates (6), tilt angle
    # (2), tilt rate (2); at the last step: every rate = 0; on the inputs: total pose
    # accelerations (6), tilt accelerations (2)
    S = np.zeros((22, NX))
    tau = 0.5 * params.step_s
    for d in range(ND):
        S[_POSE_OF[d], d] = 1.0
        S[6 + _POSE_OF[d], ND + d] = 1.0
        # the pose a half step ahead at this rate stays in the box too: the platform glides
        # onto a bound instead of crossing it between two points of the grid (and the next
        # tick's problem stays feasible)
        S[16 + _POSE_OF[d], d] = 1.0
        S[16 + _POSE_OF[d], ND + d] = tau
    S[12, 3] = S[13, 4] = 1.0
    S[14, ND + 3] = S[15, ND + 4] = 1.0
    tilt = params.tilt_limits  # rows angle, rate, acceleration; columns roll, pitch
    box_hi = np.concatenate(
        [params.pose_upper, params.velocity_limit, tilt[0], tilt[1], params.pose_upper]
    )
    box_lo = np.concatenate(
        [params.pose_lower, -params.velocity_limit, -tilt[0], -tilt[1], params.pose_lower]
    )
    Sbar = scipy.linalg.block_diag(*[S] * N)
    term = np.zeros((ND, N * NX))
    term[:, (N - 1) * NX + ND : (N - 1) * NX + 2 * ND] = np.eye(ND)
    Su = np.zeros((8, NU))
    for d in range(ND):
        Su[_POSE_OF[d], d] = 1.0
    Su[6, 3] = Su[7, 4] = 1.0
    acc_hi = np.concatenate([params.acceleration_limit, tilt[2]])
    A_con = np.vstack([Sbar @ Gam, term @ Gam, scipy.linalg.block_diag(*[Su] * N)])
    Sz = np.vstack([Sbar @ Phi, term @ Phi, np.zeros((8 * N, NX))])
    # the exogenous inputs do not move the platform's states: Sbar @ Lam is zero
    # the terminal rates: at rest, within a tick's worth of the accelerations (the plans
    # of successive ticks sit on grids shifted by one tick: an exact zero made a shifted
    # plan infeasible now and then)
    v_end = dt * acc_hi[[0, 1, 2, 6, 7, 3, 4, 5]]
    lo = np.concatenate([np.tile(box_lo, N), -v_end, np.tile(-acc_hi, N)])
    hi = np.concatenate([np.tile(box_hi, N), v_end, np.tile(acc_hi, N)])
    Ad, Bd, Ed = disc[0]
    return MpcModel(A, B, E, C, h, Ad, Bd, Ed, Phi, Gam, Lam, P, Fz, Fd, Fu, A_con, Sz, lo, hi)


@dataclass
class MpcInfo:
    """The last tick of the MPC.

    Attributes
    ----------
    status : str
        OSQP's status (``"solved"``, ``"maximum iterations reached"``, ``"run time limit
        reached"``, ``"primal infeasible"``...), or ``"not solved"`` before the first tick.
    iterations : int
        OSQP iterations.
    solve_time_s : float
        Wall time of the update and solve, s.
    fallback : bool
        The solution was not used (the tick followed the last plan).
    weight : float
        Share of the MPC's pose in the pose sent (1: all MPC, 0: all fallback washout).
    violation : float
        With a robot bound: the largest slack of the soft actuator constraints in the last
        solution (actuator units; 0: every constraint held as linearised).
    """

    status: str = "not solved"
    iterations: int = 0
    solve_time_s: float = 0.0
    fallback: bool = False
    weight: float = 1.0
    violation: float = 0.0


class MpcCueing(Cueing):
    """Model-predictive cueing (see the module docstring).

    Parameters
    ----------
    params : MpcParams
    dt : float
        Sample period, s (the pipeline's).

    Attributes
    ----------
    info : MpcInfo
        The last tick's solver status, iterations, solve time, fallback and blend weight.
    counts : dict
        ``{"ticks", "solved", "fallbacks"}`` since the last :meth:`reset` (a pipeline's
        run: it resets after its warm-up ticks, which the summary counted as the run's).
    """

    name = "mpc"

    def __init__(self, params: MpcParams, dt: float) -> None:
        import osqp

        from motionbase.washout.classical import ClassicalWashout

        if not isinstance(params, MpcParams):
            raise TypeError(f"params must be MpcParams, got {type(params).__name__}")
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"mpc: dt must be > 0 s, got {dt!r}")
        self.params = params
        self.dt = dt
        with np.errstate(over="ignore", invalid="ignore"):  # (said below, as one error)
            self.model = m = build_model(params, dt)
        self.fallback = ClassicalWashout(params.fallback_washout, dt)
        N = params.steps
        self._N = N
        self._offsets = np.concatenate([[0.0], np.cumsum(m.h[:-1])])
        # real-time mode: the current sample over the steps, held or decaying
        tau = params.reference_decay_s
        ahead = np.ones(N) if tau == 0.0 else np.exp(-self._offsets / tau)
        self._Fd_hold = m.Fd @ np.kron(ahead[:, None], np.eye(NE))
        self._osqp = osqp
        self.robot = None
        self._legs: _LegConstraint | None = None
        # false cues: the perceived signals of every step, from the state and the inputs
        self._nf = 6 * N if params.w_false_cue > 0.0 else 0
        if self._nf:
            Cbar = scipy.linalg.block_diag(*[m.C] * N)
            self._Cz, self._Cu, self._Cd = Cbar @ m.Phi, Cbar @ m.Gam, Cbar @ m.Lam
            self._Cd_hold = self._Cd @ np.kron(ahead[:, None], np.eye(NE))
            thresholds = np.concatenate([THRESHOLD_SPECIFIC_FORCE, THRESHOLD_ANGULAR_VELOCITY])
            self._thr = np.tile(thresholds, N)
        self._assemble()
        self._ref_gain = np.array([*params.specific_force_gain, *params.angular_velocity_gain])
        self._ref_limit = np.array(
            [*params.specific_force_limit, *np.radians(params.angular_velocity_limit_deg_s)]
        )
        self._tilt_limits = params.tilt_limits
        self._preview: np.ndarray | None = None
        self.info = MpcInfo()
        self._mpc_pose = np.zeros(6)
        self._fb_pose = np.zeros(6)
        self.reset()

    def _assemble(self) -> None:
        """Set OSQP up on the whole problem. Variables: the accelerations ``U``, the false
        cues' slacks, the actuator rows' slacks; rows: the model's constraints, the false
        cues' (above, below, slack >= 0), the actuators' (last: :meth:`_LegConstraint.locate`
        finds them)."""
        m, N, nf, legs = self.model, self._N, self._nf, self._legs
        nl = legs.rows if legs is not None else 0
        nu = N * NU
        blocks = [[sp.csc_matrix(m.A_con), None, None]]
        lo, hi = [m.lo], [m.hi]
        weights = [sp.csc_matrix(m.P)]
        if nf:
            Cu, eye = sp.csc_matrix(self._Cu), sp.identity(nf, format="csc")
            blocks += [[Cu, -eye, None], [Cu, eye, None], [None, eye, None]]
            free = np.full(nf, np.inf)  # (the bounds of each tick: _false_cue_bounds)
            lo += [-free, -free, np.zeros(nf)]
            hi += [free, free, free]
            weights.append(sp.diags(self.params.w_false_cue * np.repeat(m.h, 6)))
        else:
            blocks = [[b[0]] for b in blocks]
        if legs is not None:
            width = len(blocks[0])
            blocks = [[*b, None] for b in blocks]
            blocks.append([legs.pattern, *([None] * (width - 1)), -sp.identity(nl)])
            # (per row, not per second: the first step, one tick long, is the pose sent)
            weights.append(sp.diags(np.full(nl, self.params.violation_weight)))
        A = sp.bmat(blocks, format="csc")
        A.sort_indices()
        if legs is not None:
            legs.locate(A, A.shape[0] - nl, nu)
            # set up at the neutral pose's values (OSQP scales the problem from them)
            A.data[legs.ax_idx], l_leg, u_leg = legs.linearise(np.zeros(NX), np.zeros(nu))
            lo.append(l_leg)
            hi.append(u_leg)
        P = sp.block_diag(weights, format="csc")
        self._setup_solver(A, np.concatenate(lo), np.concatenate(hi), P)

    def _setup_solver(self, A: sp.csc_matrix, lo: np.ndarray, hi: np.ndarray, P: Any) -> None:
        p = self.params
        self._slack = np.zeros(P.shape[0] - self._N * NU)
        budget = {"time_limit": p.time_limit_ms * 1e-3} if p.time_limit_ms > 0 else {}
        if not (np.isfinite(P.data).all() and np.isfinite(A.data).all()):
            raise ConfigError(
                "mpc parameters: the QP's coefficients overflow with these parameters (a "
                "weight, a limit or g too large; fix the [weights], [limits] or g)"
            )
        self._solver = self._osqp.OSQP()
        try:
            self._osqp_setup(A, lo, hi, P, budget)
        except self._osqp.OSQPException as exc:  # (its C library also says why, on stdout)
            raise ConfigError(
                f"mpc parameters: OSQP cannot factorise the QP these parameters make (error "
                f"{exc}); bring the [weights] closer to the shipped presets' (a weight of "
                "1e300 did this)"
            ) from None

    def _osqp_setup(
        self, A: sp.csc_matrix, lo: np.ndarray, hi: np.ndarray, P: Any, budget: dict
    ) -> None:
        p = self.params
        self._solver.setup(
            sp.triu(P, format="csc"),
            np.zeros(P.shape[0]),
            A,
            lo,
            hi,
            verbose=False,
            warm_starting=True,
            polishing=False,
            max_iter=p.max_iter,
            **budget,
            eps_abs=p.eps_abs,
            eps_rel=p.eps_rel,
            check_termination=5,
            # a fixed interval: OSQP's default (0) derives it from the setup's wall time,
            # which made runs of the same input differ
            adaptive_rho_interval=25,
        )

    def bind_robot(self, robot: Any) -> None:
        """Constrain the actuators, not only the pose box: the robot's actuator positions,
        linearised around the pose the last plan predicts at each step (re-linearised every
        tick), within their limits less ``[robot] actuator_margin`` of their range, and the
        actuator speeds and accelerations within ``speed_share`` and ``accel_share`` of
        theirs (see :class:`_LegConstraint`). The pose box stays. Called once by the
        pipeline, after the cueing is made.

        Raises
        ------
        ConfigError
            The robot lacks a pose axis (:func:`check_reach`, which also warns when the
            pose box exceeds the robot's reach)."""
        if robot is None or robot.n < 1:
            return
        check_reach(self.params, robot)
        self.robot = robot
        # soft: each leg row has a slack (free, cost violation_weight * slack^2): a state
        # the new linearisation puts past a limit (a tick cannot undo it) leaves the
        # problem feasible, and the plan returns within the limits
        self._legs = _LegConstraint(robot, self.model, self.params)
        self._assemble()
        self.reset()

    # -- lifecycle ---------------------------------------------------------------------
    def reset(self) -> None:
        """Back to rest at the neutral pose (model, plan, blend, fallback and counts)."""
        self.z = np.zeros(NX)
        self._z_air = np.zeros(NX)  # the model driven by the aircraft alone (false cues)
        self._a_prev = np.zeros(NU)
        self._plan = np.zeros((self._N, NU))
        self._plan_age = 0.0
        self._blend = 1.0
        self._blend_rate = 0.0  # the blend's change last tick
        self.counts = {"ticks": 0, "solved": 0, "fallbacks": 0}
        self._tick = 0
        self.fallback.reset()
        self._mpc_pose[:] = 0.0

    def set_preview(self, f: np.ndarray | None, w: np.ndarray | None = None) -> None:
        """Offline (preview) mode: the whole reference, one row per tick from the next
        :meth:`reset` (or from now, counted from the last reset): specific force (N, 3),
        m/s^2, and body rates (N, 3), rad/s. ``None`` goes back to the real-time mode."""
        if f is None:
            self._preview = None
            return
        f = np.asarray(f, dtype=float)
        w = np.asarray(w, dtype=float)
        if f.ndim != 2 or f.shape[1] != 3 or w.shape != f.shape or not len(f):
            raise ValueError("mpc preview: f and w must be (N, 3) arrays of the same length")
        d = np.hstack([f - np.array([0.0, 0.0, -self.params.gravity]), w])
        if not np.isfinite(d).all():
            raise ValueError("mpc preview: the reference has non-finite values")
        self._preview = self._ref_gain * np.clip(d, -self._ref_limit, self._ref_limit)

    def diagnostics(self) -> dict[str, Any]:
        """The last tick (:attr:`info`) for the log's ``/cueing/mpc`` topic: ``status``,
        ``iterations``, ``solve_time_s``, ``fallback``, ``weight``, ``preview``,
        ``violation``."""
        i = self.info
        return {
            "status": i.status,
            "iterations": i.iterations,
            "solve_time_s": i.solve_time_s,
            "fallback": i.fallback,
            "weight": i.weight,
            "preview": self._preview is not None,
            "violation": i.violation,
        }

    @property
    def preview(self) -> bool:
        """True in preview (offline) mode."""
        return self._preview is not None

    @property
    def made_for_preview(self) -> bool:
        """True when the parameters were tuned for preview mode (``mode = "preview"``)."""
        return self.params.mode == "preview"

    # -- one tick ----------------------------------------------------------------------
    def advance(self, u: np.ndarray, out: np.ndarray) -> bool:
        """One sample ``u = [f, w]`` to the pose in ``out`` (see :class:`Cueing`)."""
        if not np.isfinite(u).all():
            return False
        g = self.params.gravity
        d = np.array([u[0], u[1], u[2] + g, u[3], u[4], u[5]])
        d = self._ref_gain * np.clip(d, -self._ref_limit, self._ref_limit)
        self.fallback.advance(u, self._fb_pose)
        a0 = self._solve(d)
        m = self.model
        self.z = m.Ad @ self.z + m.Bd @ a0 + m.Ed @ d
        if self._nf:
            self._z_air = m.Ad @ self._z_air + m.Ed @ d
        z = self.z
        # the tilt in its own limits (first: the pose box below moves the rotational part).
        # A tilt past its angle limit by the solver's tolerance cannot come back within the
        # next tick (its acceleration limit is a perception threshold): every programme
        # after it was infeasible, until the old plan brought it back
        for j, dof in enumerate(_TILT):
            limit, rate_limit = self._tilt_limits[0, j], self._tilt_limits[1, j]
            if abs(z[dof]) > limit:
                if z[ND + dof] * z[dof] > 0.0:
                    z[ND + dof] = 0.0
                z[dof] = math.copysign(limit, z[dof])
            z[ND + dof] = min(max(z[ND + dof], -rate_limit), rate_limit)
        # the model's pose stays in its box (OSQP's tolerance): never an out-of-box pose
        pose = _pose_of(z)
        over = np.clip(pose, self.params.pose_lower, self.params.pose_upper) - pose
        for k in np.flatnonzero(over):
            _shift_axis(z, k, over[k])
        self._a_prev = a0
        self._mpc_pose[:] = _pose_of(z)
        wgt = smoothstep(self._blend)
        self.info.weight = wgt
        if wgt >= 1.0:
            out[:] = self._mpc_pose
        else:
            out[:] = wgt * self._mpc_pose + (1.0 - wgt) * self._fb_pose
        self._tick += 1
        return True

    def _reference(self, d: np.ndarray) -> np.ndarray:
        """Preview mode's exogenous inputs per step (N * 6): the current sample ``d``, then
        the recorded future (its last sample held past its end)."""
        D = np.tile(d, self._N)
        n = len(self._preview)
        idx = self._tick + np.rint(self._offsets[1:] / self.dt).astype(int)
        D[NE:] = self._preview[np.minimum(idx, n - 1)].reshape(-1)
        return D

    def _solve(self, d: np.ndarray) -> np.ndarray:
        m, z = self.model, self.z
        t0 = time.perf_counter()
        D = None if self._preview is None else self._reference(d)
        if D is None:
            q = m.Fz @ z + self._Fd_hold @ d + m.Fu @ self._a_prev
        else:
            q = m.Fz @ z + m.Fd @ D + m.Fu @ self._a_prev
        s = m.Sz @ z
        lo, hi = [m.lo - s], [m.hi - s]
        if self._nf:
            lo_f, hi_f = self._false_cue_bounds(d, D)
            lo += [np.full(self._nf, -np.inf), lo_f, np.zeros(self._nf)]
            hi += [hi_f, np.full(self._nf, np.inf), np.full(self._nf, np.inf)]
        if self._slack.size:
            q = np.concatenate([q, self._slack])
        if self._legs is None:
            self._solver.update(q=q, l=np.concatenate(lo), u=np.concatenate(hi))
        else:
            Ax, l_leg, u_leg = self._legs.linearise(z, self._plan.reshape(-1))
            self._solver.update(
                q=q,
                l=np.concatenate([*lo, l_leg]),
                u=np.concatenate([*hi, u_leg]),
                Ax=Ax,
                Ax_idx=self._legs.ax_idx,
            )
        res = self._solver.solve(raise_error=False)
        dt_solve = time.perf_counter() - t0
        status = res.info.status
        info = self.info
        info.status, info.iterations, info.solve_time_s = status, int(res.info.iter), dt_solve
        self.counts["ticks"] += 1
        x = res.x
        ok = status in _OK and x is not None and np.isfinite(x).all()
        self._move_blend(ok)
        if ok:
            self.counts["solved"] += 1
            info.fallback = False
            self._plan = x[: self._N * NU].reshape(self._N, NU)
            legs = x[self._N * NU + self._nf :]  # (the actuator rows' slacks)
            info.violation = float(np.max(np.abs(legs), initial=0.0))
            self._plan_age = 0.0
        else:
            self.counts["fallbacks"] += 1
            info.fallback = True
            self._plan_age += self.dt
        return self._planned(self._plan_age)

    def _move_blend(self, toward_mpc: bool) -> None:
        """One tick of the blend toward the MPC's pose (or the fallback's): at most ``step =
        dt / blend_s`` a tick, its change itself moving by at most ``2 step^2`` a tick (from
        rest to full pace in ``blend_s / 2``; a full blend takes ``1.25 blend_s``), so that the
        weight's rate never steps and its second difference stays within the smoothstep's
        own, ``6 step^2``. A blend turning at once made the pose of a solver failing every
        other tick zig-zag between MPC and fallback (cue accelerations of 80 m/s^2 and 120
        rad/s^2 where neither exceeded 16); a single failed tick now barely moves it."""
        step = self.dt / self.params.blend_s
        turn = 2.0 * step * step
        rate = step if toward_mpc else -step
        rate = min(max(rate, self._blend_rate - turn), self._blend_rate + turn)
        blend = self._blend + rate
        self._blend = min(1.0, max(0.0, blend))
        self._blend_rate = rate if blend == self._blend else 0.0  # (at rest at either end)

    def _false_cue_bounds(
        self, d: np.ndarray, D: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The false-cue rows' bounds on ``C Gam U`` (``y - s <= hi``, ``y + s >= lo`` in
        the model's docstring, the state's part moved to the right): the aircraft's
        predicted perceived motion ``y_air`` decides, per step and axis, which side of the
        threshold a platform cue may not cross."""
        air = self._Cz @ self._z_air
        # the model driven by the aircraft alone perceives (0 - aircraft): y_air = -that
        y_air = -(air + (self._Cd_hold @ d if D is None else self._Cd @ D))
        base = self._Cz @ self.z - air
        thr = self._thr
        hi = np.where(y_air > thr, np.inf, thr) - base
        lo = np.where(y_air < -thr, -np.inf, -thr) - base
        return lo, hi

    def _planned(self, age: float) -> np.ndarray:
        """The last plan's acceleration ``age`` s after it was made; past its end, a brake
        to rest within the acceleration limits."""
        ends = np.cumsum(self.model.h)
        k = int(np.searchsorted(ends, age + 1e-12, side="right"))
        if k < self._N:
            return self._plan[k].copy()
        v = self.z[ND : 2 * ND]
        lim = np.concatenate([self.params.acceleration_limit, self.params.tilt_limits[2]])
        a_lim = lim[[0, 1, 2, 6, 7, 3, 4, 5]]  # per dof
        return np.clip(-v / self.dt, -a_lim, a_lim)

    def track(self, achieved: np.ndarray) -> None:
        """Anti-windup: the model (and the fallback washout) continue from the pose the
        platform got (roll and pitch differences go to their rotational parts)."""
        ach = np.asarray(achieved, dtype=float)
        if ach.shape != (6,) or not np.isfinite(ach).all():
            return
        self.fallback.track(ach)
        diff = ach - self._mpc_pose  # (both continue from it, so their blend does too)
        z = self.z
        for k in np.flatnonzero(diff):
            _shift_axis(z, k, diff[k])
            lo, hi = self.params.pose_lower[k], self.params.pose_upper[k]
            tot = _pose_of(z)[k]
            z[_rot_dof(k)] += np.clip(tot, lo, hi) - tot
        self._mpc_pose[:] = _pose_of(z)

    def __repr__(self) -> str:
        mode = "preview" if self.preview else "real-time"
        return f"MpcCueing(dt={self.dt:g}, steps={self._N}, {mode})"


class _LegConstraint:
    """The actuators in the QP: their positions, speeds and accelerations, linearised per step.

    At step ``k`` the last plan (applied from the current state) predicts the pose
    ``pbar_k``; there the actuator positions are ``q_k = q(pbar_k)`` and their Jacobian
    ``J_k = dq/dpose`` (central differences, one batched call for every step:
    :meth:`motionbase.platform.robot.Robot.actuator_jacobian`). The constraints, on the
    QP's accelerations ``U``::

        lower + margin <= q_k + J_k (p_k(U) - pbar_k) + b_k J_k v_k(U) <= upper - margin
        |J_k v_k(U)| <= speed_share * max_speed
        |J_k a_k(U) + dJ_k/dt vbar_k| <= accel_share * max_accel

    with ``p_k(U)``, ``v_k(U)`` the predicted pose and pose rate (linear in ``U``); ``b_k J_k
    v_k`` the actuators' stopping distance ``v^2 / (2 a)`` at ``a = accel_share * max_accel``,
    linearised about the last plan's actuator speed ``J_k vbar_k`` (``b_k = |J_k vbar_k| /
    (2 a)``): an actuator moving toward a limit must be able to stop before it, so the plan
    brakes in time even where its later steps are not held to the actuators' accelerations;
    ``a_k(U)`` the pose acceleration of step ``k`` (part of ``U``) and ``dJ_k/dt vbar_k``
    the actuators' acceleration along the last plan's pose rate ``vbar_k`` at zero pose
    acceleration (:meth:`curvature`). Their constraints hold at the steps
    :func:`constrained_steps` picks (``[robot] steps`` of them; the speeds and accelerations
    at the first ``speed_steps``: fewer rows, a cheaper refactorisation).
    Their rows ``J_k T_k`` change every tick but not their sparsity pattern (every dof's
    acceleration of steps ``0..k``), so OSQP updates the values and refactorises
    numerically. A predicted pose the robot cannot reach is replaced by its clamp (the
    nearest reachable one toward neutral) as the linearisation point.
    """

    def __init__(self, robot: Any, model: MpcModel, params: MpcParams) -> None:
        self.robot = robot
        N = model.steps
        n = int(robot.n)
        self.n, self.N = n, N
        Sp = np.zeros((6, NX))
        Sv = np.zeros((6, NX))
        Sa = np.zeros((6, NU))  # the inputs are the dofs' accelerations
        for d in range(ND):
            Sp[_POSE_OF[d], d] = 1.0
            Sv[_POSE_OF[d], ND + d] = 1.0
            Sa[_POSE_OF[d], d] = 1.0
        G = model.Gam.reshape(N, NX, N * NU)
        F = model.Phi.reshape(N, NX, NX)
        sel_p = constrained_steps(N, params.robot_steps)
        sel_v = sel_p[: min(params.robot_speed_steps, len(sel_p))]
        self.sel_p, self.sel_v = sel_p, sel_v
        self.Tp = np.einsum("ij,kjc->kic", Sp, G)  # (N, 6, N NU)
        self.Tv_p = np.einsum("ij,kjc->kic", Sv, G[sel_p])  # pose rates of the position steps
        self.Tv = self.Tv_p[: len(sel_v)]  # (the speed steps are the first position steps)
        self.Pp = np.einsum("ij,kjc->kic", Sp, F)  # (N, 6, NX)
        self.Pv_p = np.einsum("ij,kjc->kic", Sv, F[sel_p])
        self.Ta = np.zeros((len(sel_v), 6, N * NU))  # step k's pose acceleration from U
        for i, k in enumerate(sel_v):
            self.Ta[i, :, k * NU : (k + 1) * NU] = Sa
        lim = robot.limits
        lower = np.asarray(lim.lower, dtype=float)
        upper = np.asarray(lim.upper, dtype=float)
        span = upper - lower
        self.q_lo = lower + params.actuator_margin * span
        self.q_hi = upper - params.actuator_margin * span
        self.v_max = params.speed_share * np.asarray(lim.max_speed, dtype=float)
        self.a_max = params.accel_share * np.asarray(lim.max_accel, dtype=float)
        self.rows = (len(sel_p) + 2 * len(sel_v)) * n
        # the structural pattern: position and speed rows of step k touch every dof of steps
        # 0..k, acceleration rows those of step k
        cp = (np.abs(self.Tp[sel_p]) + np.abs(self.Tv_p)).sum(axis=1) > 0
        cv = np.abs(self.Tv).sum(axis=1) > 0
        ca = np.abs(self.Ta).sum(axis=1) > 0
        mask = np.vstack([np.repeat(c, n, axis=0) for c in (cp, cv, ca)])
        self.pattern = sp.csc_matrix(mask.astype(float))
        self._h = 1e-6  # the Jacobian's difference step, m and rad
        self.ax_idx = np.empty(0, dtype=np.int64)
        self._rows = self._cols = np.empty(0, dtype=np.int64)
        self.clamped_points = 0
        # the clamp of :meth:`actuators`, loaded now: lazily, where a plan first left the
        # reach, mid-run
        robot.clamp(robot.pose_from_cue(np.zeros((1, 6))))

    def locate(self, A: sp.csc_matrix, row0: int, ncols: int) -> None:
        """The positions of the leg rows' entries in the CSC data of ``A`` (rows from
        ``row0``, columns before ``ncols``: the accelerations), in OSQP's order."""
        idx, rows, cols = [], [], []
        for c in range(ncols):
            for j in range(A.indptr[c], A.indptr[c + 1]):
                r = A.indices[j]
                if r >= row0:
                    idx.append(j)
                    rows.append(r - row0)
                    cols.append(c)
        self.ax_idx = np.array(idx, dtype=np.int64)
        self._rows = np.array(rows, dtype=np.int64)
        self._cols = np.array(cols, dtype=np.int64)

    def actuators(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Actuator positions (M, n) and Jacobians (M, n, 6) of cue poses (M, 6); a pose
        out of reach is replaced by its clamp."""
        robot = self.robot
        q, J = robot.actuator_jacobian(poses, self._h)
        bad = ~(np.isfinite(q).all(axis=1) & np.isfinite(J).all(axis=(1, 2)))
        if bad.any():
            self.clamped_points += int(bad.sum())
            cl, _ = robot.clamp(robot.pose_from_cue(poses[bad]))
            pairs = zip(cl, poses[bad], strict=True)
            back = np.array([robot.cue_from_pose(c, p) for c, p in pairs])
            q[bad], J[bad] = robot.actuator_jacobian(back, self._h)
        return np.nan_to_num(q), np.nan_to_num(J)

    def linearise(self, z: np.ndarray, plan: np.ndarray) -> tuple[np.ndarray, ...]:
        """The leg rows' values (in :attr:`ax_idx` order) and bounds for state ``z`` and
        the last plan (N NU,)."""
        free_p = self.Pp @ z  # (N, 6)
        moved = self.Tp @ plan
        sp_ = self.sel_p
        pbar = (free_p + moved)[sp_]
        q, J = self.actuators(pbar)
        # braking: the position rows hold q_k + b_k v_q,k, where the actuator's stopping
        # distance v^2 / (2 a) is linearised about the last plan's speed vbar (b = |vbar| / 2a)
        free_vp = self.Pv_p @ z  # (Np, 6)
        rates = free_vp + self.Tv_p @ plan
        b = np.abs(np.einsum("kij,kj->ki", J, rates)) / (2.0 * self.a_max)
        Mp = J @ self.Tp[sp_] + b[:, :, None] * (J @ self.Tv_p)  # (Np, n, N NU)
        nv = len(self.sel_v)  # the speed steps are the first position steps
        Mv = J[:nv] @ self.Tv
        Ma = J[:nv] @ self.Ta
        vals = np.concatenate([M.reshape(-1, M.shape[-1]) for M in (Mp, Mv, Ma)])
        Jv = np.einsum("kij,kj->ki", J, free_vp)  # the actuators' free speeds
        # J_k (pbar_k - free_k), less the braking term's free part
        Jm = np.einsum("kij,kj->ki", J, moved[sp_]) - b * Jv
        Jv = Jv[:nv]
        c = self.curvature(pbar[:nv], rates[:nv], q[:nv])
        lo = np.concatenate(
            [(self.q_lo - q + Jm).ravel(), (-self.v_max - Jv).ravel(), (-self.a_max - c).ravel()]
        )
        hi = np.concatenate(
            [(self.q_hi - q + Jm).ravel(), (self.v_max - Jv).ravel(), (self.a_max - c).ravel()]
        )
        return vals[self._rows, self._cols], lo, hi

    def curvature(self, poses: np.ndarray, rates: np.ndarray, q: np.ndarray) -> np.ndarray:
        """The actuators' acceleration at zero pose acceleration, ``dJ/dt v``: the second
        derivative of ``q(p + s v)`` in ``s`` (central differences), per pose (M, n); 0
        where the robot cannot reach the probes."""
        h = 1e-3  # s
        cue = np.concatenate([poses + h * rates, poses - h * rates])
        robot = self.robot
        qq = np.asarray(robot.inverse(robot.pose_from_cue(cue)), dtype=float)
        qq = qq.reshape(2, len(poses), -1)
        return np.nan_to_num((qq[0] - 2.0 * q + qq[1]) / (h * h))


#: The reach warnings given in this process (each once: the tuner builds many pipelines).
_WARNED: set[str] = set()


def check_reach(params: MpcParams, robot: Any) -> None:
    """The MPC against the robot it drives: a ConfigError when the robot lacks a pose axis
    (the MPC plans all six, sustained forces by tilt included, and would count on cues the
    robot drops), and a warning (once) naming each axis where the pose box ``[limits]``
    exceeds the robot's single-axis reach
    (:func:`~motionbase.platform.rus6_workspace.single_axis_envelope`, a few milliseconds):
    the clamp then cuts what the MPC plans, so the box is another platform's or wrong."""
    from motionbase.platform.robot import ROBOTS
    from motionbase.platform.rus6_workspace import AXES, lacking_axes, single_axis_envelope
    from motionbase.washout.cueing import LOADED_FROM, cueing_spec

    spec = ROBOTS.get(robot.name)
    what = spec.description if spec is not None else f"{robot.name} robot"
    lacking = lacking_axes(robot)
    if lacking:
        raise ConfigError(
            f"mpc: the {what} does not render {', '.join(lacking)}; the MPC plans all six "
            "axes of the pose (sustained forces by tilt included) and would count on cues "
            "this robot drops: use --cueing classical"
        )
    env = single_axis_envelope(robot, tol=1e-6)
    reach = np.array([[-a.negative for a in env], [a.positive for a in env]])
    box = np.array([params.pose_lower, params.pose_upper])
    # (5e-4 of it beyond, either sign: the 4 significant digits limits_from_robot writes
    # round a full reach outwards by as much, 0.5 mm on a reach of 1 m)
    slack = 5e-4 * np.abs(reach)
    over = np.flatnonzero((box[0] < reach[0] - slack[0]) | (box[1] > reach[1] + slack[1]))
    if not over.size:
        return

    def span(k: int, b: np.ndarray) -> str:
        lo, hi = (1e3 * b, "mm") if k < 3 else (np.degrees(b), "deg")
        return f"{lo[0]:.1f}..{lo[1]:.1f} {hi}"

    axes = ", ".join(f"{AXES[k]} {span(k, box[:, k])} (reach {span(k, reach[:, k])})" for k in over)
    source = getattr(params, LOADED_FROM, None)
    shipped = [
        f"--params {preset} for the {name} geometry {geometry}; "
        for (name, geometry), preset in cueing_spec("mpc").tuned_presets.items()
        if name == robot.name
    ]
    message = (
        f"mpc: the pose box of {Path(source).name if source else 'the parameters'} exceeds the "
        f"{what}'s single-axis reach on {axes}; the clamp will cut what the MPC plans there: "
        f"give MPC parameters made for this platform ({''.join(shipped)}their [limits] from "
        "motionbase.washout.mpc_params.limits_from_robot)"
    )
    if message not in _WARNED:
        _WARNED.add(message)
        logging.getLogger(__name__).warning(message)


def constrained_steps(steps: int, count: int) -> np.ndarray:
    """The prediction steps (of ``steps``) whose actuators are constrained: ``count`` of
    them, the first ones dense and then spread to the last (quadratic spacing:
    15, 7 -> 0 1 2 3 6 10 14)."""
    count = max(1, min(int(count), steps))
    if count == 1:
        return np.zeros(1, dtype=int)
    raw = np.rint(np.linspace(0.0, math.sqrt(steps - 1), count) ** 2).astype(int)
    out = [0]
    for r in raw[1:]:
        out.append(max(out[-1] + 1, int(r)))
    over = out[-1] - (steps - 1)
    if over > 0:  # pulled back from the end, keeping them distinct
        out = [min(o, steps - 1 - (count - 1 - i)) for i, o in enumerate(out)]
    return np.array(out, dtype=int)


def _rot_dof(axis: int) -> int:
    """The dof that takes a correction of pose axis ``axis`` (the rotational part)."""
    return (0, 1, 2, 5, 6, 7)[axis]


def _shift_axis(z: np.ndarray, k: int, shift: float) -> None:
    """Move the model's pose axis ``k`` by ``shift`` (through its rotational dof for roll
    and pitch) and stop that axis's rates that point against the shift (further out)."""
    z[_rot_dof(k)] += shift
    for j in np.flatnonzero(_POSE_OF == k):
        if z[ND + j] * shift < 0.0:
            z[ND + j] = 0.0


def _pose_of(z: np.ndarray) -> np.ndarray:
    p = z[:ND]
    return np.array([p[0], p[1], p[2], p[3] + p[5], p[4] + p[6], p[7]])
