"""The classical washout filter (Reid & Nahon 1985), streaming and batch.

Structure (DESIGN.md, "The pipeline", step 2; Reid, L. D. & Nahon, M. A., "Flight
simulation motion-base drive algorithms: part 1", UTIAS Report 296, 1985):

0. **Input low-pass** (optional, ``[input] lowpass_wn`` > 0): a critically damped
   second-order low-pass ``wn^2/(s^2 + 2 wn s + wn^2)`` on each input channel (the
   specific force's deviation from level flight, and the body rates), for sources that
   hold a sample between sparse messages (MAVLink telemetry at a few Hz): it turns the
   held staircase's steps, which the high-passes below would pass on as steps of the
   platform's acceleration and, in the rotational channel, of its angular velocity
   (an angular acceleration spike the crank limiter then cuts), into smooth ramps, at the
   price of a lag of ``2/wn`` s. Level flight at rest passes unchanged.
1. **Scale and limit**, per axis::

       f_s = f_0 + K_f sat(f - f_0),   f_0 = (0, 0, -g)      (level flight)
       w_s = K_w sat(w)

   The gain acts on the deviation from level flight so that the 1 g an occupant
   feels at rest is never scaled down (scaling it would start every run with a
   heave transient): level unaccelerated flight maps to exactly the neutral pose.
2. **Tilt coordination** (low frequency specific force rendered by gravity)::

       f_l = wn_l^2/(s^2 + 2 zeta_l wn_l s + wn_l^2) f_s      (x, y only)
       pitch_t = asin(f_lx / g),  roll_t = -asin(f_ly / (g cos pitch_t))

   then each is angle-limited and followed by a tracker that limits the tilt rate
   (``|d tilt/dt| <= tilt_rate_limit``, below the semicircular canals' threshold)
   *and* the tilt acceleration (``|d^2 tilt/dt^2| <= tilt_accel_limit``), so the tilt
   rate never steps (see "Tilt tracker" below). Roll and pitch each have their own angle,
   rate and acceleration limits. A cab at rest tilted by (roll, pitch)
   feels ``f = (g sin pitch, -g sin roll cos pitch, -g cos roll cos pitch)``, so a
   sustained forward ``f_x > 0`` pitches the nose up and a sustained ``f_y > 0`` rolls
   left wing down (negative roll). The tilt is never high-passed.
3. **Rotational channel**: Euler rates ``beta_dot = T_s(beta) w_s`` (Z-Y-X), a
   second-order high-pass ``s^2/(s^2 + 2 zeta wn s + wn^2)`` and an integration,
   per axis; the tilt is added: ``beta = beta_hp + (roll_t, pitch_t, 0)``.
4. **Translational channel**: ``a = L_IS(beta) f_s + (0, 0, g)`` in base axes (FRD),
   third-order high-pass ``s^2/(s^2 + 2 zeta wn s + wn^2) * s/(s + wb)`` and double
   integration to position, per axis, so that a sustained acceleration returns the
   platform to neutral.
5. **Cue limiter** (optional, per axis, ``translational.accel_limit`` and
   ``velocity_limit`` > 0): the translational cue follows the high-pass position within
   those limits (below, "Cue limiter").

The output pose is ``[x, y, z, roll, pitch, yaw]`` (m, rad) in base axes FRD.
``T_s`` uses the attitude of the previous output (the attitude actually sent, after
:meth:`ClassicalWashout.track`), ``L_IS`` the attitude of this sample.

Discretisation and state
------------------------
Each linear block is realised in physical states (position, velocity, integral of
position, see :mod:`motionbase.washout.filters`) and discretised by the pre-warped
Tustin rule (default) or exact zero-order hold. The whole state is one float
vector, inspectable as a :class:`WashoutState`. ``step`` and ``run`` call the same
compiled kernel (numba, compiled on first use and cached on disk), so they give
bit-identical numbers.

Tilt tracker
------------
Per tilt axis, each sample (angles in rad, ``u = tilt_accel_limit * dt``), the one-tick
tracker of the safety limiter (:func:`motionbase.physics.track_toward`) with a glide:

- the target is the angle-limited tilt ``clip(tilt_t, -lim, lim)``; its own rate,
  limited to the rate limit, is fed forward so a slow target is followed without lag;
- the error left after the feed-forward is closed no faster than the *glide speed*
  of the remaining distance ``d``: the lower of the speed from which the tilt can
  still stop in time braking by ``u`` per tick (the braking curve of the safety
  stage) and ``d a/v_max`` (plus a tenth of ``u``, so that it lands in finite time).
  Along the glide the deceleration is proportional to the speed, with the time
  constant ``v_max/a`` (0.375 s for 3 deg/s and 8 deg/s^2): equal to ``a`` at the rate
  limit and easing off toward the stop, so it lands on a fixed target without
  overshoot and without a kink in the rate;
- the tilt never approaches ``+-lim`` faster than the glide speed of its distance to
  it: it decelerates on the way to the angle limit instead of halting there in one
  tick (the old limiter's rate step, a felt rotational jerk that the crank limiter
  then had to absorb);
- the rate changes by at most ``u`` per tick and stays within the rate limit; when all
  the limits allow the whole step, the tilt lands exactly on the target (bit-exact
  hold of a constant target or of the angle limit).

Cue limiter
-----------
Per translational axis whose ``accel_limit`` (``a``, m/s^2) or ``velocity_limit``
(``v_max``, m/s) is set, the cue position follows the high-pass position with the tilt
tracker's rules (above) and no angle limit: the target's own velocity fed forward, the
rest closed no faster than the glide speed ``min(braking curve, dist a/v_max + u/10)``
(the braking curve alone without a velocity limit; no braking without an acceleration
limit, only the velocity clip), then ``|v - v_prev| <= a dt`` and ``|v| <= v_max``. The
cue's velocity and acceleration (finite differences of the pose) never exceed the limits,
and it lands on a settled target without overshoot. An axis without limits is untouched
(its numbers are those of the filter alone, bit for bit). The channel's washout still
brings the cue back to neutral: the limiter only slows it.

Anti-windup (back-calculation)
------------------------------
When the platform cannot reach the commanded pose, the pipeline clamps it and calls
:meth:`ClassicalWashout.track` with the pose actually sent. ``track`` writes that
pose back into the states that produced it, so the next samples continue from where
the platform really is:

- translation, per axis: the position state is set to the achieved position, and
  the velocity state is zeroed if it points in the direction the clamp cut (it
  would only push further into the limit); the cue limiter's position is set the same way,
  and its velocity zeroed likewise. The integral-of-position state keeps
  integrating the *achieved* position. The realisation has no free integrator, so
  whatever the states hold, they decay back to neutral with the filter's own
  poles: the pose can neither stick at the limit nor pump past neutral.
- rotation, roll and pitch: when the clamp scaled the angle toward neutral
  (``achieved = s * commanded``, ``0 <= s <= 1``), the tilt angle, its rate and
  the high-pass angle are all scaled by ``s``; the tilt tracker then brings the
  tilt back within its rate and acceleration limits. Otherwise (and for yaw) the difference goes
  to the high-pass angle state.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from motionbase.errors import ConfigError, CueingInputError
from motionbase.physics import rotation_terms, track_toward
from motionbase.washout.cueing import STEP_SIGNATURE, TRACK_SIGNATURE, Cueing
from motionbase.washout.filters import (
    discretise,
    lowpass2,
    rotational_highpass,
    translational_highpass,
)
from motionbase.washout.params import WashoutParams

__all__ = ["ClassicalWashout", "WashoutInputError", "WashoutState"]


class WashoutInputError(CueingInputError):
    """An input sample of the washout is malformed (wrong shape, NaN or infinite)."""


# --- packed layouts (compile-time constants for the kernels) -------------------------------

# coefficients
_TPHI, _TG0, _TG1 = 0, 27, 36  # translational: 3 axes x (3x3), 3 x 3, 3 x 3
_RPHI, _RG0, _RG1 = 45, 57, 63  # rotational: 3 axes x (2x2), 3 x 2, 3 x 2
_LPHI, _LG0, _LG1 = 69, 77, 81  # tilt low-pass: 2 axes x (2x2), 2 x 2, 2 x 2
_KF, _FLIM, _KW, _WLIM = 85, 88, 91, 94
_G, _DT = 97, 98
# tilt tracker per tilt axis (roll, pitch): rate limit, angle limit, rate change per tick,
# 1/tau of the glide
_TVMAX, _TLIM, _TU, _TK = 99, 101, 103, 105
_PON, _PPHI, _PG0, _PG1 = 107, 108, 112, 114  # input low-pass: on flag, (2x2), 2, 2
# cue limiter per axis: on flag, velocity limit (inf: off), velocity change per tick (inf:
# off), 1/tau of the glide (0 without a velocity limit)
_XON, _XV, _XU, _XK = 116, 119, 122, 125
_NC = 128

# state
_QT, _UT = 0, 9  # translational states (axis*3 + [integral, position, velocity]), inputs
_QL, _UL = 12, 16  # tilt low-pass states (axis*2 + [output, rate]), inputs
_TILT = 18  # tilt angles (roll, pitch)
_QR, _UR = 20, 26  # rotational states (axis*2 + [integral, angle]), inputs
_POSE = 29  # last pose sent (6)
_TRATE = 35  # tilt rates (roll, pitch)
_TTGT = 37  # last angle-limited tilt targets (roll, pitch)
_QP, _UP = 39, 51  # input low-pass states (channel*2 + [output, rate]), inputs (6 channels)
_XS = 57  # cue limiter states (axis*3 + [position, velocity, last target])
_NS = 66

_COS_MIN = 1e-3  # guard of 1/cos(pitch) in T_s (pitch within 0.06 deg of +-90 deg)


@numba.njit(cache=True, inline="always")
def _clip(x: float, lo: float, hi: float) -> float:
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@numba.njit(cache=True, inline="always")
def _tilt_track(cf, st, i, tgt):  # pragma: no cover - compiled
    """Tilt axis ``i`` one tick toward ``tgt`` (within +-lim); returns the new tilt.

    Rate, acceleration and angle limits with the glide (:func:`motionbase.physics.track_toward`;
    module docstring, "Tilt tracker").
    """
    dt, lim = cf[_DT], cf[_TLIM + i]
    q0 = st[_TILT + i]
    q = track_toward(
        q0, st[_TRATE + i], st[_TTGT + i], tgt, dt, -lim, lim, cf[_TVMAX + i], cf[_TU + i],
        cf[_TK + i],
    )[0]  # fmt: skip
    st[_TRATE + i] = (q - q0) / dt
    st[_TTGT + i] = tgt
    st[_TILT + i] = q
    return q


@numba.njit(cache=True, inline="always")
def _cue_track(cf, st, i, tgt):  # pragma: no cover - compiled
    """Translational cue axis ``i`` one tick toward the high-pass position ``tgt`` (m),
    within its acceleration and velocity limits (0: that limit off); returns the new
    position. The tilt tracker's rules without an angle limit ("Cue limiter")."""
    dt = cf[_DT]
    j = _XS + 3 * i
    q0 = st[j]
    q = track_toward(
        q0, st[j + 1], st[j + 2], tgt, dt, -np.inf, np.inf, cf[_XV + i], cf[_XU + i], cf[_XK + i]
    )[0]  # fmt: skip
    st[j + 1] = (q - q0) / dt
    st[j + 2] = tgt
    st[j] = q
    return q


