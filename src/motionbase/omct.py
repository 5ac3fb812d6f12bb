"""The objective motion cueing test (OMCT): the frequency response of the whole motion chain.

The test of ICAO Doc 9625 (4th edition; Hosman & Advani, "Design and evaluation of the
objective motion cueing test and criterion", The Aeronautical Journal 120, 2016): the
aircraft moves sinusoidally about one axis at a time, at the 12 frequencies
``w_k = 10^(-1 + 0.2 k)`` rad/s, ``k = 0..11`` (0.1 to 15.85 rad/s), and the gain and
phase of what the platform does are measured at the input frequency. This module does
the maths and no I/O: signals, the simulation through the pipeline, the Fourier
coefficients and the classical washout's analytic linear response.
:mod:`motionbase.io.omct_plots` writes the JSON file, the tables and the Bode plots.

The tests
---------
Direct responses (gain dimensionless):

- ``roll``, ``pitch``, ``yaw``: aircraft body rate (p, q, r) -> platform body rate.
- ``surge``, ``sway``, ``heave``: aircraft specific force (x, y, z deviation from level
  flight) -> platform specific force at the pilot reference point, in cab axes.

Cross-couplings:

- ``pitch->surge``, ``roll->sway``: aircraft pitch (roll) angle -> platform surge (sway)
  specific force, in (m/s^2)/rad. The aircraft's specific force stays at level flight,
  so the ideal response is 0: what is measured is the false cue of the platform's
  rotation (the gravity component ``g sin(theta)`` of its tilt) less what the washout's
  translation cancels of it.
- ``surge->pitch``, ``sway->roll``: aircraft surge (sway) specific force -> platform pitch
  (roll) angle, in rad/(m/s^2): the tilt coordination. ``g`` times the gain is the share
  of the specific force rendered by tilting the cab.

Input signals
-------------
One axis at a time, starting from rest in level flight (specific force ``(0, 0, -g)``)
after the pipeline's soft start: the test input ``u`` (an angular velocity, rad/s, or a
specific force deviation, m/s^2) is ``A cos(w t)`` from ``t = 0``. The aircraft's velocity
(translational tests) or attitude (rotational tests: ``A/w sin(w t)``) then oscillates
about a constant without drift. The rotational tests keep the aircraft's specific force at
level flight, ``(0, 0, -g)``: the rotation is about the pilot reference point in
coordinated flight, where the felt force does not follow the attitude (a cab tilted at rest
would feel the gravity component; the OMCT's own convention could not be checked, see the
amplitudes below).

Amplitudes (:class:`Amplitudes`): **not** the test table of Doc 9625, which could not be
consulted (only the abstracts of Hosman & Advani 2016 and of the papers that use it were at
hand). They are chosen so that the default and gentle washouts on the ``ceart`` platform
stay linear (no clamp, no scaling limit, no tilt-rate or tilt-acceleration limit, no
actuator speed or acceleration limit): rotations of 5 deg of aircraft attitude, with the
angular-velocity amplitude capped at 10 deg/s (so 5 deg up to 2 rad/s, then 10 deg/s / w),
and specific forces of 0.5 m/s^2 (with the default washout's gain 0.5 and tilt low-pass at
2 rad/s the tilt rate peaks at 1.5 deg/s and the tilt acceleration at 5.8 deg/s^2, inside
3 deg/s and 8 deg/s^2). ``Amplitudes().scaled(k)`` (``motionbase omct --scale K``) pushes
the chain into its limits, where the measured response leaves the linear one.

Measurement
-----------
The pipeline (:func:`simulate`: validation, washout, fades, clamp, inverse kinematics,
safety limiter) turns the samples into commanded actuator angles. The achieved pose is
computed from those angles by the robot's forward kinematics, at the pilot reference point:
the platform frame origin (the centroid of the platform joints; the geometries define no
other point). The cab's specific force ``R^T (p'' - (0, 0, g))`` and body rates follow
from the poses (:func:`~motionbase.washout.perception.platform_specific_force` and
:func:`~motionbase.washout.perception.platform_angular_velocity`, central differences).
Planar mode (the 3-RRR): its ``[x, y, phi]`` about home is mapped back to a full-size cab
as the pipeline mapped the washout onto it (divided by ``planar_scale_m`` and
``planar_yaw_scale``); its plane is horizontal, so its specific force is its acceleration.
Only the ``surge``, ``sway`` and ``yaw`` tests apply to it.

The transient is discarded: whole periods covering ``10 / sigma`` seconds, where ``sigma``
is the decay rate of the washout's slowest pole (the translational ``wb``, 0.3 rad/s for the
default: 33 s; a double pole has decayed to about 1e-3 of its peak by then), at least one
period. Then at least 2 periods and at least 5 s are measured. Gain and phase are the ratio
of output to input Fourier coefficients at the input frequency over those whole periods
(a least-squares fit of cosine, sine and a constant, which equals the discrete Fourier
coefficients over whole periods and ignores the constant offset, such as 1 g in heave).

The analytic response (:func:`classical_response`)
-------------------------------------------------
The classical washout linearised about level flight (small angles, no limit acting), from
its parameters and the continuous filter designs of :mod:`motionbase.washout.filters`;
``Hr`` the rotational high-pass (rate to rate, ``s^2/(s^2 + 2 zeta wn s + wn^2)``), ``Ht``
the translational one (acceleration to acceleration, ``s^3/((s^2 + 2 zeta wn s + wn^2)
(s + wb))``), ``L`` the tilt low-pass, ``K_w`` and ``K_f`` the gains:

- roll, pitch, yaw: ``K_w Hr``;
- heave: ``K_f Ht``;
- surge, sway: ``K_f (L + (1 - L) Ht)``: the tilt renders ``L`` (through gravity), and the
  translational channel gets what the tilt leaves, ``(1 - L)``, because the washout turns
  the scaled force into base axes with the tilted attitude (Reid & Nahon's ``L_IS``).
  Planar mode: ``K_f (1 - L) Ht`` (the robot cannot tilt);
- pitch->surge: ``+g K_w Hr (1 - Ht)``; roll->sway: ``-g K_w Hr (1 - Ht)``: the tilt's
  gravity component, less the translation the washout commands against it;
- surge->pitch: ``K_f L / g``; sway->roll: ``-K_f L / g``;
- each of them times the input low-pass ``P = wn^2/(s^2 + 2 wn s + wn^2)`` when the file
  has one (``[input] lowpass_wn`` > 0): it filters every input channel first.

The tables and plots compare the measurement with the same response of the discrete chain
(``classical_response(..., dt=...)``: each block discretised as the washout does it and
evaluated at ``z = e^{j w dt}``, the central differences of the measurement in place of
``s`` and ``s^2``); on the default washout and ``ceart`` they agree within 2e-4. That
response differs from the continuous design by the Tustin frequency warping and the central
differences: at 120 Hz, gains by at most 0.45 % and phases by at most 0.05 deg, except the
pitch->surge and roll->sway phases at the top frequencies (1.2 deg at 15.85 rad/s), where
the tilt's gravity cue and the translation against it nearly cancel and the small errors of
each show; they grow as ``(w dt)^2``. A difference between the measurement and the linear
response is nonlinearity: clamping, the scaling limits, the tilt rate and acceleration
limits, the actuators' speed and acceleration limits (the table counts the clamped and
rate-limited ticks of each measured window).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from motionbase import __version__
from motionbase.errors import ConfigError, MotionbaseError
from motionbase.physics import STANDARD_GRAVITY
from motionbase.pipeline import Pipeline, PipelineConfig
from motionbase.platform.robot import ROBOTS
from motionbase.washout.filters import (
    discretise,
    lowpass2,
    rotational_highpass,
    translational_highpass,
)
from motionbase.washout.params import WashoutParams
from motionbase.washout.perception import platform_angular_velocity, platform_specific_force

__all__ = [
    "AXES",
    "FREQUENCIES",
    "MIN_SCALE",
    "TESTS",
    "Amplitudes",
    "Motion",
    "OmctResult",
    "OmctTest",
    "Simulated",
    "TestResult",
    "achieved_motion",
    "classical_response",
    "excitation",
    "phasor",
    "run_omct",
    "settle_time",
    "simulate",
    "slowest_decay",
]

#: The 12 test frequencies, rad/s: ``10^(-1 + 0.2 k)``, k = 0..11 (0.1 to 15.85).
FREQUENCIES = 10.0 ** (-1.0 + 0.2 * np.arange(12))
#: The excited axes, in the order of the pose's angles and of the specific force.
AXES = ("roll", "pitch", "yaw", "surge", "sway", "heave")
_ROTATIONS = ("roll", "pitch", "yaw")
_COMPONENT = {"roll": 0, "pitch": 1, "yaw": 2, "surge": 0, "sway": 1, "heave": 2}
#: Axes the planar 3-RRR renders (planar mode maps surge, sway and yaw).
PLANAR_AXES = ("surge", "sway", "yaw")
#: Discarded time, in units of the slowest washout pole's time constant.
SETTLE_TIME_CONSTANTS = 10.0
MIN_MEASURE_PERIODS = 2
MIN_MEASURE_S = 5.0  # s
#: The highest frequency needs this many samples per half period (8 per period).
MIN_SAMPLES_PER_HALF_PERIOD = 4
#: Level flight before the excitation starts, beyond the pipeline's soft start, s.
PRE_ROLL_S = 1.0
#: The most ticks one run may simulate (about 0.5 kB a tick: 2.5 GB). The default washout on
#: ceart (``tuned_ceart``, 192 s of transient) at the highest rate, 10 kHz: 3.8 million.
MAX_RUN_TICKS = 5_000_000
#: The smallest amplitude scale (``Amplitudes.scaled``, ``omct --scale``): at 1e-6 the
#: heave gain at 0.1 rad/s is still within 3e-5 of the one at 1e-2; by 1e-12 the heave input
#: (5e-13 m/s^2 on 9.8) is 0.1 % off by rounding and the gains are noise.
MIN_SCALE = 1e-6


# --------------------------------------------------------------------------- the tests


@dataclass(frozen=True)
class OmctTest:
    """One OMCT test: which axis is excited and what is measured.

    Attributes
    ----------
    name : str
        ``"pitch"``, ``"pitch->surge"``, ...
    title : str
        What is compared, in words.
    excite : str
        The aircraft axis moved (one of :data:`AXES`).
    output : str
        The platform axis measured.
    gain_unit : str
        Unit of the gain (``"-"`` for the direct responses).
    """

    name: str
    title: str
    excite: str
    output: str
    gain_unit: str

    @property
    def direct(self) -> bool:
        return self.excite == self.output

    @property
    def input_unit(self) -> str:
        """Unit of the quantity the gain divides by."""
        if self.excite in _ROTATIONS:
            return "rad/s" if self.direct else "rad"
        return "m/s^2"


TESTS: tuple[OmctTest, ...] = (
    OmctTest("roll", "aircraft roll rate -> platform roll rate", "roll", "roll", "-"),
    OmctTest("pitch", "aircraft pitch rate -> platform pitch rate", "pitch", "pitch", "-"),
    OmctTest("yaw", "aircraft yaw rate -> platform yaw rate", "yaw", "yaw", "-"),
    OmctTest(
        "surge", "aircraft surge specific force -> platform surge specific force", "surge",
        "surge", "-",
    ),
    OmctTest(
        "sway", "aircraft sway specific force -> platform sway specific force", "sway", "sway",
        "-",
    ),
    OmctTest(
        "heave", "aircraft heave specific force -> platform heave specific force", "heave",
        "heave", "-",
    ),
    OmctTest(
        "pitch->surge", "aircraft pitch angle -> platform surge specific force", "pitch",
        "surge", "(m/s^2)/rad",
    ),
    OmctTest(
        "roll->sway", "aircraft roll angle -> platform sway specific force", "roll", "sway",
        "(m/s^2)/rad",
    ),
    OmctTest(
        "surge->pitch", "aircraft surge specific force -> platform pitch angle", "surge",
        "pitch", "rad/(m/s^2)",
    ),
    OmctTest(
        "sway->roll", "aircraft sway specific force -> platform roll angle", "sway", "roll",
        "rad/(m/s^2)",
    ),
)  # fmt: skip
_BY_NAME = {t.name: t for t in TESTS}


def _test(test: str | OmctTest) -> OmctTest:
    if isinstance(test, OmctTest):
        return test
    try:
        return _BY_NAME[test]
    except KeyError:
        raise ConfigError(f"OMCT: unknown test {test!r} (one of {', '.join(_BY_NAME)})") from None


@dataclass(frozen=True)
class Amplitudes:
    """Input amplitudes of the tests (module docstring: why these, and what they are not).

    Parameters
    ----------
    angle : float
        Rotational tests: amplitude of the aircraft's attitude, rad (default 5 deg) ...
    rate : float
        ... with its angular velocity ``w * angle`` capped at this, rad/s (default 10 deg/s).
    specific_force : float
        Translational tests: amplitude of the specific force deviation, m/s^2 (0.5).
    """

    angle: float = math.radians(5.0)
    rate: float = math.radians(10.0)
    specific_force: float = 0.5

    def __post_init__(self) -> None:
        for name in ("angle", "rate", "specific_force"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"OMCT amplitudes: {name} must be > 0, got {value!r}")

    def of(self, axis: str, w: float) -> float:
        """Amplitude of the test input at ``w`` rad/s: angular velocity (rad/s) or m/s^2."""
        if axis in _ROTATIONS:
            return min(self.angle * w, self.rate)
        return self.specific_force

    def scaled(self, k: float) -> Amplitudes:
        """Every amplitude times ``k`` (at least :data:`MIN_SCALE`)."""
        if not (isinstance(k, (int, float)) and math.isfinite(k) and k > 0):
            raise ConfigError(f"OMCT: the amplitude scale must be a number > 0, got {k!r}")
        if k < MIN_SCALE:
            raise ConfigError(
                f"OMCT: --scale {k:g} is below {MIN_SCALE:g}: the test signals would be lost "
                "in the chain's rounding (a heave input on top of 1 g, the platform's motion "
                "read back by forward kinematics), giving noise for gains; use a larger --scale"
            )
        return Amplitudes(self.angle * k, self.rate * k, self.specific_force * k)

    def describe(self) -> str:
        return (
            f"rotations {math.degrees(self.angle):g} deg of attitude with the rate capped at "
            f"{math.degrees(self.rate):g} deg/s; specific force {self.specific_force:g} m/s^2"
        )


def excitation(
    axis: str, w: float, amplitude: float, t: np.ndarray, t0: float, g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Aircraft samples of one test: level flight, then ``amplitude cos(w (t - t0))`` on one axis.

    Parameters
    ----------
    axis : str
        One of :data:`AXES`.
    w : float
        Frequency, rad/s.
    amplitude : float
        Angular velocity (rad/s, rotations) or specific force deviation (m/s^2).
    t : ndarray, shape (N,)
        Sample times, s.
    t0 : float
        Start of the excitation, s (level flight before).
    g : float
        Gravity, m/s^2.

    Returns
    -------
    f, w, att : ndarray, shape (N, 3) each
        Specific force (m/s^2), body rates (rad/s) and attitude (rad), body axes FRD. A
        rotation about one body axis from level attitude: the body rate is the Euler rate.
    """
    if axis not in AXES:
        raise ConfigError(f"OMCT: unknown axis {axis!r} (one of {', '.join(AXES)})")
    t = np.asarray(t, dtype=float)
    tau = t - t0
    on = tau >= 0.0
    n = t.shape[0]
    f = np.zeros((n, 3))
    f[:, 2] = -g
    rates = np.zeros((n, 3))
    att = np.zeros((n, 3))
    i = _COMPONENT[axis]
    u = np.where(on, amplitude * np.cos(w * tau), 0.0)
    if axis in _ROTATIONS:
        rates[:, i] = u
        att[:, i] = np.where(on, amplitude / w * np.sin(w * tau), 0.0)
    else:
        f[:, i] += u
    return f, rates, att


