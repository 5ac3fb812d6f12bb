"""Vestibular perception models and cueing-quality metrics.

What the pilot would feel in the aircraft is compared with what the pilot feels on
the platform, both through the same models of the vestibular system:

- **Otolith** (Young & Meiry 1968), specific force per axis::

      H_oto(s) = K (tau_a s + 1) / ((tau_L s + 1)(tau_s s + 1)),
      K = 0.4, tau_a = 13.2 s, tau_L = 5.33 s, tau_s = 0.66 s

- **Semicircular canals** (Young & Oman), angular velocity per axis::

      H_scc(s) = tau_L tau_a s^2 / ((tau_L s + 1)(tau_s s + 1)(tau_a s + 1)),
      tau_L = 6.1 s (roll), 5.3 s (pitch), 10.2 s (yaw), tau_s = 0.1 s, tau_a = 30 s

The platform's specific force in cab axes is ``f = R(beta)^T (p'' - (0, 0, g))``:
its translational acceleration plus the gravity component of its tilt (that is how
tilt coordination renders sustained accelerations). Its body rates come from the
Euler angle rates. Derivatives are finite differences at the sample period.

Perception thresholds (for false cues): roll 3.0, pitch 3.6, yaw 2.6 deg/s;
0.17 m/s^2 longitudinal and lateral, 0.28 m/s^2 vertical.

The module does no I/O: :func:`cueing_metrics` takes arrays and returns a frozen
:class:`CueingMetrics`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from motionbase.errors import MotionbaseError
from motionbase.physics import STANDARD_GRAVITY, body_rates_from_euler_rates, rotation_matrix
from motionbase.washout.filters import tustin_tf

__all__ = [
    "CANAL_TAU_L",
    "CueingMetrics",
    "PerceivedMotion",
    "THRESHOLD_ANGULAR_VELOCITY",
    "THRESHOLD_SPECIFIC_FORCE",
    "canal_tf",
    "cueing_metrics",
    "otolith_tf",
    "perceive",
    "perceived_angular_velocity",
    "perceived_motion",
    "perceived_specific_force",
    "platform_angular_velocity",
    "platform_specific_force",
]

OTOLITH_K = 0.4
OTOLITH_TAU_A = 13.2  # s
OTOLITH_TAU_L = 5.33  # s
OTOLITH_TAU_S = 0.66  # s
CANAL_TAU_L = (6.1, 5.3, 10.2)  # s, roll, pitch, yaw
CANAL_TAU_S = 0.1  # s
CANAL_TAU_A = 30.0  # s

THRESHOLD_SPECIFIC_FORCE = np.array([0.17, 0.17, 0.28])  # m/s^2, x, y, z
THRESHOLD_ANGULAR_VELOCITY = np.deg2rad([3.0, 3.6, 2.6])  # rad/s, roll, pitch, yaw

# Single-axis reach of the ceart platform (DESIGN.md, "Geometry defaults"), base axes FRD:
# lower and upper bounds of [x, y, z, roll, pitch, yaw] (surge 0.30 m back, 0.36 m forward;
# heave 0.20 m up, 0.12 m down; pitch 17.6 deg nose down, 30.3 deg nose up).
CEART_REACH = np.array(
    [
        [-0.30, -0.31, -0.20, -np.radians(19.0), -np.radians(17.6), -np.radians(48.9)],
        [0.36, 0.31, 0.12, np.radians(19.0), np.radians(30.3), np.radians(48.9)],
    ]
)


class PerceptionInputError(MotionbaseError, ValueError):
    """Arrays given to the perception functions have wrong shapes or non-finite values."""


# --- models --------------------------------------------------------------------------------


def otolith_tf(
    k: float = OTOLITH_K,
    tau_a: float = OTOLITH_TAU_A,
    tau_l: float = OTOLITH_TAU_L,
    tau_s: float = OTOLITH_TAU_S,
) -> tuple[np.ndarray, np.ndarray]:
    """Otolith transfer function ``K (tau_a s + 1)/((tau_L s + 1)(tau_s s + 1))``.

    Returns
    -------
    num, den : ndarray
        Polynomials in descending powers of s; input specific force (m/s^2), output
        afferent response (DC gain ``K``).
    """
    return k * np.array([tau_a, 1.0]), np.polymul([tau_l, 1.0], [tau_s, 1.0])


def canal_tf(
    tau_l: float, tau_s: float = CANAL_TAU_S, tau_a: float = CANAL_TAU_A
) -> tuple[np.ndarray, np.ndarray]:
    """Semicircular canal transfer function ``tau_L tau_a s^2/((tau_L s+1)(tau_s s+1)(tau_a s+1))``.

    Parameters
    ----------
    tau_l : float
        Long time constant, s (6.1 roll, 5.3 pitch, 10.2 yaw: ``CANAL_TAU_L``).
    tau_s, tau_a : float
        Short and adaptation time constants, s.

    Returns
    -------
    num, den : ndarray
        Input angular velocity (rad/s), output perceived angular velocity (unit gain
        in the mid band, zero at DC).
    """
    den = np.polymul(np.polymul([tau_l, 1.0], [tau_s, 1.0]), [tau_a, 1.0])
    return np.array([tau_l * tau_a, 0.0, 0.0]), den


def perceive(
    num: np.ndarray, den: np.ndarray, u: np.ndarray, dt: float, initial: str = "steady"
) -> np.ndarray:
    """Apply a continuous model to a signal (bilinear transform, then ``lfilter``).

    Parameters
    ----------
    num, den : array_like
        Continuous transfer function.
    u : ndarray, shape (N,)
        Input samples at period ``dt``.
    dt : float
        Sample period, s.
    initial : {"steady", "rest"}
        ``"steady"``: the model starts adapted to the first sample (as if it had
        lasted forever); ``"rest"``: all states zero before the first sample.
    """
    import scipy.signal  # here: about a second to import, and a run never needs it

    b, a, zi_unit = _discrete_model(
        tuple(float(c) for c in np.ravel(num)), tuple(float(c) for c in np.ravel(den)), float(dt)
    )
    u = np.asarray(u, dtype=float)
    if initial == "rest":
        return scipy.signal.lfilter(b, a, u)
    if initial != "steady":
        raise PerceptionInputError(f"initial must be 'steady' or 'rest', got {initial!r}")
    zi = zi_unit * (u[0] if u.size else 0.0)
    return scipy.signal.lfilter(b, a, u, zi=zi)[0]


@functools.lru_cache(maxsize=64)
def _discrete_model(
    num: tuple[float, ...], den: tuple[float, ...], dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(b, a)`` of :func:`perceive`'s model and its steady state for a unit input
    (``lfilter_zi``), read-only. The design is kept: a tuning scores thousands of parameter
    sets through the same few models at the same rate, and designing them took half of
    each evaluation."""
    import scipy.signal

    b, a = tustin_tf(np.array(num), np.array(den), dt)
    zi = scipy.signal.lfilter_zi(b, a)
    for x in (b, a, zi):
        x.setflags(write=False)
    return b, a, zi