@numba.njit(cache=True, inline="always")
def _prefilter(cf, st, i, u):  # pragma: no cover - compiled
    """Input low-pass of channel ``i`` (0-2: f - (0, 0, -g), 3-5: rates); returns its output."""
    q0 = st[_QP + 2 * i]
    q1 = st[_QP + 2 * i + 1]
    up = st[_UP + i]
    n0 = cf[_PPHI] * q0 + cf[_PPHI + 1] * q1 + cf[_PG0] * up + cf[_PG1] * u
    n1 = cf[_PPHI + 2] * q0 + cf[_PPHI + 3] * q1 + cf[_PG0 + 1] * up + cf[_PG1 + 1] * u
    st[_QP + 2 * i] = n0
    st[_QP + 2 * i + 1] = n1
    st[_UP + i] = u
    return n0


@numba.njit(cache=True, inline="always")
def _step_kernel(cf, st, fx, fy, fz, wx, wy, wz, out):  # pragma: no cover - compiled
    g = cf[_G]
    # 0. input low-pass (on the deviation from level flight, so rest stays rest)
    if cf[_PON] != 0.0:
        fx = _prefilter(cf, st, 0, fx)
        fy = _prefilter(cf, st, 1, fy)
        fz = _prefilter(cf, st, 2, fz + g) - g
        wx = _prefilter(cf, st, 3, wx)
        wy = _prefilter(cf, st, 4, wy)
        wz = _prefilter(cf, st, 5, wz)
    # 1. scale and limit (deviation from level flight for f)
    fs0 = cf[_KF + 0] * _clip(fx, -cf[_FLIM + 0], cf[_FLIM + 0])
    fs1 = cf[_KF + 1] * _clip(fy, -cf[_FLIM + 1], cf[_FLIM + 1])
    fs2 = cf[_KF + 2] * _clip(fz + g, -cf[_FLIM + 2], cf[_FLIM + 2]) - g
    w0 = cf[_KW + 0] * _clip(wx, -cf[_WLIM + 0], cf[_WLIM + 0])
    w1 = cf[_KW + 1] * _clip(wy, -cf[_WLIM + 1], cf[_WLIM + 1])
    w2 = cf[_KW + 2] * _clip(wz, -cf[_WLIM + 2], cf[_WLIM + 2])

    # 2. tilt coordination: low-pass of f_s x and y
    fl0 = 0.0
    fl1 = 0.0
    for i in range(2):
        u = fs0 if i == 0 else fs1
        up = st[_UL + i]
        q0 = st[_QL + 2 * i]
        q1 = st[_QL + 2 * i + 1]
        p = _LPHI + 4 * i
        n0 = cf[p] * q0 + cf[p + 1] * q1 + cf[_LG0 + 2 * i] * up + cf[_LG1 + 2 * i] * u
        n1 = cf[p + 2] * q0 + cf[p + 3] * q1 + cf[_LG0 + 2 * i + 1] * up + cf[_LG1 + 2 * i + 1] * u
        st[_QL + 2 * i] = n0
        st[_QL + 2 * i + 1] = n1
        st[_UL + i] = u
        if i == 0:
            fl0 = n0
        else:
            fl1 = n0
    pitch_t = np.arcsin(_clip(fl0 / g, -1.0, 1.0))
    cpt = max(np.cos(pitch_t), _COS_MIN)
    roll_t = -np.arcsin(_clip(fl1 / (g * cpt), -1.0, 1.0))
    tr = _tilt_track(cf, st, 0, _clip(roll_t, -cf[_TLIM], cf[_TLIM]))
    tp = _tilt_track(cf, st, 1, _clip(pitch_t, -cf[_TLIM + 1], cf[_TLIM + 1]))

    # 3. rotational channel: Euler rates at the previous attitude, high-pass, integrate
    ph = st[_POSE + 3]
    th = st[_POSE + 4]
    sph = np.sin(ph)
    cph = np.cos(ph)
    cth = np.cos(th)
    if abs(cth) < _COS_MIN:
        cth = _COS_MIN if cth >= 0.0 else -_COS_MIN
    tth = np.sin(th) / cth
    qs = w1 * sph + w2 * cph
    r0 = w0 + qs * tth
    r1 = w1 * cph - w2 * sph
    r2 = qs / cth
    b0 = 0.0
    b1 = 0.0
    b2 = 0.0
    for i in range(3):
        u = r0 if i == 0 else (r1 if i == 1 else r2)
        up = st[_UR + i]
        q0 = st[_QR + 2 * i]
        q1 = st[_QR + 2 * i + 1]
        p = _RPHI + 4 * i
        n0 = cf[p] * q0 + cf[p + 1] * q1 + cf[_RG0 + 2 * i] * up + cf[_RG1 + 2 * i] * u
        n1 = cf[p + 2] * q0 + cf[p + 3] * q1 + cf[_RG0 + 2 * i + 1] * up + cf[_RG1 + 2 * i + 1] * u
        st[_QR + 2 * i] = n0
        st[_QR + 2 * i + 1] = n1
        st[_UR + i] = u
        if i == 0:
            b0 = n1
        elif i == 1:
            b1 = n1
        else:
            b2 = n1
    roll = b0 + tr
    pitch = b1 + tp
    yaw = b2

    # 4. translational channel: a = L_IS(beta) f_s + (0, 0, g), high-pass, double integration
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation_terms(roll, pitch, yaw)
    a0 = r00 * fs0 + r01 * fs1 + r02 * fs2
    a1 = r10 * fs0 + r11 * fs1 + r12 * fs2
    a2 = r20 * fs0 + r21 * fs1 + r22 * fs2 + g
    for i in range(3):
        u = a0 if i == 0 else (a1 if i == 1 else a2)
        up = st[_UT + i]
        q0 = st[_QT + 3 * i]
        q1 = st[_QT + 3 * i + 1]
        q2 = st[_QT + 3 * i + 2]
        p = _TPHI + 9 * i
        ga = _TG0 + 3 * i
        gb = _TG1 + 3 * i
        n0 = cf[p] * q0 + cf[p + 1] * q1 + cf[p + 2] * q2 + cf[ga] * up + cf[gb] * u
        n1 = cf[p + 3] * q0 + cf[p + 4] * q1 + cf[p + 5] * q2 + cf[ga + 1] * up + cf[gb + 1] * u
        n2 = cf[p + 6] * q0 + cf[p + 7] * q1 + cf[p + 8] * q2 + cf[ga + 2] * up + cf[gb + 2] * u
        st[_QT + 3 * i] = n0
        st[_QT + 3 * i + 1] = n1
        st[_QT + 3 * i + 2] = n2
        st[_UT + i] = u
        out[i] = n1 if cf[_XON + i] == 0.0 else _cue_track(cf, st, i, n1)
    out[3] = roll
    out[4] = pitch
    out[5] = yaw
    for i in range(6):
        st[_POSE + i] = out[i]