# --------------------------------------------------------------------------- the chain


class Simulated(NamedTuple):
    """What the pipeline commanded, per tick.

    Attributes
    ----------
    angles : ndarray, shape (N, n)
        Commanded actuator angles, rad (after the safety stage).
    poses : ndarray, shape (N, m)
        The pipeline's platform poses (6-RUS ``[x, y, z, roll, pitch, yaw]``, planar
        ``[x, y, phi]``): guesses for the forward kinematics.
    clamped : ndarray of bool, shape (N,)
        The workspace clamp moved the pose.
    limited : ndarray of bool, shape (N,)
        The safety stage rate-limited or held the command.
    fallbacks, ticks : int
        For a cueing that counts them (an MPC's ``counts``): the ticks its solver failed on
        (the pose blended toward its fallback washout), of the ticks it solved for.
    """

    angles: np.ndarray
    poses: np.ndarray
    clamped: np.ndarray
    limited: np.ndarray
    fallbacks: int = 0
    ticks: int = 0


def simulate(
    config: PipelineConfig,
    t: np.ndarray,
    f: np.ndarray,
    w: np.ndarray,
    att: np.ndarray,
    *,
    cueing: Any | None = None,
    preview: bool = False,
) -> Simulated:
    """Run aircraft samples through a new pipeline; the one place the OMCT runs the chain.

    The pipeline's batch path (:meth:`Pipeline.run_batch`): every stage, compiled.

    Parameters
    ----------
    config : PipelineConfig
    t : ndarray, shape (N,)
        Sample times, s, one per tick (``1 / config.rate_hz`` apart).
    f, w, att : ndarray, shape (N, 3)
        Specific force (m/s^2), body rates (rad/s), attitude (rad).
    cueing : Cueing, optional
        A cueing plug-in object to run instead of the one ``config`` names (a test
        cueing that is not registered).
    preview : bool
        Hand the cueing the whole input first (``set_preview``: an MPC's offline mode).

    Raises
    ------
    MotionbaseError
        The pipeline rejected a sample (an amplitude beyond its input bounds).
    """
    pipeline = Pipeline(config, cueing=cueing)
    if preview:
        pipeline.cueing.set_preview(f, w)
    result = pipeline.run_batch(t, f, w, att)
    if not result.accepted.all():
        k = int(np.flatnonzero(~result.accepted)[0])
        raise MotionbaseError(
            f"OMCT: the pipeline rejected the test signal at t = {t[k]:.3f} s "
            f"({pipeline.health.last_rejection}); lower the amplitudes (a smaller --scale)"
        )
    angles, poses = result.commands, result.poses
    clamped, limited = result.clamped, result.limited
    counts = getattr(pipeline.cueing, "counts", None)
    counts = counts if isinstance(counts, dict) else {}
    fallbacks, ticks = int(counts.get("fallbacks", 0)), int(counts.get("ticks", 0))
    return Simulated(angles, poses, clamped, limited, fallbacks, ticks)


