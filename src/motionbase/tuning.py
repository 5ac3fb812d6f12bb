"""Tuning the cueing: the score of washout parameters over manoeuvres, and CMA-ES on it.

``motionbase tune`` looks for classical-washout parameters that make the pilot on a
given platform feel what the aircraft does, over a set of manoeuvres
(:mod:`motionbase.io.manoeuvres`). This module holds the maths: running a manoeuvre
through the whole chain, scoring it, and the optimiser. It does no I/O; the job
(:func:`motionbase.app.tune`) loads the manoeuvres, chooses where the evaluations run
(:mod:`motionbase.io.executors`, which calls :meth:`TuningProblem.evaluate`) and
writes the result.

The chain
---------
Each manoeuvre runs through the real pipeline (:class:`~motionbase.pipeline.Pipeline`:
validation, washout, fades and soft start, workspace clamp with anti-windup, inverse
kinematics, safety limiter) at the manoeuvre's rate, from park; :func:`run_chain` is the
one place that does it (one tick at a time today; the batch path of the pipeline
redesign replaces that one call). What the pilot feels is computed from the pose the
actuators realise, after clamping and safety, never from what the washout asked for.

The score (lower is better)
---------------------------
Per manoeuvre, over the ``running`` phase (the soft start from park excluded, as in
``motionbase report``), with the perception models and metrics of
:mod:`motionbase.washout.perception` (:func:`~motionbase.washout.perception.cueing_metrics`:
otolith, Young & Meiry; semicircular canals, Young & Oman; the same call ``report``
makes)::

    cost = e_f + W_ANGULAR e_w + W_FALSE_CUE c + W_LIMITS k + W_WORKSPACE u

- ``e_f``, m/s^2: the perceived specific-force error, the sum over x, y, z of the RMS of
  platform minus aircraft (1 g removed from both; otolith output normalised to read a
  sustained force at its value). Summed per axis rather than taken as a vector norm, so
  that an error no platform can remove on one axis (a 4 g pull-up in heave) does not
  mute the improvements on the others.
- ``e_w``, rad/s: the same for the perceived angular velocity (canal outputs), roll,
  pitch and yaw. ``W_ANGULAR`` = :data:`WEIGHT_ANGULAR` = 20 (m/s^2)/(rad/s), 0.35
  m/s^2 per deg/s: an error at the roll threshold (3.0 deg/s) costs about six times one
  at the surge threshold (0.17 m/s^2). With the ratio of the thresholds alone (3.25)
  the tuner gave rotation cues away for specific force (in a 200-evaluation trial on
  the default manoeuvres: angular error +13 % for specific force -16 %); rotation cues
  (the roll into a turn, the pitch of a rotation) are what pilots miss first.
- ``c``: false cues, the mean over the six channels (x, y, z force; roll, pitch, yaw
  rate) of the share of time in which the platform's perceived cue is above the
  perception threshold and the aircraft's is below it or of the other sign (the
  definition of ``report``). Thresholds: 0.17, 0.17, 0.28 m/s^2 (x, y, z) and 3.0, 3.6,
  2.6 deg/s (roll, pitch, yaw). ``W_FALSE_CUE`` = :data:`WEIGHT_FALSE_CUE` = 10 m/s^2:
  a false cue on one channel a tenth of the time costs 0.17 m/s^2.
- ``k``: the platform's limits are a hard constraint: the pipeline's clamp and safety
  stage never let a command past them, and what they did is counted, not hidden:
  ``k`` is the share of running ticks in which the workspace clamp moved the pose or
  the safety stage limited or held the command. ``W_LIMITS`` = :data:`WEIGHT_LIMITS`
  = 20 m/s^2: clamping 1 % of the time costs 0.2 m/s^2 (on top of the perceived
  error the clamp itself causes).
- ``u``: workspace use beyond a margin, ``sum of max(0, usage - 0.8)^2`` over the six
  pose axes and the six cranks. A pose axis's usage is its largest excursion as a share
  of the platform's single-axis reach that way (:func:`motionbase.report.robot_reach`); a
  crank's is its largest angle from its neutral angle as a share of the way to its limit
  that side (combined motions reach the crank limits before any single-axis reach).
  ``WORKSPACE_MARGIN`` = :data:`WORKSPACE_MARGIN` = 0.8, ``W_WORKSPACE`` =
  :data:`WEIGHT_WORKSPACE` = 10 m/s^2 (a full reach on one axis costs 0.4 m/s^2). It
  keeps a margin for motion the tuning set does not have, and keeps the cranks off the
  limits where the safety stage brakes them.

The score of a parameter set is the mean of the manoeuvres' costs (each manoeuvre
counts once, whatever its length; the totals in the tables are the same means) plus a
sizing term that does not depend on the manoeuvres::

    score = mean(cost) + W_SIZING s

- ``s``: the rule every shipped washout preset follows (``tests/test_washout_params.py``):
  an input held at its saturation limit on one axis at a time, each way (a specific
  force of 1000 m/s^2 clipped to ``specific_force_limit``, or a body rate clipped to
  ``angular_velocity_limit``; :data:`SIZING_DURATION_S` = 40 s at 120 Hz through the
  washout alone), must keep every pose axis within :data:`SIZING_MARGIN` = 90 % of the
  platform's single-axis reach. ``s`` is the sum over the six pose axes of the largest
  use beyond 90 %, ``W_SIZING`` = :data:`WEIGHT_SIZING` = 10 m/s^2 (10 % beyond costs
  1 m/s^2). The manoeuvres alone cannot see motion they do not contain; this keeps the
  result fit for any flight, as the default is. With flight-phase profiles, the file's
  own values and each profile's are sized alike, the largest use kept (a profile runs
  whole flights too).

The parameters tuned (:data:`KNOBS`)
------------------------------------
Twenty-one numbers of :class:`~motionbase.washout.params.WashoutParams`, each searched
between the bounds below on a log scale, normalised to [0, 1] (``(ln p - ln lo) /
(ln hi - ln lo)``), so CMA-ES steps are relative changes alike for every one. The
rest of the start set is kept as it is: the dampings (``zeta``), the input saturation
limits, gravity and the discretisation. Values are rounded to four significant digits
when decoded, so the file written holds exactly the parameters that were scored.

=======================  ==========================================  =================
parameter                field (axes)                                bounds
=======================  ==========================================  =================
specific-force gain      ``scaling.specific_force_gain`` x, y, z     0.05 .. 1
angular-velocity gain    ``scaling.angular_velocity_gain`` r, p, y   0.05 .. 1
translational wn         ``translational.wn`` x, y, z                0.3 .. 20 rad/s
translational wb         ``translational.wb`` x and y (one), z       0.05 .. 3 rad/s
tilt low-pass wn         ``tilt.wn``                                 0.3 .. 20 rad/s
tilt rate limit          ``tilt.rate_limit_deg_s`` roll, pitch       1 .. 6 deg/s
tilt angle limit         ``tilt.angle_limit_deg`` roll, pitch        1 .. 20 deg
tilt acceleration limit  ``tilt.accel_limit_deg_s2`` roll, pitch     2 .. 40 deg/s^2
rotational wn            ``rotational.wn`` roll, pitch, yaw          0.2 .. 5 rad/s
=======================  ==========================================  =================

The optimiser
-------------
CMA-ES (:mod:`cma`, Hansen's reference implementation) in the normalised space, with
the bounds handled by ``cma`` (``bounds = [0, 1]``), starting at the start set with a
step of :data:`SIGMA0` = 0.2 and ``cma``'s default population (13 for 21 parameters).
The budget counts evaluations of one parameter set over the whole manoeuvre set; the
start set is the first of them, so the result is never worse than the start on the
tuning set. Whole generations are told to CMA-ES; when the budget ends inside a
generation, its first candidates are still evaluated and may win. The seed ``S`` seeds
``cma``'s sampler (with ``S + 1``: ``cma`` reads 0 as "from the clock"); the same seed,
manoeuvres, platform and start give the same result, whatever runs the evaluations
(they are collected in order). A time budget may end the search sooner (no generation
starts that the last one's duration says would end after it); what it finds then
depends on the machine's speed too.
"""