@numba.njit(STEP_SIGNATURE, cache=True)
def _step(cf, st, u, out):  # pragma: no cover - compiled
    """One sample; returns False (and touches nothing) on a non-finite input."""
    for i in range(6):
        if not np.isfinite(u[i]):
            return False
    _step_kernel(cf, st, u[0], u[1], u[2], u[3], u[4], u[5], out)
    return True


@numba.njit(cache=True)
def _run(cf, st, f, w, out):  # pragma: no cover - compiled
    """Many samples; returns the index of the first non-finite sample, or -1."""
    n = f.shape[0]
    for k in range(n):
        for j in range(3):
            if not (np.isfinite(f[k, j]) and np.isfinite(w[k, j])):
                return k
    row = np.empty(6)
    for k in range(n):
        _step_kernel(cf, st, f[k, 0], f[k, 1], f[k, 2], w[k, 0], w[k, 1], w[k, 2], row)
        for j in range(6):
            out[k, j] = row[j]
    return -1


@numba.njit(TRACK_SIGNATURE, cache=True)
def _track(cf, st, ach):  # pragma: no cover - compiled
    # translation: position := achieved; zero a velocity that points into the cut
    for i in range(3):
        d = ach[i] - st[_POSE + i]
        if d != 0.0:
            st[_QT + 3 * i + 1] = ach[i]
            if st[_QT + 3 * i + 2] * d < 0.0:
                st[_QT + 3 * i + 2] = 0.0
            if cf[_XON + i] != 0.0:  # the cue limiter continues from the achieved pose too
                j = _XS + 3 * i
                st[j] = ach[i]
                st[j + 2] = ach[i]
                if st[j + 1] * d < 0.0:
                    st[j + 1] = 0.0
    # rotation: scale tilt and high-pass together when the clamp scaled toward neutral
    for j in range(3):
        cmd = st[_POSE + 3 + j]
        d = ach[3 + j] - cmd
        if d == 0.0:
            continue
        if j < 2 and cmd != 0.0:
            s = ach[3 + j] / cmd
            if 0.0 <= s <= 1.0:
                st[_TILT + j] = st[_TILT + j] * s
                st[_TRATE + j] = st[_TRATE + j] * s
                st[_QR + 2 * j + 1] = ach[3 + j] - st[_TILT + j]
                continue
        tilt = st[_TILT + j] if j < 2 else 0.0
        st[_QR + 2 * j + 1] = ach[3 + j] - tilt
    for i in range(6):
        st[_POSE + i] = ach[i]