class Motion(NamedTuple):
    """The achieved motion at the pilot reference point (washout-equivalent for planar).

    Attributes
    ----------
    pose : ndarray, shape (N, 6)
        ``[x, y, z, roll, pitch, yaw]``, m and rad, base axes FRD.
    specific_force : ndarray, shape (N, 3)
        In cab axes, m/s^2 (``(0, 0, -g)`` at rest).
    angular_velocity : ndarray, shape (N, 3)
        Body rates, rad/s.
    """

    pose: np.ndarray
    specific_force: np.ndarray
    angular_velocity: np.ndarray


def achieved_motion(config: PipelineConfig, angles: np.ndarray, guess: np.ndarray) -> Motion:
    """The motion the commanded actuator angles realise, by forward kinematics.

    Parameters
    ----------
    config : PipelineConfig
        For the robot and its planar mapping.
    angles : ndarray, shape (N, n)
        Actuator angles, rad, one row per tick.
    guess : ndarray, shape (N, m)
        Starting poses of the forward kinematics (the pipeline's poses).

    Raises
    ------
    MotionbaseError
        The forward kinematics did not converge.
    """
    robot = config.make_robot()
    pose = np.asarray(robot.forward(angles, guess), dtype=float)
    if not np.isfinite(pose).all():
        k = int(np.flatnonzero(~np.isfinite(pose).all(axis=1))[0])
        raise MotionbaseError(f"OMCT: forward kinematics did not converge at tick {k}")
    pose6 = robot.cue_from_pose(pose, np.zeros((len(pose), 6)))
    g = STANDARD_GRAVITY
    return Motion(
        pose6,
        platform_specific_force(pose6, config.dt, g),
        platform_angular_velocity(pose6, config.dt),
    )