def perceived_specific_force(
    f: np.ndarray,
    dt: float,
    *,
    normalized: bool = False,
    initial: str = "steady",
    g: float = STANDARD_GRAVITY,
) -> np.ndarray:
    """Otolith response to a specific force history, per axis.

    Parameters
    ----------
    f : ndarray, shape (N, 3)
        Specific force, m/s^2, head (cab/body) axes FRD.
    dt : float
        Sample period, s.
    normalized : bool
        Divide by the otolith's DC gain ``K`` so that a sustained force reads at its
        true value (m/s^2); the metrics use this.
    initial : {"steady", "rest"}
        See :func:`perceive`.
    g : float
        Gravity, m/s^2; the level-flight force ``(0, 0, -g)`` is removed first, so the
        output is the perceived *deviation* from 1 g.
    """
    f = _check(f, "specific force", 3)
    dev = f - np.array([0.0, 0.0, -g])
    num, den = otolith_tf()
    out = np.column_stack([perceive(num, den, dev[:, i], dt, initial) for i in range(3)])
    return out / OTOLITH_K if normalized else out


def perceived_angular_velocity(w: np.ndarray, dt: float, *, initial: str = "steady") -> np.ndarray:
    """Canal response to a body-rate history, per axis (roll, pitch, yaw).

    Parameters
    ----------
    w : ndarray, shape (N, 3)
        Angular velocity (p, q, r), rad/s, head axes FRD.
    dt : float
        Sample period, s.
    initial : {"steady", "rest"}
        See :func:`perceive`.
    """
    w = _check(w, "angular velocity", 3)
    cols = []
    for i in range(3):
        num, den = canal_tf(CANAL_TAU_L[i])
        cols.append(perceive(num, den, w[:, i], dt, initial))
    return np.column_stack(cols)


