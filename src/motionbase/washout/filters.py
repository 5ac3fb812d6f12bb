"""Linear filter blocks of the washout: continuous design, discretisation, application.

The style follows :mod:`scipy.signal`: *design* functions return coefficients
(continuous state-space matrices, then a :class:`DiscreteFilter`), and
*application* functions take the input and an explicit state and return the
output and the new state. Nothing here keeps hidden state.

Every block is realised in **physical state coordinates** (position, velocity,
integral of position, ...) so that the anti-windup hook of
:class:`~motionbase.washout.classical.ClassicalWashout` can write the
achieved pose straight into the state (back-calculation).

Discretisation
--------------
A continuous block ``q' = A q + B u``, ``y = C q`` becomes

.. math:: q_{k+1} = \\Phi q_k + \\Gamma_0 u_k + \\Gamma_1 u_{k+1}, \\qquad y_k = C q_k

- ``"tustin"``: trapezoidal integration of the ODE, which *is* the bilinear
  (Tustin) transform ``s = (2/T') (z - 1)/(z + 1)``; with pre-warping at
  ``w0`` the step ``T' = 2 tan(w0 T / 2) / w0`` replaces ``T`` so the discrete
  response equals the continuous one exactly at ``w0``. ``Gamma_0 = Gamma_1``.
  No half-sample delay: gain and phase follow the continuous design up to the
  frequency warping ``w' = (2/T) tan(w T / 2)``.
- ``"zoh"``: exact zero-order hold (``Phi = e^{A T}``, ``Gamma_1 = 0``): exact
  at the sample instants for a held input, at the price of the hold's
  half-sample delay (phase lag ``w T / 2``).

The state is the continuous state at the sample instant in both cases.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg  # (numba imports it anyway)

from motionbase.errors import ConfigError

METHODS = ("tustin", "zoh")


@dataclass(frozen=True)
class ContinuousBlock:
    """A continuous single-input single-output block ``q' = A q + B u``, ``y = C q``.

    Attributes
    ----------
    a : ndarray, shape (n, n)
    b : ndarray, shape (n,)
    c : ndarray, shape (n,)
    states : tuple of str
        Physical meaning of each state (documentation and inspection).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    states: tuple[str, ...]

    def transfer_function(self) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator polynomials (descending powers of s)."""
        import scipy.signal  # here: about a second to import, and a run never needs it

        num, den = scipy.signal.ss2tf(self.a, self.b[:, None], self.c[None, :], [[0.0]])
        return np.atleast_1d(np.squeeze(num)), den


@dataclass(frozen=True)
class DiscreteFilter:
    """Coefficients of a discretised block (see the module docstring for the recursion).

    Attributes
    ----------
    phi : ndarray, shape (n, n)
        State transition.
    gamma0, gamma1 : ndarray, shape (n,)
        Input weights of the previous and the current input sample.
    c : ndarray, shape (n,)
        Output row: ``y_k = c @ q_k``.
    dt : float
        Sample period, s.
    method : str
        ``"tustin"`` or ``"zoh"``.
    """

    phi: np.ndarray
    gamma0: np.ndarray
    gamma1: np.ndarray
    c: np.ndarray
    dt: float
    method: str


# --- design: continuous blocks -------------------------------------------------------------


def translational_highpass(wn: float, zeta: float, wb: float) -> ContinuousBlock:
    """Third-order high-pass followed by a double integration, acceleration to position.

    ``x(s)/a(s) = 1/s^2 * s^2/(s^2 + 2 zeta wn s + wn^2) * s/(s + wb)
    = s / ((s^2 + 2 zeta wn s + wn^2)(s + wb))`` (Reid & Nahon 1985, translational
    channel). Realised as ``x'' + a2 x' + a1 x + a0 int(x) = a`` with the states
    ``(int x dt [m s], x [m], x' [m/s])``: a stable realisation without free
    integrators, so any state (for instance one written by the anti-windup) decays
    back to neutral.

    Parameters
    ----------
    wn : float
        Natural frequency of the second-order high-pass, rad/s, > 0.
    zeta : float
        Its damping ratio, > 0.
    wb : float
        Break frequency of the first-order high-pass, rad/s, > 0.
    """
    a2 = 2.0 * zeta * wn + wb
    a1 = wn * wn + 2.0 * zeta * wn * wb
    a0 = wn * wn * wb
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-a0, -a1, -a2]])
    return ContinuousBlock(
        a,
        np.array([0.0, 0.0, 1.0]),
        np.array([0.0, 1.0, 0.0]),
        ("integral", "position", "velocity"),
    )


def rotational_highpass(wn: float, zeta: float) -> ContinuousBlock:
    """Second-order high-pass on an Euler rate followed by integration, rate to angle.

    ``beta(s)/beta_dot(s) = 1/s * s^2/(s^2 + 2 zeta wn s + wn^2) = s/(s^2 + 2 zeta wn s + wn^2)``
    (Reid & Nahon 1985, rotational channel). Realised as
    ``beta' + 2 zeta wn beta + wn^2 int(beta) = beta_dot`` with the states
    ``(int beta dt [rad s], beta [rad])``. A sustained rate gives an angle that
    returns to zero.

    Parameters
    ----------
    wn : float
        Natural frequency, rad/s, > 0.
    zeta : float
        Damping ratio, > 0.
    """
    a = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
    return ContinuousBlock(a, np.array([0.0, 1.0]), np.array([0.0, 1.0]), ("integral", "angle"))


def lowpass2(wn: float, zeta: float) -> ContinuousBlock:
    """Second-order low-pass ``wn^2/(s^2 + 2 zeta wn s + wn^2)`` with states ``(y, y')``.

    Used for tilt coordination (Reid & Nahon 1985): unit DC gain.

    Parameters
    ----------
    wn : float
        Natural frequency, rad/s, > 0.
    zeta : float
        Damping ratio, > 0.
    """
    a = np.array([[0.0, 1.0], [-wn * wn, -2.0 * zeta * wn]])
    return ContinuousBlock(a, np.array([0.0, wn * wn]), np.array([1.0, 0.0]), ("output", "rate"))


# --- design: discretisation ----------------------------------------------------------------


def discretise(
    block: ContinuousBlock, dt: float, method: str = "tustin", prewarp: float | None = None
) -> DiscreteFilter:
    """Discretise a continuous block (module docstring gives the recursion).

    Parameters
    ----------
    block : ContinuousBlock
        The continuous design.
    dt : float
        Sample period, s, > 0.
    method : {"tustin", "zoh"}
        Trapezoidal/bilinear (with optional pre-warping) or exact zero-order hold.
    prewarp : float, optional
        Tustin only: frequency, rad/s, at which the discrete response equals the
        continuous one; must satisfy ``0 < prewarp * dt < pi``.

    Returns
    -------
    DiscreteFilter
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ConfigError(f"washout: sample period dt must be > 0 s and finite, got {dt!r}")
    n = block.a.shape[0]
    eye = np.eye(n)
    if method == "tustin":
        step = dt
        if prewarp is not None:
            if not 0.0 < prewarp * dt < np.pi:
                raise ConfigError(
                    f"washout: filter frequency {prewarp:g} rad/s is above the Nyquist frequency "
                    f"of dt = {dt:g} s (raise the rate or lower the frequency)"
                )
            step = 2.0 * np.tan(prewarp * dt / 2.0) / prewarp
        m = np.linalg.inv(eye - block.a * (step / 2.0))
        phi = m @ (eye + block.a * (step / 2.0))
        gamma = m @ block.b * (step / 2.0)
        return DiscreteFilter(phi, gamma, gamma.copy(), block.c.copy(), float(dt), method)
    if method == "zoh":
        big = np.zeros((n + 1, n + 1))
        big[:n, :n] = block.a * dt
        big[:n, n] = block.b * dt
        e = scipy.linalg.expm(big)
        return DiscreteFilter(e[:n, :n], e[:n, n], np.zeros(n), block.c.copy(), float(dt), method)
    raise ConfigError(f"washout: unknown discretisation method {method!r} (use one of {METHODS})")


def tustin_tf(
    num: np.ndarray, den: np.ndarray, dt: float, prewarp: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear transform of a continuous transfer function, for :func:`scipy.signal.lfilter`.

    Parameters
    ----------
    num, den : array_like
        Continuous polynomials in descending powers of s.
    dt : float
        Sample period, s.
    prewarp : float, optional
        Frequency, rad/s, matched exactly.

    Returns
    -------
    b, a : ndarray
        Discrete polynomials in descending powers of z (``a[0] == 1``).
    """
    import scipy.signal  # here: about a second to import, and a run never needs it

    fs = 1.0 / dt
    if prewarp is not None:
        fs = prewarp / (2.0 * np.tan(prewarp * dt / 2.0))
    b, a = scipy.signal.bilinear(np.atleast_1d(num), np.atleast_1d(den), fs=fs)
    return b / a[0], a / a[0]


# --- application ---------------------------------------------------------------------------


def filter_step(
    filt: DiscreteFilter, state: np.ndarray, u_prev: float, u: float
) -> tuple[float, np.ndarray]:
    """Advance one sample.

    Parameters
    ----------
    filt : DiscreteFilter
    state : ndarray, shape (n,)
        State at the previous sample.
    u_prev : float
        Input at the previous sample.
    u : float
        Input at this sample.

    Returns
    -------
    y : float
        Output at this sample.
    state : ndarray, shape (n,)
        New state (a new array; the argument is not modified).
    """
    q = filt.phi @ state + filt.gamma0 * u_prev + filt.gamma1 * u
    return float(filt.c @ q), q


def filter_run(
    filt: DiscreteFilter,
    u: np.ndarray,
    state: np.ndarray | None = None,
    u_prev: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Filter a whole signal (reference implementation, pure numpy).

    Parameters
    ----------
    filt : DiscreteFilter
    u : ndarray, shape (N,)
        Input samples.
    state : ndarray, shape (n,), optional
        Initial state (zeros: at rest).
    u_prev : float
        Input before the first sample (0: at rest).

    Returns
    -------
    y : ndarray, shape (N,)
    state : ndarray, shape (n,)
        State after the last sample.
    u_last : float
        Last input, to pass as ``u_prev`` to the next call.
    """
    u = np.asarray(u, dtype=float)
    q = np.zeros(filt.phi.shape[0]) if state is None else np.array(state, dtype=float)
    y = np.empty(u.shape[0])
    prev = float(u_prev)
    for k in range(u.shape[0]):
        y[k], q = filter_step(filt, q, prev, float(u[k]))
        prev = float(u[k])
    return y, q, prev