def phasor(y: np.ndarray, t: np.ndarray, w: float) -> complex:
    """Complex amplitude ``Y`` of ``y ~ Re(Y e^{j w t}) + c`` over the samples (least squares).

    Over whole periods this is the Fourier coefficient at ``w`` (``2/N sum y e^{-j w t}``
    for uniformly sampled whole periods); the constant ``c`` is fitted and ignored.
    """
    wt = w * np.asarray(t, dtype=float)
    basis = np.column_stack([np.cos(wt), -np.sin(wt), np.ones_like(wt)])
    coef = np.linalg.lstsq(basis, np.asarray(y, dtype=float), rcond=None)[0]
    return complex(coef[0], coef[1])


# --------------------------------------------------------------------------- analytic


def classical_response(
    params: WashoutParams,
    test: str | OmctTest,
    w: Any,
    *,
    tilt: bool = True,
    dt: float | None = None,
) -> np.ndarray:
    """The classical washout's linear frequency response for one test (module docstring).

    Parameters
    ----------
    params : WashoutParams
    test : str or OmctTest
        A test name of :data:`TESTS`.
    w : array_like
        Frequencies, rad/s.
    tilt : bool
        Whether the robot renders roll and pitch (False for the planar 3-RRR: the tilt's
        gravity cue is lost, the washout's translation is not).
    dt : float, optional
        None: the continuous design. A sample period (s): the discrete chain as the OMCT
        measures it at that rate, each block discretised as the washout does it
        (:func:`~motionbase.washout.filters.discretise`, Tustin pre-warped at the block's
        ``wn``, or zero-order hold) and evaluated at ``z = e^{j w dt}``, with the
        measurement's central differences (``(z - 1/z)/(2 dt)`` for a rate, ``(z - 2 +
        1/z)/dt^2`` for an acceleration) in place of ``s`` and ``s^2``. Any difference
        between it and the measured response is nonlinearity.

    Returns
    -------
    ndarray of complex
        Output over input, in the test's gain unit.
    """
    tst = _test(test)
    w = np.asarray(w, dtype=float)
    s = 1j * w
    g = params.gravity
    i = _COMPONENT[tst.excite]
    j = _COMPONENT[tst.output]
    if dt is None:
        d1, d2 = s, s * s

        def resp(block, wn: float) -> np.ndarray:
            num, den = block.transfer_function()
            return np.polyval(num, s) / np.polyval(den, s)

    else:
        z = np.exp(s * dt)
        d1, d2 = (z - 1.0 / z) / (2.0 * dt), (z - 2.0 + 1.0 / z) / (dt * dt)
        method = params.method

        def resp(block, wn: float) -> np.ndarray:
            d = discretise(block, dt, method, prewarp=wn if method == "tustin" else None)
            eye = np.eye(d.phi.shape[0])
            return np.array(
                [d.c @ np.linalg.solve(zk * eye - d.phi, d.gamma0 + zk * d.gamma1) for zk in z]
            )

    def position(axis: int) -> np.ndarray:  # translational channel: acceleration -> position
        wn = params.translational_wn[axis]
        blk = translational_highpass(
            wn, params.translational_zeta[axis], params.translational_wb[axis]
        )
        return resp(blk, wn)

    # the optional input low-pass filters every channel before the rest (a linear factor)
    wn_in = params.input_lowpass_wn
    pre = resp(lowpass2(wn_in, 1.0), wn_in) if wn_in > 0.0 else 1.0
    # surge is tilt-coordinated by pitch (tilt axis 1), sway by roll (0)
    if i < 2 and params.tilt_angle_limit_deg[1 - i] > 0.0:
        low = resp(lowpass2(params.tilt_wn, params.tilt_zeta), params.tilt_wn)
    else:
        low = np.zeros_like(s)  # tilt coordination disabled: the channel renders it all
    if tst.excite in _ROTATIONS:
        wn = params.rotational_wn[i]
        angle = params.angular_velocity_gain[i] * resp(
            rotational_highpass(wn, params.rotational_zeta[i]), wn
        )  # platform angle per aircraft rate
        if tst.direct:
            return pre * angle * d1  # rate -> rate
        rot = angle * s  # angle -> angle (the input rate is the input angle's derivative)
        sign = 1.0 if tst.excite == "pitch" else -1.0
        ht = d2 * position(j)
        return pre * sign * g * rot * ((1.0 - ht) if tilt else -ht)
    k_f = params.specific_force_gain[i]
    if tst.excite == "heave":
        return pre * k_f * d2 * position(2)
    if tst.direct:
        ht = d2 * position(i)
        return pre * k_f * ((low if tilt else 0.0) + (1.0 - low) * ht)
    sign = 1.0 if tst.excite == "surge" else -1.0
    return pre * sign * k_f * low / g