from __future__ import annotations

import math
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from motionbase import stages
from motionbase.errors import ConfigError
from motionbase.pipeline import Pipeline, PipelineConfig
from motionbase.stopping import Stopped
from motionbase.washout.params import WashoutParams
from motionbase.washout.perception import cueing_metrics

if TYPE_CHECKING:
    from motionbase.io.manoeuvres import Manoeuvre

__all__ = [
    "KNOBS",
    "KNOBS_BY_CUEING",
    "MPC_KNOBS",
    "knobs_for",
    "SIGMA0",
    "SIZING_DURATION_S",
    "SIZING_MARGIN",
    "WEIGHT_ANGULAR",
    "WEIGHT_FALSE_CUE",
    "WEIGHT_LIMITS",
    "WEIGHT_SIZING",
    "WEIGHT_WORKSPACE",
    "WORKSPACE_MARGIN",
    "ChainRun",
    "Weights",
    "Knob",
    "ManoeuvreScore",
    "SetScore",
    "TuningProblem",
    "TuningResult",
    "TuningStopped",
    "crank_range",
    "decode",
    "describe_result",
    "encode",
    "format_table",
    "saturated_reach_use",
    "run_chain",
    "score_motion",
    "tune",
]

#: (m/s^2) per (rad/s) of perceived angular-velocity error (0.35 m/s^2 per deg/s).
WEIGHT_ANGULAR = 20.0
#: m/s^2 per unit share of time with false cues (mean over the six channels).
WEIGHT_FALSE_CUE = 10.0
#: m/s^2 per unit share of running ticks with the clamp or the safety stage acting.
WEIGHT_LIMITS = 20.0
#: m/s^2 per unit squared of workspace use beyond the margin, summed over the axes.
WEIGHT_WORKSPACE = 10.0
#: Share of the single-axis reach that workspace use may take before it costs.
WORKSPACE_MARGIN = 0.8
#: m/s^2 per unit share of the reach used beyond :data:`SIZING_MARGIN` by saturated inputs.
WEIGHT_SIZING = 10.0
#: Share of the single-axis reach a saturated input on one axis may use (the presets' rule).
SIZING_MARGIN = 0.9
#: Length of each saturated step of the sizing check, s.
SIZING_DURATION_S = 40.0


@dataclass(frozen=True)
class Weights:
    """The weights of the score's terms (defaults: the module constants, documented above)."""

    angular: float = WEIGHT_ANGULAR
    false_cue: float = WEIGHT_FALSE_CUE
    limits: float = WEIGHT_LIMITS
    workspace: float = WEIGHT_WORKSPACE
    margin: float = WORKSPACE_MARGIN
    sizing: float = WEIGHT_SIZING
    sizing_margin: float = SIZING_MARGIN


#: CMA-ES initial step in the normalised [0, 1] space.
SIGMA0 = 0.2
#: Significant digits of the parameters decoded (and written).
DIGITS = 4
#: The largest seed: ``cma`` is given ``seed + 1`` (it reads 0 as "from the clock") and
#: seeds numpy with it, which takes 0 .. 2**32 - 1.
MAX_SEED = 2**32 - 2


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class Knob:
    """One tuned number: a field of :class:`WashoutParams` (some axes of it), with bounds.

    Attributes
    ----------
    label : str
        Short name for tables.
    param : str
        The :class:`WashoutParams` attribute.
    axes : tuple of int or None
        The entries of a per-axis field set to this one value (None: a scalar field).
    lo, hi : float
        Bounds, in the field's unit (> 0; searched on a log scale).
    """

    label: str
    param: str
    axes: tuple[int, ...] | None
    lo: float
    hi: float

    def get(self, params: WashoutParams) -> float:
        """The value in ``params`` (the first of its axes)."""
        value = getattr(params, self.param)
        return float(value if self.axes is None else value[self.axes[0]])


