"""The cueing plug-in interface: aircraft motion in, platform pose out.

A motion cueing algorithm turns the aircraft's specific force and body rates at the
pilot into a *cue pose* ``[x, y, z, roll, pitch, yaw]`` (m and rad, base axes FRD) that
the robot then renders. The pipeline knows nothing else about cueing: it calls
:meth:`Cueing.advance` once a tick, :meth:`Cueing.track` when the robot's clamp moved
the pose (anti-windup) and :meth:`Cueing.reset` on a restart. The classical washout
(:class:`~motionbase.washout.ClassicalWashout`) is the first implementation; others are
listed in :data:`CUEINGS` (or added with :func:`register_cueing`) and chosen with
``--cueing NAME`` and ``--params FILE.toml``.

Time convention: one call of :meth:`Cueing.advance` is one sample period ``dt`` (s), the
pipeline's.

Flight phase (optional): before :meth:`Cueing.advance`, the pipeline calls
:meth:`Cueing.set_flight_phase` on every tick whose sample says whether the aircraft is on
the ground (:attr:`motionbase.state.AircraftState.on_ground`); a cueing that does not use
it ignores it (the default). A cueing may keep a small dict in :attr:`Cueing.status`
(plain JSON values) that the log writes with its pose on ``/washout/pose``. Parameters
with flight-phase profiles (``params.profiles``) are run by
:class:`~motionbase.washout.profiles.ProfiledCueing`, which :meth:`CueingSpec.make` builds
for them: one cueing of the registered kind per profile, blended by the phase.

Compiled kernels (optional)
---------------------------
A cueing whose step is a numba function may expose it, so that the pipeline's batch path
(:meth:`motionbase.pipeline.Pipeline.run_batch`) runs a whole flight in compiled code and
its tick calls the step without numba's per-call dispatch (in place of :meth:`Cueing.advance`,
which must do the same):
``step_kernel(params, state, u, out) -> bool`` (:data:`STEP_SIGNATURE`: ``u`` is
``[f, w]``, shape (6,); ``out`` the pose, (6,); False on a non-finite input, with the
state untouched) and ``track_kernel(params, state, achieved)``
(:data:`TRACK_SIGNATURE`), working on the arrays :attr:`Cueing.kernel_params` and
:attr:`Cueing.kernel_state` (the live state: the kernels change it in place), writable,
C-ordered float64 vectors as the signatures say (building the pipeline with others is a
TypeError that names the types). Without them the batch path steps the cueing from Python,
with the same results.
"""

from __future__ import annotations

import contextlib
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numba
import numpy as np

from motionbase.config import import_plugin
from motionbase.errors import ConfigError

_vec = numba.float64[::1]
#: Signature of a cueing's compiled step (see the module notes).
STEP_SIGNATURE = numba.boolean(_vec, _vec, _vec, _vec)
#: Signature of a cueing's compiled anti-windup feedback.
TRACK_SIGNATURE = numba.void(_vec, _vec, _vec)


class Cueing(ABC):
    """A motion cueing algorithm as the pipeline runs it.

    Subclasses set :attr:`name` and implement :meth:`reset`, :meth:`advance` and
    :meth:`track`; they are built as ``Cls(params, dt)``.

    Attributes
    ----------
    name : str
        Registry name, written in the log (``"classical"``).
    params : object
        The parameters (a frozen value object with ``to_dict``).
    dt : float
        Sample period, s.
    step_kernel, track_kernel : numba dispatcher or None
        Optional compiled step and feedback (module notes).
    kernel_params, kernel_state : ndarray or None
        Their parameter and (live) state vectors.
    status : dict or None
        Extra fields the log writes on ``/washout/pose`` (None: none).
    """

    name: ClassVar[str]
    params: Any
    dt: float
    step_kernel: Any = None
    track_kernel: Any = None
    kernel_params: np.ndarray | None = None
    kernel_state: np.ndarray | None = None
    status: dict[str, Any] | None = None

    def set_flight_phase(self, on_ground: bool) -> None:  # noqa: B027 - optional hook
        """The sample's flight phase (True: on the ground), before :meth:`advance`; only on
        ticks whose sample gives one. Ignored unless a cueing uses it."""

    @abstractmethod
    def reset(self) -> None:
        """Back to rest at the neutral pose."""

    @abstractmethod
    def advance(self, u: np.ndarray, out: np.ndarray) -> bool:
        """One sample: ``u = [f (m/s^2), w (rad/s)]``, shape (6,), body axes FRD, to the cue
        pose written into ``out`` (6,). Returns False, changing nothing, when ``u`` is not
        finite."""

    @abstractmethod
    def track(self, achieved: np.ndarray) -> None:
        """Anti-windup: the cue pose (6,) the platform actually got after the clamp."""

    def bind_robot(self, robot: Any) -> None:  # noqa: B027 (optional hook, no-op default)
        """Optional: the robot plug-in (:class:`~motionbase.platform.robot.Robot`) this
        cueing drives, given once by the pipeline after the cueing is made, before the
        first tick. A cueing that plans within the actuators' limits keeps it; the
        default ignores it."""

    #: Optional: (schema name, JSON Schema of the :meth:`diagnostics` object) for a
    #: plug-in's diagnostics to be logged, e.g. ``("my.Diagnostics", {"type": "object",
    #: "properties": {"residual": {"type": "number"}}})``; the shipped cueings' schemas
    #: are in :data:`motionbase.io.schemas.CUEING_DIAGNOSTICS`.
    diagnostics_schema: ClassVar[tuple[str, dict[str, Any]] | None] = None

    def diagnostics(self) -> dict[str, Any] | None:
        """Optional: the last tick's diagnostics (flat mapping of numbers, bools and short
        strings), logged on ``/cueing/<name>`` each tick when the cueing has a schema for
        them (:attr:`diagnostics_schema`); None (the default): nothing to log."""
        return None