# --- state view ----------------------------------------------------------------------------


@dataclass(frozen=True)
class WashoutState:
    """A read-only snapshot of every state of the washout (SI units, base axes FRD).

    Attributes
    ----------
    translational : ndarray, shape (3, 3)
        Per axis x, y, z: (integral of position [m s], position [m], velocity [m/s]).
    translational_input : ndarray, shape (3,)
        Last input of the translational high-pass: inertial acceleration, m/s^2.
    tilt_lowpass : ndarray, shape (2, 2)
        Per axis x, y: (low-passed scaled specific force [m/s^2], its rate [m/s^3]).
    tilt_lowpass_input : ndarray, shape (2,)
        Last scaled specific force x, y, m/s^2.
    tilt : ndarray, shape (2,)
        Tilt-coordination angles (roll, pitch), rad, after rate and angle limits.
    tilt_rate : ndarray, shape (2,)
        Their rates over the last sample, rad/s.
    tilt_target : ndarray, shape (2,)
        The last angle-limited tilt targets (roll, pitch) the tracker followed, rad.
    rotational : ndarray, shape (3, 2)
        Per axis roll, pitch, yaw: (integral of angle [rad s], high-passed angle [rad]).
    rotational_input : ndarray, shape (3,)
        Last scaled Euler rates, rad/s.
    pose : ndarray, shape (6,)
        Last pose sent: the washout's output, or the achieved pose given to ``track``.
    input_lowpass : ndarray, shape (6, 2)
        Per input channel (specific force deviation from level flight x, y, z [m/s^2], body
        rates p, q, r [rad/s]): the input low-pass's (output, rate); zero when it is off.
    input_lowpass_input : ndarray, shape (6,)
        Its last inputs.
    cue_limiter : ndarray, shape (3, 3)
        Per axis x, y, z: the limited translational cue's (position [m], velocity [m/s],
        last high-pass position it followed [m]); zero on axes without limits.
    """

    translational: np.ndarray
    translational_input: np.ndarray
    tilt_lowpass: np.ndarray
    tilt_lowpass_input: np.ndarray
    tilt: np.ndarray
    tilt_rate: np.ndarray
    tilt_target: np.ndarray
    rotational: np.ndarray
    rotational_input: np.ndarray
    pose: np.ndarray
    input_lowpass: np.ndarray
    input_lowpass_input: np.ndarray
    cue_limiter: np.ndarray

    @classmethod
    def from_vector(cls, st: np.ndarray) -> WashoutState:
        parts = {
            "translational": st[_QT:_UT].reshape(3, 3),
            "translational_input": st[_UT : _UT + 3],
            "tilt_lowpass": st[_QL:_UL].reshape(2, 2),
            "tilt_lowpass_input": st[_UL : _UL + 2],
            "tilt": st[_TILT : _TILT + 2],
            "tilt_rate": st[_TRATE : _TRATE + 2],
            "tilt_target": st[_TTGT : _TTGT + 2],
            "rotational": st[_QR:_UR].reshape(3, 2),
            "rotational_input": st[_UR : _UR + 3],
            "pose": st[_POSE : _POSE + 6],
            "input_lowpass": st[_QP:_UP].reshape(6, 2),
            "input_lowpass_input": st[_UP : _UP + 6],
            "cue_limiter": st[_XS : _XS + 9].reshape(3, 3),
        }
        frozen = {}
        for key, value in parts.items():
            arr = np.array(value, dtype=float)
            arr.setflags(write=False)
            frozen[key] = arr
        return cls(**frozen)

    def to_vector(self) -> np.ndarray:
        st = np.zeros(_NS)
        st[_QT:_UT] = self.translational.ravel()
        st[_UT : _UT + 3] = self.translational_input
        st[_QL:_UL] = self.tilt_lowpass.ravel()
        st[_UL : _UL + 2] = self.tilt_lowpass_input
        st[_TILT : _TILT + 2] = self.tilt
        st[_TRATE : _TRATE + 2] = self.tilt_rate
        st[_TTGT : _TTGT + 2] = self.tilt_target
        st[_QR:_UR] = self.rotational.ravel()
        st[_UR : _UR + 3] = self.rotational_input
        st[_POSE : _POSE + 6] = self.pose
        st[_QP:_UP] = self.input_lowpass.ravel()
        st[_UP : _UP + 6] = self.input_lowpass_input
        st[_XS : _XS + 9] = self.cue_limiter.ravel()
        return st