def slowest_decay(params: WashoutParams) -> float:
    """Decay rate of the washout's slowest pole, 1/s (the smallest ``-Re(pole)``)."""
    blocks = [
        translational_highpass(wn, z, wb)
        for wn, z, wb in zip(
            params.translational_wn, params.translational_zeta, params.translational_wb,
            strict=True,
        )
    ]  # fmt: skip
    blocks += [
        rotational_highpass(wn, z)
        for wn, z in zip(params.rotational_wn, params.rotational_zeta, strict=True)
    ]
    blocks.append(lowpass2(params.tilt_wn, params.tilt_zeta))
    if params.input_lowpass_wn > 0.0:
        blocks.append(lowpass2(params.input_lowpass_wn, 1.0))
    return float(min(-np.linalg.eigvals(b.a).real.max() for b in blocks))


#: Transient discarded for a cueing other than the classical washout, s (its own settling
#: is not known here; give ``settle_s`` for a slower one).
DEFAULT_SETTLE_S = 10.0


def settle_time(params: WashoutParams) -> float:
    """Transient to discard, s: ``SETTLE_TIME_CONSTANTS`` time constants of the slowest pole."""
    return SETTLE_TIME_CONSTANTS / slowest_decay(params)


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class TestResult:
    """One test over the frequencies.

    Attributes
    ----------
    test : OmctTest
    frequencies : ndarray, shape (K,)
        rad/s.
    input_amplitude : ndarray, shape (K,)
        Amplitude of the input the gain divides by (``test.input_unit``).
    response : ndarray of complex, shape (K,)
        Measured output over input at each frequency (``test.gain_unit``).
    linear : ndarray of complex, shape (K,), or None
        The classical washout's analytic linear response as the discrete chain realises
        and the OMCT measures it (:func:`classical_response` with ``dt``); None for
        another cueing.
    clamped, limited : ndarray, shape (K,)
        Share of the measured ticks the workspace clamp moved, and the safety stage
        rate-limited or held.
    design : ndarray of complex, shape (K,), or None
        The continuous design's response (:func:`classical_response` without ``dt``).
    """

    __test__ = False  # not a pytest class

    test: OmctTest
    frequencies: np.ndarray
    input_amplitude: np.ndarray
    response: np.ndarray
    linear: np.ndarray | None
    clamped: np.ndarray
    limited: np.ndarray
    design: np.ndarray | None = None

    @property
    def gain(self) -> np.ndarray:
        return np.abs(self.response)

    @property
    def phase_deg(self) -> np.ndarray:
        return _phase_deg(self.response)

    @property
    def linear_gain(self) -> np.ndarray | None:
        return None if self.linear is None else np.abs(self.linear)

    @property
    def linear_phase_deg(self) -> np.ndarray | None:
        return None if self.linear is None else _phase_deg(self.linear)

    def deviates(self, rel: float = 0.05, deg: float = 5.0, atol: float = 1e-6) -> np.ndarray:
        """Where the measured response leaves the linear one (gain by more than ``rel``
        of the linear gain plus ``atol``, in the test's gain unit, or phase by more than
        ``deg`` where the linear gain is not tiny). ``atol`` is far above the chain's
        rounding (about 1e-14 at the default amplitudes, 1e-8 at the smallest ``--scale``)
        and far below a cue anyone feels: a channel whose gain is 0 (``angular_velocity_gain
        = 0``) measures rounding noise, not a limit acting."""
        if self.linear is None:
            return np.zeros(self.frequencies.shape, dtype=bool)
        lin = np.abs(self.linear)
        gain_off = np.abs(self.gain - lin) > rel * lin + atol
        dphase = np.abs((self.phase_deg - self.linear_phase_deg + 180.0) % 360.0 - 180.0)
        visible = (lin > 1e-3 * max(float(lin.max()), 1e-300)) & (lin > atol)
        return gain_off | ((dphase > deg) & visible)

    def to_dict(self) -> dict[str, Any]:
        def opt(x: np.ndarray | None) -> list[float] | None:
            return None if x is None else [float(v) for v in x]

        return {
            "title": self.test.title,
            "excite": self.test.excite,
            "output": self.test.output,
            "gain_unit": self.test.gain_unit,
            "input_unit": self.test.input_unit,
            "frequency_rad_s": opt(self.frequencies),
            "input_amplitude": opt(self.input_amplitude),
            "gain": opt(self.gain),
            "phase_deg": opt(self.phase_deg),
            "linear_gain": opt(self.linear_gain),
            "linear_phase_deg": opt(self.linear_phase_deg),
            "design_gain": opt(None if self.design is None else np.abs(self.design)),
            "design_phase_deg": opt(None if self.design is None else _phase_deg(self.design)),
            "clamped_share": opt(self.clamped),
            "limited_share": opt(self.limited),
        }