#: The attribute :meth:`CueingSpec.load_params` sets on the parameters it read: their file.
LOADED_FROM = "_motionbase_loaded_from"


@dataclass(frozen=True)
class CueingSpec:
    """One entry of :data:`CUEINGS`.

    Attributes
    ----------
    name : str
    cueing_class, params_class : str or type
        ``"module:Class"`` (imported on use) or the class itself. The parameters class
        has ``from_toml(path)``, ``from_dict(data, source=...)`` and ``to_dict()``, and,
        when it names other files or presets, ``self_contained()``: the same parameters
        holding their values, which the log stores.
    preset_kind : str
        Shipped parameter files are ``motionbase/presets/<preset_kind>_<name>.toml``.
    default_preset : str
        The preset used when none is given, except on a geometry of ``tuned_presets``.
    description : str
    tuned_presets : dict of (str, str) to str
        Presets made for one robot geometry (``motionbase tune``, the MPC's limits):
        ``{(robot, geometry preset): cueing preset}``; on that geometry the tuned preset is
        the default.
    """

    name: str
    cueing_class: Any
    params_class: Any
    preset_kind: str
    default_preset: str = "default"
    description: str = ""
    tuned_presets: dict[tuple[str, str], str] = field(default_factory=dict)

    @property
    def cueing_type(self) -> type[Cueing]:
        c = self.cueing_class
        return import_plugin(c, f"cueing {self.name!r}") if isinstance(c, str) else c

    @property
    def params_type(self) -> Any:
        c = self.params_class
        return import_plugin(c, f"cueing {self.name!r}'s parameters") if isinstance(c, str) else c

    def load_params(self, preset_or_path: str | Path | None = None) -> Any:
        """Parameters from a preset name or a TOML path (the default preset for None)."""
        from motionbase.config import resolve_preset_or_path

        path = resolve_preset_or_path(self.preset_kind, preset_or_path or self.default_preset)
        params = self.params_type.from_toml(path)
        # for :meth:`make`'s errors (not a field: equality and the log ignore it); not on a
        # plug-in's parameters with __slots__
        with contextlib.suppress(AttributeError, TypeError):
            object.__setattr__(params, LOADED_FROM, str(path))
        return params

    def make(self, params: Any, dt: float) -> Cueing:
        """The cueing for ``params`` at sample period ``dt`` (s): a
        :class:`~motionbase.washout.profiles.ProfiledCueing` when they hold flight-phase
        profiles.

        Raises
        ------
        ConfigError
            The parameters do not fit ``dt`` (a filter frequency above the Nyquist
            frequency); the message names their file when :meth:`load_params` read one.
        """
        try:
            if getattr(params, "profiles", ()):
                from motionbase.washout.profiles import ProfiledCueing

                return ProfiledCueing(self.cueing_type, params, dt, name=self.name)
            return self.cueing_type(params, dt)
        except ConfigError as exc:
            source = getattr(params, LOADED_FROM, None)
            if source is None or str(exc).startswith(source):
                raise
            raise ConfigError(f"{source}: {exc}") from None


#: Every cueing algorithm by name; :func:`register_cueing` adds one.
CUEINGS: dict[str, CueingSpec] = {
    "classical": CueingSpec(
        "classical",
        "motionbase.washout.classical:ClassicalWashout",
        "motionbase.washout.params:WashoutParams",
        preset_kind="washout",
        description="classical washout (Reid & Nahon), tilt coordination",
        tuned_presets={("rus6", "ceart"): "tuned_ceart", ("stewart6", "seat"): "tuned_seat"},
    ),
    "mpc": CueingSpec(
        "mpc",
        "motionbase.washout.mpc:MpcCueing",
        "motionbase.washout.mpc_params:MpcParams",
        preset_kind="mpc",
        default_preset="tuned_ceart",
        description="model-predictive cueing (vestibular models, platform limits; OSQP)",
        tuned_presets={("stewart6", "seat"): "seat"},
    ),
}


def register_cueing(spec: CueingSpec, *, replace: bool = False) -> None:
    """Add a cueing algorithm, selectable by ``spec.name`` (``--cueing NAME``)."""
    if spec.name in CUEINGS and not replace:
        raise ConfigError(f"a cueing named {spec.name!r} is already registered")
    CUEINGS[spec.name] = spec


def cueing_spec(name: str) -> CueingSpec:
    """The registry entry of ``name``, or a ConfigError listing the known cueings."""
    try:
        return CUEINGS[name]
    except (KeyError, TypeError):
        raise ConfigError(
            f"unknown cueing {name!r} (choose one of: {', '.join(sorted(CUEINGS))})"
        ) from None