# --- the filter ----------------------------------------------------------------------------


def _pack(params: WashoutParams, dt: float) -> np.ndarray:
    cf = np.zeros(_NC)
    m = params.method

    def disc(block, wn: float, field: str):
        """The block discretised at ``dt``; an error names the file's field."""
        try:
            return discretise(block, dt, m, prewarp=wn if m == "tustin" else None)
        except ConfigError as exc:
            raise ConfigError(f"{exc} (washout field {field})") from None

    axes = ("x", "y", "z")
    for i in range(3):
        wn = params.translational_wn[i]
        blk = translational_highpass(wn, params.translational_zeta[i], params.translational_wb[i])
        d = disc(blk, wn, f"translational.wn, {axes[i]}")
        cf[_TPHI + 9 * i : _TPHI + 9 * i + 9] = d.phi.ravel()
        cf[_TG0 + 3 * i : _TG0 + 3 * i + 3] = d.gamma0
        cf[_TG1 + 3 * i : _TG1 + 3 * i + 3] = d.gamma1
        wn = params.rotational_wn[i]
        d = disc(
            rotational_highpass(wn, params.rotational_zeta[i]),
            wn,
            f"rotational.wn, {('roll', 'pitch', 'yaw')[i]}",
        )
        cf[_RPHI + 4 * i : _RPHI + 4 * i + 4] = d.phi.ravel()
        cf[_RG0 + 2 * i : _RG0 + 2 * i + 2] = d.gamma0
        cf[_RG1 + 2 * i : _RG1 + 2 * i + 2] = d.gamma1
    wn = params.tilt_wn
    d = disc(lowpass2(wn, params.tilt_zeta), wn, "tilt.wn")
    for i in range(2):
        cf[_LPHI + 4 * i : _LPHI + 4 * i + 4] = d.phi.ravel()
        cf[_LG0 + 2 * i : _LG0 + 2 * i + 2] = d.gamma0
        cf[_LG1 + 2 * i : _LG1 + 2 * i + 2] = d.gamma1
    cf[_KF : _KF + 3] = params.specific_force_gain
    cf[_FLIM : _FLIM + 3] = params.specific_force_limit
    cf[_KW : _KW + 3] = params.angular_velocity_gain
    cf[_WLIM : _WLIM + 3] = params.angular_velocity_limit
    cf[_G] = params.g
    cf[_DT] = dt
    cf[_TVMAX : _TVMAX + 2] = params.tilt_rate_limit
    cf[_TLIM : _TLIM + 2] = params.tilt_angle_limit
    cf[_TU : _TU + 2] = params.tilt_accel_limit * dt
    cf[_TK : _TK + 2] = params.tilt_accel_limit / params.tilt_rate_limit  # 1/tau of the glide
    wn = params.input_lowpass_wn
    if wn > 0.0:
        d = disc(lowpass2(wn, 1.0), wn, "input.lowpass_wn")
        cf[_PON] = 1.0
        cf[_PPHI : _PPHI + 4] = d.phi.ravel()
        cf[_PG0 : _PG0 + 2] = d.gamma0
        cf[_PG1 : _PG1 + 2] = d.gamma1
    for i in range(3):
        a = params.translational_accel_limit[i]
        v = params.translational_velocity_limit[i]
        cf[_XON + i] = 1.0 if (a > 0.0 or v > 0.0) else 0.0
        vmax = v if v > 0.0 else np.inf
        cf[_XV + i] = vmax
        cf[_XU + i] = a * dt if a > 0.0 else np.inf
        cf[_XK + i] = a / vmax if a > 0.0 else 0.0  # (0 without a velocity limit: braking alone)
    return cf