KNOBS: tuple[Knob, ...] = (
    Knob("K_f x", "specific_force_gain", (0,), 0.05, 1.0),
    Knob("K_f y", "specific_force_gain", (1,), 0.05, 1.0),
    Knob("K_f z", "specific_force_gain", (2,), 0.05, 1.0),
    Knob("K_w roll", "angular_velocity_gain", (0,), 0.05, 1.0),
    Knob("K_w pitch", "angular_velocity_gain", (1,), 0.05, 1.0),
    Knob("K_w yaw", "angular_velocity_gain", (2,), 0.05, 1.0),
    Knob("trans wn x", "translational_wn", (0,), 0.3, 20.0),
    Knob("trans wn y", "translational_wn", (1,), 0.3, 20.0),
    Knob("trans wn z", "translational_wn", (2,), 0.3, 20.0),
    Knob("trans wb x,y", "translational_wb", (0, 1), 0.05, 3.0),
    Knob("trans wb z", "translational_wb", (2,), 0.05, 3.0),
    Knob("tilt wn", "tilt_wn", None, 0.3, 20.0),
    Knob("tilt rate roll deg/s", "tilt_rate_limit_deg_s", (0,), 1.0, 6.0),
    Knob("tilt rate pitch deg/s", "tilt_rate_limit_deg_s", (1,), 1.0, 6.0),
    Knob("tilt angle roll deg", "tilt_angle_limit_deg", (0,), 1.0, 20.0),
    Knob("tilt angle pitch deg", "tilt_angle_limit_deg", (1,), 1.0, 20.0),
    Knob("tilt accel roll deg/s2", "tilt_accel_limit_deg_s2", (0,), 2.0, 40.0),
    Knob("tilt accel pitch deg/s2", "tilt_accel_limit_deg_s2", (1,), 2.0, 40.0),
    Knob("rot wn roll", "rotational_wn", (0,), 0.2, 5.0),
    Knob("rot wn pitch", "rotational_wn", (1,), 0.2, 5.0),
    Knob("rot wn yaw", "rotational_wn", (2,), 0.2, 5.0),
)


#: The model-predictive cueing's knobs (:class:`~motionbase.washout.mpc_params.MpcParams`):
#: the cost weights, the reference limits and the tilt thresholds (its platform limits come
#: from the robot).
MPC_KNOBS: tuple[Knob, ...] = (
    Knob("w sf x", "w_specific_force", (0,), 0.1, 10.0),
    Knob("w sf y", "w_specific_force", (1,), 0.1, 10.0),
    Knob("w sf z", "w_specific_force", (2,), 0.1, 10.0),
    Knob("w ang roll,pitch", "w_angular_velocity", (0, 1), 40.0, 4000.0),
    Knob("w ang yaw", "w_angular_velocity", (2,), 40.0, 4000.0),
    Knob("w pos x,y", "w_position", (0, 1), 2.0, 200.0),
    Knob("w pos z", "w_position", (2,), 2.0, 200.0),
    Knob("w pos roll,pitch", "w_position", (3, 4), 20.0, 2000.0),
    Knob("w pos yaw", "w_position", (5,), 5.0, 500.0),
    Knob("w tilt", "w_tilt", (0,), 0.01, 1.0),
    # from 3e-3 up: lighter jerk weights let the MPC amplify specific force above about
    # 3 rad/s in the objective motion cueing test (benchmarks/RESULTS.md, issue 16)
    Knob("w jerk", "w_jerk", (0, 1, 2, 3, 4, 5), 3e-3, 0.1),
    Knob("ref sf x,y m/s2", "specific_force_limit", (0, 1), 0.5, 5.0),
    Knob("ref sf z m/s2", "specific_force_limit", (2,), 0.1, 3.0),
    Knob("ref ang deg/s", "angular_velocity_limit_deg_s", (0, 1, 2), 5.0, 60.0),
    Knob("tilt rate deg/s", "tilt_rate_limit_deg_s", (0, 1), 1.0, 6.0),
    Knob("tilt accel deg/s2", "tilt_accel_limit_deg_s2", (0, 1), 2.0, 40.0),
)

#: The knobs of each cueing (its registry name, :data:`~motionbase.washout.cueing.CUEINGS`).
KNOBS_BY_CUEING: dict[str, tuple[Knob, ...]] = {"classical": KNOBS, "mpc": MPC_KNOBS}


def knobs_for(cueing: str) -> tuple[Knob, ...]:
    """The tuned parameters of ``cueing``; a ConfigError for a cueing without knobs."""
    try:
        return KNOBS_BY_CUEING[cueing]
    except KeyError:
        raise ConfigError(
            f"tune: no knobs for the cueing {cueing!r} (tunable: "
            f"{', '.join(sorted(KNOBS_BY_CUEING))}; add its entry to "
            "motionbase.tuning.KNOBS_BY_CUEING)"
        ) from None


def encode(params: WashoutParams, knobs: Sequence[Knob] = KNOBS) -> np.ndarray:
    """Normalised log coordinates of ``params`` in [0, 1] (values outside the bounds clip).

    Returns
    -------
    ndarray, shape (len(knobs),)
    """
    out = np.empty(len(knobs))
    for i, k in enumerate(knobs):
        v = min(max(k.get(params), k.lo), k.hi)
        out[i] = (math.log(v) - math.log(k.lo)) / (math.log(k.hi) - math.log(k.lo))
    return out


def _round(v: float) -> float:
    return float(f"{v:.{DIGITS}g}")