def _phase_deg(z: np.ndarray) -> np.ndarray:
    """Phase in degrees, in (-180, 180]."""
    p = np.degrees(np.angle(z))
    return np.where(p <= -180.0, p + 360.0, p)


@dataclass(frozen=True)
class OmctResult:
    """The whole test: per-test results and what produced them.

    Attributes
    ----------
    results : tuple of TestResult
    not_applicable : tuple of str
        Tests the robot cannot show (planar mode: it renders surge, sway and yaw only).
    config : PipelineConfig
    amplitudes : Amplitudes
    settle_s : float
        Transient discarded (at least), s.
    discard_periods, measure_periods : ndarray of int, shape (K,)
        Periods discarded and measured at each frequency.
    cueing : str
        ``"classical"``, or the name of the substituted cueing.
    preview : bool
        The cueing saw each run's whole input first (offline mode, ``omct --preview``).
    cueing_fallbacks : (int, int)
        For a cueing that counts them (an MPC): the ticks of all runs its solver failed on,
        when the pose blended toward its fallback washout, and the ticks it solved for.
    """

    results: tuple[TestResult, ...]
    not_applicable: tuple[str, ...]
    config: PipelineConfig
    amplitudes: Amplitudes
    settle_s: float
    discard_periods: np.ndarray
    measure_periods: np.ndarray
    cueing: str = "classical"
    command: str = field(default="", compare=False)
    preview: bool = False
    cueing_fallbacks: tuple[int, int] = (0, 0)

    def __getitem__(self, name: str) -> TestResult:
        for r in self.results:
            if r.test.name == name:
                return r
        raise KeyError(name)

    @property
    def robot_label(self) -> str:
        name = getattr(self.config.geometry, "name", "")
        kind = ROBOTS[self.config.robot].description
        return f"{name} ({kind})" if name else kind

    def linear_curves(
        self, r: TestResult, n: int = 300
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Dense curves of the linear response for a plot: ``(w, linear, design)``.

        ``w`` spans the test's frequencies and a little more (rad/s); ``linear`` is the
        discrete chain's response, ``design`` the continuous one (complex). None when the
        cueing is not the classical washout.
        """
        if r.linear is None:
            return None
        w = np.logspace(
            np.log10(r.frequencies.min()) - 0.15, np.log10(r.frequencies.max()) + 0.15, n
        )
        tilt = not self.config.planar
        params = self.config.cueing_params
        return (
            w,
            classical_response(params, r.test, w, tilt=tilt, dt=self.config.dt),
            classical_response(params, r.test, w, tilt=tilt),
        )

    def method_text(self) -> str:
        """How the numbers were made, in one paragraph."""
        f = self.results[0].frequencies if self.results else FREQUENCIES
        return (
            f"OMCT of the {self.cueing} cueing"
            f"{' in preview mode (each run seen whole first)' if self.preview else ''} on "
            f"{self.robot_label} at "
            f"{self.config.rate_hz:g} Hz; inputs: {self.amplitudes.describe()}; "
            f"transient discarded: >= {self.settle_s:.1f} s "
            f"({int(self.discard_periods.min())}-{int(self.discard_periods.max())} periods), "
            f"then {int(self.measure_periods.min())}-{int(self.measure_periods.max())} whole "
            f"periods measured; {len(f)} frequencies {f.min():.3g}-{f.max():.3g} rad/s"
        )

    def table_text(self) -> str:
        """Per test: frequency, gain, phase, linear gain and phase, clamped and limited share."""
        lines = [self.method_text(), ""]
        for r in self.results:
            lines.append(f"{r.test.name}: {r.test.title} (gain {r.test.gain_unit})")
            lines.append(
                f"  {'w rad/s':>8} {'gain':>10} {'phase':>8} {'lin gain':>10} {'lin phase':>10}"
                f" {'clamped':>8} {'limited':>8}"
            )
            lin_g, lin_p = r.linear_gain, r.linear_phase_deg
            for k, w in enumerate(r.frequencies):
                lg = f"{lin_g[k]:10.4g}" if lin_g is not None else f"{'-':>10}"
                lp = f"{_fmt_phase(lin_p[k], 1):>10}" if lin_p is not None else f"{'-':>10}"
                lines.append(
                    f"  {w:8.3f} {r.gain[k]:10.4g} {_fmt_phase(r.phase_deg[k], 1):>8} {lg} {lp}"
                    f" {100 * r.clamped[k]:7.1f}% {100 * r.limited[k]:7.1f}%"
                )
            lines.append("")
        if self.not_applicable:
            lines.append(
                "not applicable (the planar robot renders surge, sway and yaw only): "
                + ", ".join(self.not_applicable)
            )
        fallbacks, ticks = self.cueing_fallbacks
        if fallbacks:
            fallback = getattr(self.config.cueing_params, "fallback_name", "its fallback")
            lines.append(
                f"warning: {self.cueing}: the solver failed on {fallbacks} of {ticks} ticks, "
                f"which fell back: there the pose blended toward the fallback washout "
                f"{fallback}, whose response these figures partly are"
            )
        return "\n".join(lines).rstrip("\n")

    def markdown(self) -> str:
        """The compact table for the README: measured gain and phase per frequency and test."""
        head = ["w (rad/s)"] + [
            r.test.name + ("" if r.test.gain_unit == "-" else f" [{r.test.gain_unit}]")
            for r in self.results
        ]
        lines = []
        if self.command:
            lines.append(f"`{self.command}` (motionbase {__version__}):")
            lines.append("")
        lines += [
            "| " + " | ".join(head) + " |",
            "|" + "|".join(["---:"] * len(head)) + "|",
        ]
        marks = [r.deviates() for r in self.results]
        f = self.results[0].frequencies if self.results else np.array([])
        for k, w in enumerate(f):
            cells = [f"{w:.3g}"]
            for r, m in zip(self.results, marks, strict=True):
                phase = _fmt_phase(r.phase_deg[k], 0)
                cells.append(f"{_fmt_gain(r.gain[k])} ∠{phase}{'*' if m[k] else ''}")
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
        note = (
            "Measured gain ∠ phase (deg) of the whole chain (cueing, clamp, inverse kinematics, "
            "safety, forward kinematics); the direct tests are dimensionless."
        )
        if any(r.linear is not None for r in self.results):
            note += (
                " * marks where it differs from the classical washout's linear response by "
                "more than 5 % in gain or 5 deg in phase (a limit acts)."
            )
        lines.append(note)
        if self.not_applicable:
            lines.append(
                "Not applicable to the planar robot (it renders surge, sway and yaw only): "
                + ", ".join(self.not_applicable)
                + "."
            )
        lines.append("")
        lines.append(self.method_text() + ".")
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the JSON file."""
        return {
            "motionbase": __version__,
            "command": self.command,
            "cueing": self.cueing,
            "preview": self.preview,
            "robot": self.config.robot,
            "geometry": getattr(self.config.geometry, "name", ""),
            "rate_hz": self.config.rate_hz,
            "amplitudes": {
                "angle_rad": self.amplitudes.angle,
                "rate_rad_s": self.amplitudes.rate,
                "specific_force_m_s2": self.amplitudes.specific_force,
            },
            "rotational_specific_force": "level flight (0, 0, -g)",
            "reference_point": "platform frame origin (centroid of the platform joints)",
            "settle_s": self.settle_s,
            "discard_periods": [int(v) for v in self.discard_periods],
            "measure_periods": [int(v) for v in self.measure_periods],
            "tests": {r.test.name: r.to_dict() for r in self.results},
            "not_applicable": list(self.not_applicable),
            "cueing_fallbacks": list(self.cueing_fallbacks),
            "pipeline_config": self.config.to_dict(),
        }


def _fmt_phase(p: float, digits: int) -> str:
    """A phase in degrees as printed, in (-180, 180] after rounding: -179.7 is "180" (not
    "-180"), and -0.3 is "0" (not "-0")."""
    v = round(float(p), digits)
    if v <= -180.0:
        v += 360.0
    return f"{v + 0.0:.{digits}f}"  # (+ 0.0: no negative zero)


def _fmt_gain(g: float) -> str:
    if g == 0.0:
        return "0"
    if g >= 100 or g < 1e-3:
        return f"{g:.1e}"
    return f"{g:.3g}"


# --------------------------------------------------------------------------- the run


def run_omct(
    config: PipelineConfig,
    *,
    frequencies: Sequence[float] | np.ndarray = FREQUENCIES,
    amplitudes: Amplitudes | None = None,
    tests: Sequence[str] | None = None,
    cueing: Callable[[], Any] | None = None,
    cueing_name: str = "classical",
    settle_s: float | None = None,
    progress: Callable[[int, int, str, float], None] | None = None,
    command: str = "",
    preview: bool = False,
) -> OmctResult:
    """Run the OMCT through the whole chain.

    Parameters
    ----------
    config : PipelineConfig
        Robot, geometry, washout parameters and rate.
    frequencies : sequence of float
        rad/s; default :data:`FREQUENCIES`.
    amplitudes : Amplitudes, optional
        Default :class:`Amplitudes()`.
    tests : sequence of str, optional
        Test names (default: every test the robot can show). One simulation per
        excited axis serves its direct test and its cross-coupling.
    cueing : callable, optional
        A factory of a cueing object substituted for the classical washout (see
        :func:`simulate`); the analytic response is then not drawn.
    cueing_name : str
        Its name, for the tables.
    settle_s : float, optional
        Transient to discard, s; default :func:`settle_time` of the washout parameters.
    progress : callable, optional
        ``progress(done, total, axis, w)`` after each simulation.
    command : str
        The command line that asked for it (recorded in the tables and the JSON).
    preview : bool
        Offline mode: the cueing sees each run's whole input first (``set_preview``; a
        cueing that can, such as the MPC). A sinusoid is foreseeable, so this is the
        response of the cueing as ``fly --preview`` runs it, not as a live run does.
    """
    freqs = np.asarray(frequencies, dtype=float).reshape(-1)
    if freqs.size == 0 or not (np.isfinite(freqs).all() and (freqs > 0).all()):
        raise ConfigError("OMCT: frequencies must be positive numbers (rad/s)")
    amps = amplitudes if amplitudes is not None else Amplitudes()
    planar = config.planar
    rendered = PLANAR_AXES if planar else AXES
    wanted = [_test(n) for n in tests] if tests is not None else list(TESTS)
    chosen = [t for t in wanted if t.excite in rendered and t.output in rendered]
    skipped = tuple(t.name for t in wanted if t not in chosen)
    if not chosen:
        raise ConfigError("OMCT: none of the tests asked for applies to this robot")
    params = config.cueing_params
    # the classical washout's linear response is drawn beside the measured one
    analytic = cueing is None and config.cueing == "classical"
    if settle_s is not None:
        settle = float(settle_s)
    else:
        settle = settle_time(params) if analytic else DEFAULT_SETTLE_S
    if not (math.isfinite(settle) and settle >= 0.0):
        raise ConfigError(f"OMCT: settle time must be >= 0 s, got {settle_s!r}")
    dt = config.dt
    if freqs.max() * dt > np.pi / MIN_SAMPLES_PER_HALF_PERIOD:
        # the lowest whole rate that passes (rounded up: 20.2 Hz is not "at least 20 Hz")
        need = math.ceil(MIN_SAMPLES_PER_HALF_PERIOD * freqs.max() / np.pi)
        raise ConfigError(
            f"OMCT: a pipeline rate of {config.rate_hz:g} Hz is too low for "
            f"{freqs.max():.4g} rad/s (at least {need} Hz: {2 * MIN_SAMPLES_PER_HALF_PERIOD}"
            " samples per period; raise --rate)"
        )
    g = STANDARD_GRAVITY
    t0 = config.soft_start_s + PRE_ROLL_S
    periods = 2.0 * np.pi / freqs
    discard = np.maximum(1, np.ceil(settle / periods - 1e-9)).astype(int)
    measure = np.maximum(MIN_MEASURE_PERIODS, np.ceil(MIN_MEASURE_S / periods)).astype(int)
    longest = float(np.max(t0 + (discard + measure) * periods))  # s, the longest run
    if longest / dt > MAX_RUN_TICKS:
        why = (
            f"the washout's slowest pole decays at {SETTLE_TIME_CONSTANTS / settle:.3g} 1/s, "
            f"so its transient needs {settle:.3g} s to settle"
            if settle_s is None and analytic
            else f"{settle:.3g} s of transient to discard"
        )
        raise ConfigError(
            f"OMCT: {why}: a run of {longest:.3g} s at {config.rate_hz:g} Hz, "
            f"{longest / dt:.3g} ticks (at most {MAX_RUN_TICKS:.0e}); damp that pole more "
            "(a larger zeta * wn or wb in the washout file) or lower --rate"
        )
    axes = [a for a in AXES if any(t.excite == a for t in chosen)]

    nk = freqs.size
    resp = {t.name: np.zeros(nk, dtype=complex) for t in chosen}
    amp_in = {t.name: np.zeros(nk) for t in chosen}
    clamped = {t.name: np.zeros(nk) for t in chosen}
    limited = {t.name: np.zeros(nk) for t in chosen}
    total = len(axes) * nk
    done = 0
    fallbacks = ticks = 0
    for axis in axes:
        for k, w in enumerate(freqs):
            a = amps.of(axis, float(w))
            lo = int(math.ceil((t0 + discard[k] * periods[k]) / dt))  # first measured tick
            n_win = int(round(measure[k] * periods[k] / dt))
            n = lo + n_win + 1  # one tick more: the central difference at the last one
            t = np.arange(n) * dt
            f_in, w_in, att_in = excitation(axis, float(w), a, t, t0, g)
            sim = simulate(
                config, t, f_in, w_in, att_in, cueing=cueing() if cueing else None, preview=preview
            )
            fallbacks, ticks = fallbacks + sim.fallbacks, ticks + sim.ticks
            win = slice(lo, lo + n_win)
            # the motion one tick either side of the window, for the central differences
            motion = achieved_motion(config, sim.angles[lo - 1 :], sim.poses[lo - 1 :])
            tw = t[win] - t0
            for tst in (x for x in chosen if x.excite == axis):
                i, j = _COMPONENT[tst.excite], _COMPONENT[tst.output]
                if tst.excite in _ROTATIONS:
                    u = (w_in if tst.direct else att_in)[win, i]
                else:
                    u = f_in[win, i]
                if tst.output in _ROTATIONS:
                    y = (motion.angular_velocity if tst.direct else motion.pose[:, 3:])[1:-1, j]
                else:
                    y = motion.specific_force[1:-1, j]
                u_ph = phasor(u, tw, float(w))
                resp[tst.name][k] = phasor(y, tw, float(w)) / u_ph
                amp_in[tst.name][k] = abs(u_ph)
                clamped[tst.name][k] = float(sim.clamped[win].mean())
                limited[tst.name][k] = float(sim.limited[win].mean())
            done += 1
            if progress is not None:
                progress(done, total, axis, float(w))

    results = []
    for tst in chosen:
        lin = design = None
        if analytic:
            lin = classical_response(params, tst, freqs, tilt=not planar, dt=dt)
            design = classical_response(params, tst, freqs, tilt=not planar)
        results.append(
            TestResult(
                test=tst,
                frequencies=freqs.copy(),
                input_amplitude=amp_in[tst.name],
                response=resp[tst.name],
                linear=lin,
                clamped=clamped[tst.name],
                limited=limited[tst.name],
                design=design,
            )
        )
    return OmctResult(
        results=tuple(results),
        not_applicable=skipped,
        config=config,
        amplitudes=amps,
        settle_s=settle,
        discard_periods=discard,
        measure_periods=measure,
        cueing=cueing_name if cueing is not None else config.cueing,
        command=command,
        preview=preview,
        cueing_fallbacks=(fallbacks, ticks),
    )