class ClassicalWashout(Cueing):
    """Classical washout filter: aircraft specific force and rates to a platform pose.

    The first :class:`~motionbase.washout.cueing.Cueing` plug-in (``--cueing classical``).

    Parameters
    ----------
    params : WashoutParams
        Gains, limits and filter frequencies.
    dt : float
        Sample period, s (the pipeline rate; e.g. 1/120).

    Notes
    -----
    Lifecycle: construct, then ``step`` every sample (or ``run`` a batch), ``track``
    after a clamp, ``reset`` on pause, aircraft load and E-stop. The structure and
    equations are in the module docstring.
    """

    def __init__(self, params: WashoutParams, dt: float) -> None:
        if not isinstance(params, WashoutParams):
            raise TypeError(f"params must be WashoutParams, got {type(params).__name__}")
        self._params = params
        self._dt = float(dt)
        self._cf = _pack(params, self._dt)  # validates dt and Nyquist
        self._st = np.zeros(_NS)
        self._u = np.zeros(6)
        self._out = np.zeros(6)
        self._ach = np.zeros(6)
        self.kernel_params = self._cf
        self.kernel_state = self._st

    name = "classical"
    step_kernel = staticmethod(_step)
    track_kernel = staticmethod(_track)

    def advance(self, u: np.ndarray, out: np.ndarray) -> bool:
        """One sample into ``out`` (the pipeline's tick): see :class:`Cueing`."""
        return _step(self._cf, self._st, u, out)

    @property
    def params(self) -> WashoutParams:
        """The parameters (immutable)."""
        return self._params

    @property
    def dt(self) -> float:
        """Sample period, s."""
        return self._dt

    @property
    def state(self) -> WashoutState:
        """A snapshot of every filter state (a copy; changing it changes nothing)."""
        return WashoutState.from_vector(self._st)

    @state.setter
    def state(self, value: WashoutState) -> None:
        vec = value.to_vector()
        if not np.isfinite(vec).all():
            raise WashoutInputError("washout state: every value must be finite")
        self._st[:] = vec

    def reset(self) -> None:
        """Back to rest at the neutral pose (every state zero)."""
        self._st[:] = 0.0

    def step(self, specific_force, angular_velocity) -> np.ndarray:
        """Advance one sample (the real-time path).

        Parameters
        ----------
        specific_force : array_like, shape (3,)
            Specific force at the pilot, m/s^2, body axes FRD (level flight
            ``(0, 0, -g)``).
        angular_velocity : array_like, shape (3,)
            Body rates (p, q, r), rad/s, body axes FRD.

        Returns
        -------
        ndarray, shape (6,)
            Pose ``[x, y, z, roll, pitch, yaw]`` (m, rad), base axes FRD, before clamping.

        Raises
        ------
        WashoutInputError
            On a wrong shape or a non-finite value (the state is left unchanged).
        """
        u = self._u
        try:
            u[0:3] = specific_force
            u[3:6] = angular_velocity
        except (ValueError, TypeError):
            raise WashoutInputError(
                "washout input: specific_force and angular_velocity must be 3 numbers each, "
                f"got {specific_force!r} and {angular_velocity!r}"
            ) from None
        if not _step(self._cf, self._st, u, self._out):
            raise WashoutInputError(
                f"washout input: non-finite value in specific_force {u[:3]} or "
                f"angular_velocity {u[3:]} (reject the sample before the washout)"
            )
        return self._out.copy()

    def run(
        self,
        specific_force,
        angular_velocity,
        clamp: Callable[[np.ndarray], object] | None = None,
    ) -> np.ndarray:
        """Advance many samples (the batch path), exactly as many calls of :meth:`step`.

        The state carries over: ``run(a); run(b)`` equals ``run(concat(a, b))``.

        Parameters
        ----------
        specific_force : array_like, shape (N, 3)
            Specific force per sample, m/s^2, body axes FRD.
        angular_velocity : array_like, shape (N, 3)
            Body rates per sample, rad/s, body axes FRD.
        clamp : callable, optional
            ``clamp(pose) -> achieved`` or ``-> (achieved, clamped)``, the platform's
            clamp. When given, each sample is stepped, clamped and, when the achieved
            pose differs, fed back with :meth:`track`, exactly as the streaming
            pipeline does. This path loops in Python (about the cost of ``step``
            plus ``clamp`` per sample); without a clamp the loop is compiled.

        Returns
        -------
        ndarray, shape (N, 6)
            Washout poses before clamping (apply ``clamp`` row by row for the
            achieved ones).
        """
        f = np.ascontiguousarray(specific_force, dtype=float)
        w = np.ascontiguousarray(angular_velocity, dtype=float)
        if f.ndim != 2 or f.shape[1] != 3 or w.shape != f.shape:
            raise WashoutInputError(
                "washout input: specific_force and angular_velocity must both have shape (N, 3), "
                f"got {f.shape} and {w.shape}"
            )
        out = np.empty((f.shape[0], 6))
        if clamp is None:
            bad = _run(self._cf, self._st, f, w, out)
            if bad >= 0:
                raise WashoutInputError(
                    f"washout input: non-finite value at sample {bad} (reject it before the "
                    "washout); the state is unchanged"
                )
            return out
        if not (np.isfinite(f).all() and np.isfinite(w).all()):
            raise WashoutInputError(
                "washout input: non-finite value (reject it before the washout)"
            )
        for k in range(f.shape[0]):
            pose = self.step(f[k], w[k])
            out[k] = pose
            result = clamp(pose)
            achieved = result[0] if isinstance(result, tuple) else result
            achieved = np.asarray(achieved, dtype=float)
            if not np.array_equal(achieved, pose):
                self.track(achieved)
        return out

    def track(self, achieved_pose) -> None:
        """Anti-windup: tell the filter the pose the platform actually got.

        Call it after the platform's clamp with the pose sent, when it differs from
        the last :meth:`step` output. The states are rewritten so that the filter's
        pose equals ``achieved_pose`` and continues from it (back-calculation; the
        rules are in the module docstring). Calling it with the unchanged pose is a
        no-op.

        Parameters
        ----------
        achieved_pose : array_like, shape (6,)
            ``[x, y, z, roll, pitch, yaw]`` (m, rad), base axes FRD.
        """
        ach = self._ach
        try:
            ach[:] = achieved_pose
        except (ValueError, TypeError):
            raise WashoutInputError(
                f"washout track: achieved pose must be 6 numbers, got {achieved_pose!r}"
            ) from None
        if not np.isfinite(ach).all():
            raise WashoutInputError(f"washout track: achieved pose must be finite, got {ach}")
        _track(self._cf, self._st, ach)

    def __repr__(self) -> str:
        return f"ClassicalWashout(dt={self._dt:g}, method={self._params.method!r})"