# --- platform motion in cab axes -----------------------------------------------------------


def _second_difference(x: np.ndarray, dt: float) -> np.ndarray:
    acc = np.zeros_like(x)
    if x.shape[0] >= 3:
        acc[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / (dt * dt)
        acc[0] = acc[1]
        acc[-1] = acc[-2]
    return acc


def platform_specific_force(pose: np.ndarray, dt: float, g: float = STANDARD_GRAVITY) -> np.ndarray:
    """Specific force felt in the cab, ``R(beta)^T (p'' - (0, 0, g))``.

    Parameters
    ----------
    pose : ndarray, shape (N, 6)
        Platform poses ``[x, y, z, roll, pitch, yaw]`` (m, rad), base axes FRD.
    dt : float
        Sample period, s (accelerations by central second differences).
    g : float
        Gravity, m/s^2.

    Returns
    -------
    ndarray, shape (N, 3)
        m/s^2 in cab axes FRD; ``(0, 0, -g)`` at rest level.
    """
    pose = _check(pose, "platform pose", 6)
    acc = _second_difference(pose[:, :3], dt) - np.array([0.0, 0.0, g])
    return np.einsum("nji,nj->ni", rotation_matrix(pose[:, 3:]), acc)


def platform_angular_velocity(pose: np.ndarray, dt: float) -> np.ndarray:
    """Body rates (p, q, r) of the cab from its Euler angles (Z-Y-X), rad/s, shape (N, 3)."""
    pose = _check(pose, "platform pose", 6)
    ang = pose[:, 3:]
    if ang.shape[0] < 2:
        return np.zeros((ang.shape[0], 3))
    rate = np.gradient(ang, dt, axis=0)
    return np.column_stack(
        body_rates_from_euler_rates(ang[:, 0], ang[:, 1], rate[:, 0], rate[:, 1], rate[:, 2])
    )


# --- metrics -------------------------------------------------------------------------------


@dataclass(frozen=True)
class PerceivedMotion:
    """Perceived signals (normalized otolith in m/s^2, canals in rad/s), each (N, 3).

    Specific forces are deviations from level flight (1 g removed).
    """

    aircraft_specific_force: np.ndarray
    aircraft_angular_velocity: np.ndarray
    platform_specific_force: np.ndarray
    platform_angular_velocity: np.ndarray


def perceived_motion(
    aircraft_f: np.ndarray,
    aircraft_w: np.ndarray,
    platform_pose: np.ndarray,
    dt: float,
    g: float = STANDARD_GRAVITY,
) -> PerceivedMotion:
    """What the pilot feels in the aircraft and on the platform (see the module docstring).

    Parameters
    ----------
    aircraft_f : ndarray, shape (N, 3)
        Aircraft specific force at the pilot, m/s^2, body axes FRD.
    aircraft_w : ndarray, shape (N, 3)
        Aircraft body rates, rad/s.
    platform_pose : ndarray, shape (N, 6)
        Platform poses actually sent (after clamping), m and rad, base axes FRD.
    dt : float
        Sample period, s.
    g : float
        Gravity, m/s^2.
    """
    dt = _check_dt(dt)
    af = _check(aircraft_f, "aircraft specific force", 3)
    aw = _check(aircraft_w, "aircraft angular velocity", 3)
    pp = _check(platform_pose, "platform pose", 6)
    if not af.shape[0] == aw.shape[0] == pp.shape[0]:
        raise PerceptionInputError(
            f"perception: arrays must have the same length, got {af.shape[0]}, {aw.shape[0]} "
            f"and {pp.shape[0]} samples"
        )
    pf = platform_specific_force(pp, dt, g)
    pw = platform_angular_velocity(pp, dt)
    return PerceivedMotion(
        perceived_specific_force(af, dt, normalized=True, g=g),
        perceived_angular_velocity(aw, dt),
        perceived_specific_force(pf, dt, normalized=True, g=g),
        perceived_angular_velocity(pw, dt),
    )


@dataclass(frozen=True)
class CueingMetrics:
    """How well the platform's motion reproduces the aircraft's, as perceived.

    Attributes
    ----------
    duration : float
        s.
    rmse_specific_force : ndarray, shape (3,)
        RMS of perceived platform minus perceived aircraft specific force, m/s^2, x y z.
    rmse_angular_velocity : ndarray, shape (3,)
        Same for angular velocity, rad/s, roll pitch yaw.
    correlation_specific_force, correlation_angular_velocity : ndarray, shape (3,)
        Pearson correlation of the perceived signals (shape agreement, 1 is best;
        NaN where either signal is constant).
    false_cue_specific_force, false_cue_angular_velocity : ndarray, shape (3,)
        Share of the time (0..1) with a false cue: the platform's perceived cue is above
        the perception threshold and either points the other way than the aircraft's
        or the aircraft's is below threshold (a cue the aircraft does not give). A
        scaled-down or stronger cue in the right direction is not false.
    workspace_usage : ndarray, shape (6,)
        Largest excursion per axis as a share of the reach in that direction.
    """

    duration: float
    rmse_specific_force: np.ndarray
    rmse_angular_velocity: np.ndarray
    correlation_specific_force: np.ndarray
    correlation_angular_velocity: np.ndarray
    false_cue_specific_force: np.ndarray
    false_cue_angular_velocity: np.ndarray
    workspace_usage: np.ndarray

    def to_dict(self) -> dict[str, object]:
        """Plain mapping (lists of floats), e.g. for a JSON report."""
        return {
            k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()
        }

    def summary(self) -> str:
        """A short text table."""

        def row(label: str, values: np.ndarray, fmt: str) -> str:
            cells = ["n/a" if not np.isfinite(v) else format(v, fmt) for v in values]
            return f"  {label:<34s}" + "".join(f"{c:>10s}" for c in cells)

        lines = [
            f"cueing metrics over {self.duration:.1f} s (perceived: otolith, semicircular canals)",
            f"  {'':<34s}{'x':>10s}{'y':>10s}{'z':>10s}",
            row("specific force RMSE [m/s^2]", self.rmse_specific_force, ".3f"),
            row("specific force correlation", self.correlation_specific_force, ".2f"),
            row("specific force false cues [%]", 100 * self.false_cue_specific_force, ".1f"),
            f"  {'':<34s}{'roll':>10s}{'pitch':>10s}{'yaw':>10s}",
            row("angular vel. RMSE [deg/s]", np.degrees(self.rmse_angular_velocity), ".2f"),
            row("angular vel. correlation", self.correlation_angular_velocity, ".2f"),
            row("angular vel. false cues [%]", 100 * self.false_cue_angular_velocity, ".1f"),
            f"  {'':<34s}" + "".join(f"{a:>8s}" for a in ("x", "y", "z", "roll", "pitch", "yaw")),
            "  "
            + f"{'workspace usage [%]':<34s}"
            + "".join(f"{100 * u:>8.0f}" for u in self.workspace_usage),
        ]
        return "\n".join(lines)


def cueing_metrics(
    t: np.ndarray,
    aircraft_f: np.ndarray,
    aircraft_w: np.ndarray,
    platform_pose: np.ndarray,
    dt: float,
    *,
    reach: np.ndarray | None = None,
    g: float = STANDARD_GRAVITY,
) -> CueingMetrics:
    """Compare the aircraft's motion with the platform's, as the pilot perceives them.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times, s (used for the duration).
    aircraft_f : ndarray, shape (N, 3)
        Aircraft specific force at the pilot, m/s^2, body axes FRD.
    aircraft_w : ndarray, shape (N, 3)
        Aircraft body rates, rad/s.
    platform_pose : ndarray, shape (N, 6)
        Poses actually sent to the platform, m and rad, base axes FRD.
    dt : float
        Sample period, s (uniform sampling).
    reach : ndarray, shape (2, 6), optional
        Lower and upper single-axis reach; default the ceart figures of DESIGN.md
        (``CEART_REACH``).
    g : float
        Gravity, m/s^2.

    Returns
    -------
    CueingMetrics
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    pm = perceived_motion(aircraft_f, aircraft_w, platform_pose, dt, g)
    n = pm.aircraft_specific_force.shape[0]
    if t.shape[0] != n:
        raise PerceptionInputError(f"perception: t has {t.shape[0]} samples, the arrays {n}")
    if n == 0:
        raise PerceptionInputError("perception: no samples")
    reach = CEART_REACH if reach is None else np.asarray(reach, dtype=float)
    if reach.shape != (2, 6) or not (reach[0] < 0).all() or not (reach[1] > 0).all():
        raise PerceptionInputError(
            "perception: reach must be (2, 6) lower (< 0) and upper (> 0) bounds"
        )
    pose = np.asarray(platform_pose, dtype=float)
    usage = np.maximum(pose.max(axis=0) / reach[1], pose.min(axis=0) / reach[0])
    usage = np.maximum(usage, 0.0)

    def rmse(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.sqrt(np.mean((a - b) ** 2, axis=0))

    def corr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        out = np.full(3, np.nan)
        for i in range(3):
            da, db = a[:, i] - a[:, i].mean(), b[:, i] - b[:, i].mean()
            na, nb = np.sqrt(da @ da), np.sqrt(db @ db)
            if na > 1e-12 and nb > 1e-12:
                out[i] = float(da @ db / (na * nb))
        return out

    def false_cue(air: np.ndarray, plat: np.ndarray, thr: np.ndarray) -> np.ndarray:
        felt = np.abs(plat) > thr
        bad = felt & ((np.abs(air) <= thr) | (np.sign(plat) != np.sign(air)))
        return bad.mean(axis=0)

    return CueingMetrics(
        duration=float(t[-1] - t[0]) + dt if n > 1 else dt,
        rmse_specific_force=rmse(pm.platform_specific_force, pm.aircraft_specific_force),
        rmse_angular_velocity=rmse(pm.platform_angular_velocity, pm.aircraft_angular_velocity),
        correlation_specific_force=corr(pm.platform_specific_force, pm.aircraft_specific_force),
        correlation_angular_velocity=corr(
            pm.platform_angular_velocity, pm.aircraft_angular_velocity
        ),
        false_cue_specific_force=false_cue(
            pm.aircraft_specific_force, pm.platform_specific_force, THRESHOLD_SPECIFIC_FORCE
        ),
        false_cue_angular_velocity=false_cue(
            pm.aircraft_angular_velocity, pm.platform_angular_velocity, THRESHOLD_ANGULAR_VELOCITY
        ),
        workspace_usage=usage,
    )


def _check_dt(dt: float) -> float:
    try:
        v = float(dt)
    except (TypeError, ValueError):
        raise PerceptionInputError(
            f"perception: dt must be a number of seconds, got {dt!r}"
        ) from None
    if not (np.isfinite(v) and v > 0):
        raise PerceptionInputError(f"perception: dt must be > 0 s and finite, got {dt!r}")
    return v


def _check(x: np.ndarray, name: str, width: int) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != width:
        raise PerceptionInputError(
            f"perception: {name} must have shape (N, {width}), got {arr.shape}"
        )
    if not np.isfinite(arr).all():
        raise PerceptionInputError(f"perception: {name} has non-finite values")
    return arr
