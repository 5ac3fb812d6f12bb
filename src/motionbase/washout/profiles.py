"""Flight-phase profiles: one cueing per profile, blended by the source's flight phase.

A cueing parameter file may hold ``[profile.ground]`` and ``[profile.air]`` tables that
override its own values on the ground and in the air (:mod:`motionbase.washout.params`,
"Flight-phase profiles"). :class:`ProfiledCueing` runs one cueing of the registered kind
per profile, every one on the same input each tick (so each is warm, its filters in the
state the flight put them in), and sends the blend of their poses::

    pose = sum_i w_i pose_i,    sum_i w_i = 1

The weights follow the flight phase the pipeline hands over
(:meth:`~motionbase.washout.cueing.Cueing.set_flight_phase`, from
:attr:`motionbase.state.AircraftState.on_ground`): when the phase changes, they move from
where they are to the new phase's profile along the C1 smoothstep
``h(s) = 3 s^2 - 2 s^3``, ``s = elapsed / blend_s``, so the weights' rate starts and ends
at zero. Each profile's pose is continuous and so is the blend: a phase change adds no
step in pose or velocity beyond what either profile gives alone. A phase change in the
middle of a blend starts the next one from the weights reached (continuous; its rate
then restarts from zero). The blend's own rate is up to ``1.5 / blend_s`` times the
profiles' difference: each profile's cue limits (tilt rate, translational velocity) hold
for its own pose, not for that share.

Until the source gives a phase, the file's own values run (the profile ``"base"``); an
unknown phase (``on_ground`` None) keeps the current profile. A phase known before the
first sample (a flight that starts on the ground) starts on its profile at once, with
no blend (nothing was sent yet). A phase whose profile the file does not define runs the
file's own values.

Anti-windup: :meth:`ProfiledCueing.track` tells every profile's cueing the pose the
platform achieved, so each continues from it.

Only the cueing's pose and status are blended; the parameters written in the log are the
whole file (:attr:`ProfiledCueing.params`). The profiled cueing has no compiled kernels:
the pipeline's batch path steps it from Python, like any cueing without them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from motionbase.errors import ConfigError
from motionbase.physics import smoothstep
from motionbase.washout.cueing import Cueing

__all__ = ["BASE", "ProfiledCueing"]

#: Name of the file's own values (before the first known phase, or a phase without a
#: profile of its own).
BASE = "base"


class ProfiledCueing(Cueing):
    """A cueing per flight-phase profile, blended by the flight phase (module notes).

    Parameters
    ----------
    cueing_class : type
        The cueing each profile runs, built as ``cueing_class(profile_params, dt)``.
    params : object
        Parameters with profiles: ``profile_names``, ``for_profile(name)`` (the values of
        a profile, or the file's own for None) and ``profile_blend_s`` (s), as
        :class:`~motionbase.washout.params.WashoutParams` has them.
    dt : float
        Sample period, s.
    name : str, optional
        Registry name written in the log (default: the class's).

    Attributes
    ----------
    profile : str
        The profile the weights go to (``"base"``, ``"ground"`` or ``"air"``).
    weights : dict of str to float
        Each profile's share of the pose now (a copy).
    status : dict
        ``{"profile": ..., "profile_weights": {...}}``, what the log writes with the cue
        pose (a new dict whenever it changes).
    """

    def __init__(self, cueing_class: Any, params: Any, dt: float, *, name: str = "") -> None:
        self.params = params
        self.dt = float(dt)
        self.name = name or getattr(cueing_class, "name", "profiled")
        #: the profiles' cueing's schema: its diagnostics are logged as without profiles
        self.diagnostics_schema = getattr(cueing_class, "diagnostics_schema", None)
        defined = tuple(params.profile_names)
        self._names = (BASE, *defined)
        self._cueings = [self._make(cueing_class, params, name) for name in (None, *defined)]
        #: phase (True: ground) -> index of the profile it runs
        self._index = {
            True: self._names.index("ground") if "ground" in defined else 0,
            False: self._names.index("air") if "air" in defined else 0,
        }
        # the file's own values stop running once left, when no phase leads back to them
        self._base_needed = 0 in self._index.values()
        self._blend_s = float(params.profile_blend_s)
        n = len(self._cueings)
        self._poses = np.zeros((n, 6))
        self._w = np.zeros(n)
        self._w0 = np.zeros(n)
        self.reset()

    def _make(self, cueing_class: type[Cueing], params: Any, name: str | None) -> Cueing:
        """The cueing of profile ``name`` (None: the file's own values); an error that only
        its values cause (a frequency above the Nyquist frequency) names the profile."""
        try:
            return cueing_class(params.for_profile(name), self.dt)
        except ConfigError as exc:
            if name is None:
                raise
            raise ConfigError(f"[profile.{name}]: {exc}") from None

    # -- state -------------------------------------------------------------------------------
    def reset(self) -> None:
        """Every profile's cueing back to rest; the file's own values run until a phase."""
        for c in self._cueings:
            c.reset()
        self._w[:] = 0.0
        self._w[0] = 1.0
        self._w0[:] = self._w
        self._target = 0
        self._s = 1.0  # blend progress (1: settled)
        self._started = False
        self._set_status()

    @property
    def profile(self) -> str:
        return self._names[self._target]

    @property
    def weights(self) -> dict[str, float]:
        return {name: float(w) for name, w in zip(self._names, self._w, strict=True)}

    def _set_status(self) -> None:
        self.status = {"profile": self.profile, "profile_weights": self.weights}

    # -- the hook ----------------------------------------------------------------------------
    def set_flight_phase(self, on_ground: bool) -> None:
        """The source's flight phase this tick (True: on the ground); a change starts a
        blend toward that phase's profile (at once before the first sample)."""
        j = self._index[bool(on_ground)]
        if j == self._target:
            return
        self._target = j
        if not self._started or self._blend_s <= 0.0:
            self._w[:] = 0.0
            self._w[j] = 1.0
            self._s = 1.0
        else:
            self._w0[:] = self._w
            self._s = 0.0
        self._set_status()

    # -- one tick ----------------------------------------------------------------------------
    def advance(self, u: np.ndarray, out: np.ndarray) -> bool:
        """Every profile one sample on ``u``; ``out`` the blend of their poses."""
        self._started = True
        if self._s < 1.0:
            self._s = min(1.0, self._s + self.dt / self._blend_s)
            h = smoothstep(self._s)
            w = self._w0 * (1.0 - h)
            w[self._target] += h
            if self._s >= 1.0:
                w[:] = 0.0
                w[self._target] = 1.0
            self._w[:] = w
            self._set_status()
        poses, weights = self._poses, self._w
        for i, c in enumerate(self._cueings):
            if i == 0 and weights[0] == 0.0 and not self._base_needed:
                continue
            if not c.advance(u, poses[i]):
                return False  # the same input for all: the first refuses it, untouched
        j = self._target
        if weights[j] == 1.0:
            out[:] = poses[j]
        else:
            np.dot(weights, poses, out=out)
        return True

    def track(self, achieved: np.ndarray) -> None:
        """Anti-windup: every running profile continues from the achieved pose."""
        for i, c in enumerate(self._cueings):
            if i == 0 and self._w[0] == 0.0 and not self._base_needed:
                continue
            c.track(achieved)

    def bind_robot(self, robot: Any) -> None:
        """Every profile's cueing drives the same robot."""
        for c in self._cueings:
            c.bind_robot(robot)

    def diagnostics(self) -> dict[str, Any] | None:
        """The diagnostics of the profile the weights go to."""
        return self._cueings[self._target].diagnostics()

    def __repr__(self) -> str:
        return (
            f"ProfiledCueing({self.name!r}, profiles={self._names[1:]}, "
            f"blend_s={self._blend_s:g}, dt={self.dt:g})"
        )