def decode(x: Sequence[float], base: WashoutParams, knobs: Sequence[Knob] = KNOBS) -> WashoutParams:
    """The parameters at normalised coordinates ``x`` (clipped to [0, 1]), the rest ``base``'s.

    Each value is rounded to :data:`DIGITS` significant digits.
    """
    x = np.clip(np.asarray(x, dtype=float), 0.0, 1.0)
    if x.shape != (len(knobs),):
        raise ValueError(f"decode: expected {len(knobs)} coordinates, got shape {x.shape}")
    values: dict[str, Any] = {}
    for xi, k in zip(x, knobs, strict=True):
        v = _round(math.exp(math.log(k.lo) + xi * (math.log(k.hi) - math.log(k.lo))))
        if k.axes is None:
            values[k.param] = v
        else:
            current = list(values.get(k.param, getattr(base, k.param)))
            for a in k.axes:
                current[a] = v
            values[k.param] = tuple(current)
    return replace(base, **values)


# --------------------------------------------------------------------------- the chain


class ChainRun(NamedTuple):
    """What the chain did with one manoeuvre, per tick (N ticks, one per sample).

    Attributes
    ----------
    pose : ndarray, shape (N, 6)
        The realised platform pose (after clamping and safety), m and rad.
    clamped : ndarray of bool, shape (N,)
        The workspace clamp moved the pose.
    limited : ndarray of bool, shape (N,)
        The safety stage rate-limited or held the command.
    running : ndarray of bool, shape (N,)
        Ticks in the ``running`` phase (after the soft start).
    accepted : ndarray of bool, shape (N,)
        Samples the pipeline's validation accepted.
    angles : ndarray, shape (N, 6), optional
        The crank angles commanded (after safety), rad.
    cueing_counts : mapping of str to int
        What the cueing counted during the run, for a cueing that counts (an MPC's
        ``ticks``, ``solved`` and ``fallbacks``); empty otherwise.
    """

    pose: np.ndarray
    clamped: np.ndarray
    limited: np.ndarray
    running: np.ndarray
    accepted: np.ndarray
    angles: np.ndarray | None = None
    cueing_counts: Mapping[str, int] = MappingProxyType({})


def run_chain(config: PipelineConfig, manoeuvre: Manoeuvre, preview: bool = False) -> ChainRun:
    """Run a manoeuvre through the whole pipeline from park, one tick per sample (the
    pipeline's batch path), with its flight phase (a profiled cueing runs the profile of
    the phase); the one place the tuner runs the chain. With ``preview`` the cueing sees
    the manoeuvre's whole reference first (``set_preview``: offline cueing, an MPC's
    ``--preview``)."""
    m = manoeuvre
    pipeline = Pipeline(config)
    if preview:
        pipeline.cueing.set_preview(m.specific_force, m.angular_velocity)  # type: ignore[attr-defined]
    before = dict(getattr(pipeline.cueing, "counts", {}))
    result = pipeline.run_batch(
        m.t, m.specific_force, m.angular_velocity, m.attitude, m.fresh, on_ground=m.on_ground
    )
    after = getattr(pipeline.cueing, "counts", {})
    return ChainRun(
        result.poses,
        result.clamped,
        result.limited,
        result.phases == stages.RUNNING,
        result.accepted,
        result.commands,
        {key: n - before.get(key, 0) for key, n in after.items()},
    )


# --------------------------------------------------------------------------- the score


@dataclass(frozen=True)
class ManoeuvreScore:
    """The score of one parameter set on one manoeuvre (see the module docstring).

    Attributes
    ----------
    name : str
    duration : float
        Scored (running) time, s.
    rmse_specific_force : ndarray, shape (3,)
        Perceived specific-force RMSE per axis, m/s^2.
    rmse_angular_velocity : ndarray, shape (3,)
        Perceived angular-velocity RMSE per axis, rad/s.
    false_cues : ndarray, shape (6,)
        Share of time with a false cue: x, y, z force; roll, pitch, yaw rate.
    clamped : float
        Share of running ticks the workspace clamp acted.
    limited : float
        Share of running ticks the clamp or the safety stage acted (``k``).
    workspace_usage : ndarray, shape (6,)
        Largest excursion per axis as a share of the reach that way.
    crank_usage : ndarray, shape (6,)
        Largest crank angle from neutral as a share of the way to its limit that side
        (zeros when the run has no angles).
    weights : Weights
        Of the cost.
    """

    name: str
    duration: float
    rmse_specific_force: np.ndarray
    rmse_angular_velocity: np.ndarray
    false_cues: np.ndarray
    clamped: float
    limited: float
    workspace_usage: np.ndarray
    crank_usage: np.ndarray = field(default_factory=lambda: np.zeros(6))
    weights: Weights = Weights()

    @property
    def error_specific_force(self) -> float:
        """``e_f``: the sum of the per-axis perceived specific-force RMSEs, m/s^2."""
        return float(np.sum(self.rmse_specific_force))

    @property
    def error_angular_velocity(self) -> float:
        """``e_w``: the sum of the per-axis perceived angular-velocity RMSEs, rad/s."""
        return float(np.sum(self.rmse_angular_velocity))

    @property
    def false_cue_share(self) -> float:
        """``c``: mean share of time with a false cue over the six channels."""
        return float(np.mean(self.false_cues))

    @property
    def workspace_excess(self) -> float:
        """``u``: sum of squared use beyond the margin (:data:`WORKSPACE_MARGIN`), pose axes
        and cranks."""
        use = np.concatenate([self.workspace_usage, self.crank_usage])
        return float(np.sum(np.maximum(0.0, use - self.weights.margin) ** 2))

    @property
    def workspace_max(self) -> float:
        """Largest use of any pose axis's reach or any crank's range, share."""
        return float(max(np.max(self.workspace_usage), np.max(self.crank_usage)))

    @property
    def manoeuvre_cost(self) -> float:
        """:attr:`cost` (the tables' cost column; a set's is the mean of these)."""
        return self.cost

    @property
    def cost(self) -> float:
        """The manoeuvre's cost, m/s^2."""
        w = self.weights
        return (
            self.error_specific_force
            + w.angular * self.error_angular_velocity
            + w.false_cue * self.false_cue_share
            + w.limits * self.limited
            + w.workspace * self.workspace_excess
        )


def scored_samples(
    manoeuvre: Manoeuvre, run: ChainRun, g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples :func:`score_motion` scores: the running ticks' indices (the soft start
    left out), and the aircraft's specific force and body rates there, each sample the
    pipeline rejected replaced by the last one it accepted (level flight before any), as
    the pipeline held them: ``(sel, f, w)``, f and w of shape (len(sel), 3).

    Raises
    ------
    ConfigError
        Fewer than three running ticks (a manoeuvre shorter than the soft start: a user's
        window or recording, said in one line).
    """
    sel = np.flatnonzero(run.running)
    if sel.size < 3:
        raise ConfigError(
            f"manoeuvre {manoeuvre.name}: fewer than 3 of its {len(run.running)} ticks "
            f"come after the soft start ({np.count_nonzero(~run.running)} ticks); give a "
            "longer window or recording"
        )
    n = len(manoeuvre)
    last = np.maximum.accumulate(np.where(run.accepted, np.arange(n), -1))
    f = np.vstack([[0.0, 0.0, -g], manoeuvre.specific_force])[last + 1]
    w = np.vstack([[0.0, 0.0, 0.0], manoeuvre.angular_velocity])[last + 1]
    return sel, f[sel], w[sel]


def score_motion(
    manoeuvre: Manoeuvre,
    run: ChainRun,
    reach: np.ndarray,
    g: float,
    weights: Weights = Weights(),
    crank_range: np.ndarray | None = None,
) -> ManoeuvreScore:
    """Score what the chain did with a manoeuvre (see the module docstring).

    Parameters
    ----------
    manoeuvre : Manoeuvre
        The aircraft's motion (samples the pipeline rejected are replaced by the last
        accepted one, as the pipeline held them; level flight before any).
    run : ChainRun
        The chain's output for it (:func:`run_chain`, or any realised poses).
    reach : ndarray, shape (2, 6)
        Lower (< 0) and upper (> 0) single-axis reach of the platform, m and rad.
    g : float
        Gravity, m/s^2.
    weights : Weights
        Of the cost.
    crank_range : ndarray, shape (3, 6), optional
        Neutral, lower and upper actuator positions, rad or m (:func:`crank_range`); with it
        and ``run.angles`` the actuators' use of their range is scored too.

    Raises
    ------
    ValueError
        Fewer than three running ticks (a manoeuvre shorter than the soft start).
    """
    sel, f, w = scored_samples(manoeuvre, run, g)
    m = cueing_metrics(manoeuvre.t[sel], f, w, run.pose[sel], manoeuvre.dt, reach=reach, g=g)
    cranks = np.zeros(6)
    if crank_range is not None and run.angles is not None:
        d = run.angles[sel] - crank_range[0]
        up, down = crank_range[2] - crank_range[0], crank_range[1] - crank_range[0]
        cranks = np.maximum(0.0, np.maximum(d.max(axis=0) / up, d.min(axis=0) / down))
    return ManoeuvreScore(
        name=manoeuvre.name,
        duration=float(m.duration),
        rmse_specific_force=m.rmse_specific_force,
        rmse_angular_velocity=m.rmse_angular_velocity,
        false_cues=np.concatenate([m.false_cue_specific_force, m.false_cue_angular_velocity]),
        clamped=float(np.mean(run.clamped[sel])),
        limited=float(np.mean(run.clamped[sel] | run.limited[sel])),
        workspace_usage=m.workspace_usage,
        crank_usage=cranks,
        weights=weights,
    )


@dataclass(frozen=True)
class SetScore:
    """The score of one parameter set over a manoeuvre set: per manoeuvre and the means.

    Attributes
    ----------
    scores : tuple of ManoeuvreScore
    sizing_usage : ndarray, shape (6,)
        Largest use of the single-axis reach per pose axis under saturated inputs
        (:func:`saturated_reach_use`).
    weights : Weights
    sizing_checked : bool
        Whether ``sizing_usage`` was measured: the rule is the classical washout's, and an
        MPC's is left at zero (it keeps its own pose box).
    """

    scores: tuple[ManoeuvreScore, ...]
    sizing_usage: np.ndarray = field(default_factory=lambda: np.zeros(6))
    weights: Weights = Weights()
    sizing_checked: bool = True

    def _mean(self, attr: str) -> float:
        return float(np.mean([getattr(s, attr) for s in self.scores]))

    @property
    def sizing_excess(self) -> float:
        """``s``: sum of the reach used beyond the sizing margin under saturated inputs."""
        margin = self.weights.sizing_margin
        return float(np.sum(np.maximum(0.0, self.sizing_usage - margin)))

    @property
    def manoeuvre_cost(self) -> float:
        """Mean cost over the manoeuvres, m/s^2 (without the sizing term)."""
        return self._mean("cost")

    @property
    def cost(self) -> float:
        """Mean cost over the manoeuvres plus the sizing term, m/s^2 (what is minimised)."""
        return self._mean("cost") + self.weights.sizing * self.sizing_excess

    @property
    def error_specific_force(self) -> float:
        """Mean ``e_f``, m/s^2."""
        return self._mean("error_specific_force")

    @property
    def error_angular_velocity(self) -> float:
        """Mean ``e_w``, rad/s."""
        return self._mean("error_angular_velocity")

    @property
    def false_cue_share(self) -> float:
        return self._mean("false_cue_share")

    @property
    def clamped(self) -> float:
        return self._mean("clamped")

    @property
    def limited(self) -> float:
        return self._mean("limited")

    @property
    def workspace_max(self) -> float:
        """Largest workspace use of any axis in any manoeuvre, share of the reach."""
        return float(max(s.workspace_max for s in self.scores))


@dataclass(frozen=True, eq=False)
class TuningProblem:
    """Everything an evaluation needs: platform, manoeuvres, reach (plain data, picklable).

    Attributes
    ----------
    geometry : Rus6Geometry or Stewart6Geometry
        The platform.
    manoeuvres : tuple of Manoeuvre
    reach : ndarray, shape (2, 6)
        The platform's single-axis reach (:func:`motionbase.report.robot_reach`).
    weights : Weights
        Of the cost.
    cueing : str
        The cueing algorithm's name.
    robot : str
        The robot ``geometry`` is for (a 6-DOF name of
        :data:`~motionbase.platform.robot.ROBOTS`: ``rus6``, ``stewart6``).
    preview : bool
        The cueing sees each manoeuvre's future (:func:`run_chain`; offline cueing only).
    cranks : ndarray, shape (3, 6)
        Set from ``geometry``: the actuators' neutral, lower and upper positions (rad or m,
        :func:`crank_range`).
    """

    geometry: Any
    manoeuvres: tuple[Manoeuvre, ...]
    reach: np.ndarray
    weights: Weights = Weights()
    cueing: str = "classical"
    robot: str = "rus6"
    preview: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "cranks", crank_range(self.geometry, self.robot))

    def config(self, params: WashoutParams, manoeuvre: Manoeuvre) -> PipelineConfig:
        """The pipeline configuration for one manoeuvre (its rate, default settings)."""
        return PipelineConfig(
            robot=self.robot,
            geometry=self.geometry,
            cueing=self.cueing,
            cueing_params=params,
            rate_hz=manoeuvre.rate_hz,
        )

    def evaluate(self, params: WashoutParams) -> SetScore:
        """Score ``params`` over every manoeuvre, and its sizing."""
        return SetScore(
            tuple(
                score_motion(
                    m,
                    run_chain(self.config(params, m), m, self.preview),
                    self.reach,
                    params.gravity,
                    self.weights,
                    self.cranks,
                )
                for m in self.manoeuvres
            ),
            # the sizing rule is the classical washout's (an MPC keeps its box by design)
            saturated_reach_use(params, self.reach) if self.cueing == "classical" else np.zeros(6),
            self.weights,
            sizing_checked=self.cueing == "classical",
        )


def crank_range(geometry: Any, robot: str = "rus6") -> np.ndarray:
    """Neutral, lower-limit and upper-limit actuator positions of a 6-DOF platform, (3, 6):
    crank angles (rad) of a 6-RUS, leg lengths (m) of a Stewart platform. Neutral is the
    command of the zero cue pose."""
    from motionbase.platform.robot import robot_spec

    r = robot_spec(robot).make(geometry)
    return np.array([r.inverse(r.neutral_pose), r.limits.lower, r.limits.upper], dtype=float)


def saturated_reach_use(
    params: WashoutParams, reach: np.ndarray, dt: float = 1.0 / 120.0
) -> np.ndarray:
    """Largest share of the single-axis reach each pose axis takes under saturated inputs.

    Twelve runs of the washout alone (no clamp), each :data:`SIZING_DURATION_S` long: the
    specific force (x, y, z) or the body rate (roll, pitch, yaw) held at far beyond its
    saturation limit, each way, on one axis at a time. Parameters with flight-phase
    profiles are sized in each of them (the file's own values and every profile's: either
    may run a whole flight), the largest use kept.

    Returns
    -------
    ndarray, shape (6,)
        Per pose axis, the largest excursion over the reach that way (1 = the reach).
    """
    from motionbase.washout import ClassicalWashout

    n = int(round(SIZING_DURATION_S / dt))
    names = getattr(params, "profile_names", ())
    sets = [params] + [params.for_profile(name) for name in names]
    worst = np.zeros(6)
    for values in sets:
        for axis in range(6):
            for sign in (1.0, -1.0):
                f = np.tile([0.0, 0.0, -values.gravity], (n, 1))
                w = np.zeros((n, 3))
                if axis < 3:
                    f[:, axis] += sign * 1e3
                else:
                    w[:, axis - 3] = sign * 1e3
                poses = ClassicalWashout(values, dt).run(f, w)
                use = np.maximum(poses.max(axis=0) / reach[1], poses.min(axis=0) / reach[0])
                worst = np.maximum(worst, use)
    return worst


# --------------------------------------------------------------------------- the optimiser


@dataclass(frozen=True)
class TuningResult:
    """What :func:`tune` found.

    Attributes
    ----------
    start, best : WashoutParams
        The start set and the best set evaluated (the start when nothing beat it).
    start_score, best_score : SetScore
        Their scores on the tuning set.
    evaluations : int
        Parameter sets evaluated (the start included).
    generations : int
        CMA-ES generations told.
    history : tuple of float
        Best cost so far after the start and after each generation.
    seed : int
    knobs : tuple of Knob
    ended_by : str
        What ended the search: ``"budget"`` (the evaluations), ``"time"`` (the time
        budget: the next generation would have ended after it), ``"converged"`` (CMA-ES's
        own stopping rules) or ``"stop"`` (a stop request; :class:`TuningStopped`).
    """

    start: WashoutParams
    best: WashoutParams
    start_score: SetScore
    best_score: SetScore
    evaluations: int
    generations: int
    history: tuple[float, ...]
    seed: int
    knobs: tuple[Knob, ...] = KNOBS
    ended_by: str = "budget"


class TuningStopped(Stopped):
    """A tuning asked to stop before its budget ran out; ``found`` is what it had found.

    Raised by :func:`tune` when ``evaluate_many`` raises
    :class:`~motionbase.stopping.Stopped` after the start set was scored (a stop before
    that raises the plain :class:`~motionbase.stopping.Stopped`: nothing was found).

    Parameters
    ----------
    reason : str
        The stop request's reason (``"SIGINT"``, ...).
    found : TuningResult
        The start, the best set of the generations completed and their scores;
        ``evaluations`` counts only the evaluations whose scores came back.
    """

    def __init__(self, reason: str, found: TuningResult) -> None:
        super().__init__(reason)
        self.found = found


#: Evaluates parameter sets in order: ``evaluate_many([p1, p2, ...]) -> [score1, ...]``.
EvaluateMany = Callable[[list[WashoutParams]], list[SetScore]]


def tune(
    start: WashoutParams,
    evaluate_many: EvaluateMany,
    *,
    budget: int | None,
    seed: int,
    popsize: int | None = None,
    sigma0: float = SIGMA0,
    knobs: Sequence[Knob] = KNOBS,
    on_progress: Callable[[int, int | None, float], None] | None = None,
    profile: str | None = None,
    time_budget_s: float | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> TuningResult:
    """CMA-ES over ``knobs`` from ``start``, within ``budget`` evaluations and
    ``time_budget_s`` seconds.

    Parameters
    ----------
    start : WashoutParams
        The start set (its untuned fields are kept in every candidate).
    evaluate_many : callable
        Scores a list of parameter sets, results in the same order (locally, in a
        process pool or on a cluster: :mod:`motionbase.io.executors`).
    budget : int or None
        Evaluations of one parameter set over the whole manoeuvre set, >= 1 (the
        start is the first); None: no limit (``time_budget_s`` must then be given).
    seed : int
        Seeds CMA-ES (>= 0).
    popsize : int, optional
        CMA-ES population; default ``cma``'s (4 + 3 ln n).
    sigma0 : float
        Initial step in the normalised space.
    knobs : sequence of Knob
        The parameters tuned.
    on_progress : callable, optional
        ``on_progress(evaluations, budget, best_cost)`` after each batch.
    time_budget_s : float, optional
        Seconds on ``clock`` from the call, the start set's evaluation included: no
        generation is started that would end after it, judged by the last generation's
        duration (the first starts if any time is left). The result then depends on the
        machine's speed, not only on the seed.
    clock : callable
        Seconds, monotonic (:func:`time.monotonic`; a test's own clock).
    profile : str, optional
        Tune this flight-phase profile of ``start`` (``"ground"``, ``"air"``: its values,
        written as the profile's overrides, :meth:`WashoutParams.with_profile`) instead of
        the file's own values; the rest of the file is kept. The manoeuvres' flight phase
        decides where each profile runs.

    Raises
    ------
    TuningStopped
        ``evaluate_many`` raised :class:`~motionbase.stopping.Stopped` after the start
        set was scored: the exception carries the best set found so far.
    """
    import cma

    if budget is None and time_budget_s is None:
        raise ValueError("tune: give a budget of evaluations, of time, or both")
    if budget is not None and budget < 1:
        raise ValueError(f"tune: budget must be >= 1 evaluation, got {budget}")
    if time_budget_s is not None and not time_budget_s > 0:
        raise ValueError(f"tune: time budget must be > 0 s, got {time_budget_s}")
    if not 0 <= seed <= MAX_SEED:
        raise ValueError(f"tune: seed must be from 0 to {MAX_SEED}, got {seed}")
    knobs = tuple(knobs)
    tuned = start if profile is None else start.for_profile(profile)

    def candidate(x: np.ndarray) -> WashoutParams:
        values = decode(x, tuned, knobs)
        return values if profile is None else start.with_profile(profile, values)

    t0 = clock()
    deadline = math.inf if time_budget_s is None else t0 + time_budget_s
    cap = budget if budget is not None else sys.maxsize
    start_score = evaluate_many([start])[0]
    best, best_score = start, start_score
    evaluations, generations = 1, 0
    ended_by = "budget"
    last_generation_s = 0.0
    history = [start_score.cost]
    if on_progress is not None:
        on_progress(evaluations, budget, best_score.cost)
    options = {
        "bounds": [0.0, 1.0],
        "seed": seed + 1,
        "verbose": -9,
        "verb_disp": 0,
        "verb_log": 0,
    }
    if popsize is not None:
        options["popsize"] = int(popsize)

    def found() -> TuningResult:
        return TuningResult(
            start=start,
            best=best,
            start_score=start_score,
            best_score=best_score,
            evaluations=evaluations,
            generations=generations,
            history=tuple(history),
            seed=seed,
            knobs=knobs,
            ended_by=ended_by,
        )

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        es = cma.CMAEvolutionStrategy(encode(tuned, knobs).tolist(), sigma0, options)
        while evaluations < cap:
            if es.stop():
                ended_by = "converged"
                break
            began = clock()
            if began + last_generation_s >= deadline:  # it would end after the deadline
                ended_by = "time"
                break
            xs = es.ask()
            remaining = cap - evaluations
            whole = len(xs) <= remaining
            xs = xs if whole else xs[:remaining]
            candidates = [candidate(x) for x in xs]
            try:
                scores = evaluate_many(candidates)
            except Stopped as exc:  # this batch is lost; the generations before it are not
                ended_by = "stop"
                raise TuningStopped(exc.reason, found()) from None
            last_generation_s = clock() - began
            evaluations += len(candidates)
            for cand, score in zip(candidates, scores, strict=True):
                if score.cost < best_score.cost:
                    best, best_score = cand, score
            if whole:
                es.tell(xs, [s.cost for s in scores])
                generations += 1
            history.append(best_score.cost)
            if on_progress is not None:
                on_progress(evaluations, budget, best_score.cost)
    return found()


# --------------------------------------------------------------------------- tables

#: Columns of :func:`format_table`: title, attribute, scale, format.
_COLUMNS = (
    ("sf RMSE m/s^2", "error_specific_force", 1.0, "{:.3f}"),
    ("ang RMSE deg/s", "error_angular_velocity", 180.0 / math.pi, "{:.2f}"),
    ("false cues %", "false_cue_share", 100.0, "{:.1f}"),
    ("clamped %", "limited", 100.0, "{:.1f}"),
    ("workspace %", "workspace_max", 100.0, "{:.0f}"),
    ("cost", "manoeuvre_cost", 1.0, "{:.3f}"),
)


def _pct_change(before: float, after: float) -> str:
    if before == 0.0:
        return "n/a" if after == 0.0 else "+inf"
    return f"{100.0 * (after - before) / before:+.0f} %"


def format_table(sections: Sequence[tuple[str, SetScore, SetScore]]) -> str:
    """Before/after table: the score terms per manoeuvre and their means, per section.

    Parameters
    ----------
    sections : sequence of (title, before, after)
        E.g. the tuning set and the held-out set.

    Returns
    -------
    str
        Columns: perceived specific-force error ``e_f`` (m/s^2), angular-velocity error
        ``e_w`` (deg/s), false cues (mean share over the six channels, %), clamped
        (share of running ticks the clamp or the safety stage acted, %), workspace
        (largest use of any pose axis's single-axis reach or of any crank's range, %; the
        largest over the manoeuvres in the mean row), cost (the manoeuvre's; the mean row
        its mean); each before and after; then the relative change of the means, and the
        sizing under saturated inputs with the score tuned (mean cost plus the sizing term).
    """
    names = [s.name for _, b, _ in sections for s in b.scores]
    means = {id(b): f"  mean of {len(b.scores)} (workspace: largest)" for _, b, _ in sections}
    name_w = max([24, *(len(n) + 4 for n in names), *(len(m) + 2 for m in means.values())])
    cell = 16
    lines = [
        " " * name_w + "".join(f"{c[0]:>{cell}}" for c in _COLUMNS),
        f"{'':<{name_w}}" + "".join(f"{'before   after':>{cell}}" for _ in _COLUMNS),
    ]

    def row(label: str, b: Any, a: Any) -> str:
        cells = "".join(
            f"{fmt.format(scale * getattr(b, attr)):>8}{fmt.format(scale * getattr(a, attr)):>8}"
            for _, attr, scale, fmt in _COLUMNS
        )
        return f"{label:<{name_w}}{cells}"

    for title, before, after in sections:
        lines.append(title)
        for sb, sa in zip(before.scores, after.scores, strict=True):
            lines.append(row(f"  {sb.name}", sb, sa))
        lines.append(row(means[id(before)], before, after))
        changes = ", ".join(
            f"{title_} {_pct_change(getattr(before, attr), getattr(after, attr))}"
            for title_, attr, _, _ in (_COLUMNS[0], _COLUMNS[1], _COLUMNS[5])
        )
        lines.append(f"  change of the means: {changes}")
    _, before, after = sections[0]
    if not before.sizing_checked:  # (an MPC: the rule is the classical washout's)
        lines.append(
            "saturated single-axis inputs: not checked for this cueing (the sizing rule is the "
            "classical washout's; an MPC keeps the pose box of its [limits])"
        )
        lines.append(
            f"score tuned (the tuning set's mean cost): {before.cost:.3f} -> {after.cost:.3f}"
        )
        return "\n".join(lines)
    lines.append(
        "saturated single-axis inputs (washout alone): largest use of the reach "
        f"{100 * before.sizing_usage.max():.0f} % -> {100 * after.sizing_usage.max():.0f} % "
        f"(rule: at most {100 * before.weights.sizing_margin:.0f} %)"
    )
    lines.append(
        f"score tuned (the tuning set's mean cost + {before.weights.sizing:g} x the use beyond "
        f"the rule): {before.cost:.3f} -> {after.cost:.3f}"
    )
    return "\n".join(lines)


def describe_result(
    result: TuningResult,
    *,
    platform: str,
    start: str,
    holdout: tuple[SetScore, SetScore] | None = None,
) -> tuple[str, list[str]]:
    """The ``description`` and the comment lines of the file a tuning run writes.

    Parameters
    ----------
    result : TuningResult
    platform, start : str
        Names of the platform and of the start set, as the user gave them.
    holdout : (SetScore, SetScore), optional
        Held-out scores of the start and the best set.
    """
    names = ", ".join(s.name for s in result.start_score.scores)
    before, after = result.start_score, result.best_score
    description = (
        f"Tuned by motionbase tune for the {platform} platform from the {start} set "
        f"(CMA-ES, seed {result.seed}, {result.evaluations} evaluations): cost "
        f"{before.cost:.4g} -> {after.cost:.4g} over {names}"
    )
    lines = [
        f"for the platform {platform}, from the parameters {start}: CMA-ES over "
        f"{len(result.knobs)} parameters (motionbase.tuning.KNOBS_BY_CUEING; the others as in "
        "the start "
        f"set), seed {result.seed}, {result.evaluations} evaluations.",
        f"Tuning set: {names}: cost {before.cost:.4g} -> {after.cost:.4g} (perceived "
        f"specific-force error {before.error_specific_force:.3f} -> "
        f"{after.error_specific_force:.3f} m/s^2, angular-velocity error "
        f"{math.degrees(before.error_angular_velocity):.2f} -> "
        f"{math.degrees(after.error_angular_velocity):.2f} deg/s).",
    ]
    if holdout is not None:
        held = ", ".join(s.name for s in holdout[0].scores)
        lines.append(f"Held out: {held}: cost {holdout[0].cost:.4g} -> {holdout[1].cost:.4g}.")
    lines.append("The objective, its weights and thresholds: the docstring of motionbase.tuning.")
    return description, lines
