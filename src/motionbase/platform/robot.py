"""The robot plug-in interface: what the pipeline needs from any motion platform.

A robot turns the cueing's pose (``[x, y, z, roll, pitch, yaw]``, m and rad, base axes
FRD, the *cue pose*) into actuator commands. The pipeline knows nothing else about it:
the 6-RUS rotary platform, the 6-UPS Stewart platform and the planar 3-RRR robot each
implement :class:`Robot` in their own module and are listed in :data:`ROBOTS`; a robot
outside the package adds its entry at run time (the README's "Adding a robot":
``tests/heave3_robot.py`` is one).

Actuator coordinates are the robot's own: crank or servo angles in rad for rotary
actuators, leg lengths in m for linear ones (``Robot.actuator_unit``). Speeds and
accelerations follow (rad/s or m/s, rad/s^2 or m/s^2).

The compiled real-time kernel
-----------------------------
Every robot provides :attr:`Robot.solve_kernel`, a numba function compiled with the
signature :data:`SOLVE_SIGNATURE`::

    clamped = solve_kernel(G, target, cue_out, pose_out, q_out)

``G`` is the robot's packed parameters (:attr:`Robot.kernel_params`), ``target`` the cue
pose (6,) to render; it writes the pose actually commanded in robot coordinates
(``pose_out``, shape (m,)), the cue pose it realises (``cue_out``, (6,): equal to
``target`` unless clamped; what the cueing is told for anti-windup) and the actuator
command (``q_out``, (n,)), and returns True when the workspace clamp moved the pose
(arrays float64, C-contiguous). The pipeline's tick and its batch path both call it from
compiled code (:func:`motionbase.stages.after_cueing`).
"""

from __future__ import annotations

from abc import ABC
from dataclasses import dataclass
from typing import Any, ClassVar

import numba
import numpy as np

from motionbase.config import DEFAULT_RRR3, DEFAULT_RUS6, import_plugin, names_a_file
from motionbase.errors import ConfigError
from motionbase.safety import ActuatorLimits

_vec = numba.float64[::1]
#: Signature of every robot's compiled clamp + inverse kinematics (see the module notes).
SOLVE_SIGNATURE = numba.boolean(_vec, _vec, _vec, _vec, _vec)


class Robot(ABC):
    """A motion platform as the pipeline drives it.

    Attributes
    ----------
    name : str
        Registry name (``"rus6"``, ``"rrr3"``, ``"stewart6"``), written in the log.
    geometry : object
        The robot's geometry (a frozen dataclass with ``to_dict``/``from_dict``).
    n : int
        Number of actuators.
    actuator_unit : {"rad", "m"}
        Unit of the actuator coordinates.
    limits : ActuatorLimits
        Actuator position, speed and acceleration limits, shape (n,) each.
    park_angles : ndarray, shape (n,)
        Actuator command of the parked platform (rad or m, despite the name: it is the
        command sent to the drives at park).
    park_pose : ndarray, shape (m,)
        The parked pose in robot coordinates.
    park_cue : ndarray, shape (6,)
        The cue pose of :attr:`park_pose` (the soft start blends from it).
    neutral_pose : ndarray, shape (m,)
        Robot pose of the zero cue pose.
    kernel_params : ndarray, shape (k,)
        Packed parameters of :attr:`solve_kernel` (do not change them).
    solve_kernel : numba dispatcher
        Clamp + inverse kinematics, compiled with :data:`SOLVE_SIGNATURE`.
    coordinated : bool
        The flight's limiter commands poses (:func:`motionbase.stages.path_stage`): for a
        robot whose actuators, each limited alone, can leave its valid poses (False).
    kin : object, optional
        The robot's kinematics class (:class:`~motionbase.platform.rus6.Rus6`,
        :class:`~motionbase.platform.stewart6.Stewart6`,
        :class:`~motionbase.platform.rrr3.Rrr3`). The kinematics methods below call its
        methods of the same names; a robot whose coordinates differ overrides them (and a
        robot that overrides them all needs no ``kin``).

    A robot of fewer axes than the cue pose (robot pose shape (m,), m < 6) overrides
    :meth:`pose_from_cue` and :meth:`cue_from_pose`; its ``/platform/pose`` is logged as its
    own pose, and ``/tf`` as the cue pose it realises with its other axes at neutral (about
    ``geometry.platform_origin``, when the geometry has one). The README's "Adding a robot"
    lists what is required and what optional; ``tests/heave3_robot.py`` is a plug-in outside
    the package.
    """

    name: ClassVar[str]
    actuator_unit: ClassVar[str] = "rad"
    coordinated: ClassVar[bool] = False
    geometry: Any
    n: int
    limits: ActuatorLimits
    park_angles: np.ndarray
    park_pose: np.ndarray
    park_cue: np.ndarray
    neutral_pose: np.ndarray
    kernel_params: np.ndarray
    solve_kernel: Any
    kin: Any

    # -- kinematics (robot coordinates): the kinematics class's, by default -------------
    def inverse(self, pose: np.ndarray) -> np.ndarray:
        """Actuator positions of robot poses ``(..., m) -> (..., n)`` (NaN: no solution)."""
        return self.kin.inverse(pose)

    def reachable(self, pose: np.ndarray) -> np.ndarray | bool:
        """Whether each robot pose ``(..., m)`` is reachable within the actuator limits."""
        return self.kin.reachable(pose)

    def clamp(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray | bool]:
        """The nearest reachable pose toward neutral, and whether it moved."""
        return self.kin.clamp(pose)

    def forward(self, q: np.ndarray, guess: np.ndarray) -> np.ndarray:
        """Robot poses ``(..., m)`` of actuator positions ``(..., n)``, by Newton from
        ``guess`` (rows of NaN where it does not converge)."""
        return np.asarray(self.kin.forward(q, guess=guess), dtype=float)

    def cue_reachable(self, cue: np.ndarray) -> np.ndarray | bool:
        """Whether each cue pose ``(..., 6)`` is rendered as it is: its robot pose reachable
        and every axis of it realised (an axis the robot lacks, the 3-actuator platform's
        surge say, is rendered only at 0). The workspace sweeps
        (:func:`~motionbase.platform.rus6_workspace.single_axis_envelope`) use it, so a
        robot's reach is in cue terms whatever its own coordinates."""
        cue = np.asarray(cue, dtype=float)
        pose = self.pose_from_cue(cue)
        ok = np.asarray(self.reachable(pose), dtype=bool)
        back = self.cue_from_pose(pose, np.zeros_like(cue))
        ok = ok & np.all(np.abs(back - cue) <= 1e-9 * (1.0 + np.abs(cue)), axis=-1)
        return bool(ok) if ok.ndim == 0 else ok

    # -- cue pose <-> robot pose -------------------------------------------------------
    def pose_from_cue(self, cue: np.ndarray) -> np.ndarray:
        """Robot pose of a cue pose (identity for the 6-DOF platforms)."""
        return np.array(cue, dtype=float)

    def cue_from_pose(self, pose: np.ndarray, cue: np.ndarray) -> np.ndarray:
        """The cue pose a robot pose realises; axes the robot lacks keep ``cue``'s."""
        return np.array(pose, dtype=float)

    def actuator_jacobian(
        self, cue: np.ndarray, step: float = 1e-6
    ) -> tuple[np.ndarray, np.ndarray]:
        """Actuator positions of cue poses and their derivatives by the cue pose.

        Central differences of ``inverse(pose_from_cue(cue))``, all poses and probes in one
        batched call of the inverse kinematics (the MPC linearises its legs with it every
        tick, the foresight planner a whole flight at once).

        Parameters
        ----------
        cue : ndarray, shape (M, 6) or (6,)
            Cue poses ``[x, y, z, roll, pitch, yaw]``, m and rad.
        step : float
            Difference step on each axis, m or rad.

        Returns
        -------
        q : ndarray, shape (M, n) or (n,)
            Actuator positions (rad or m; NaN where the pose has no solution).
        J : ndarray, shape (M, n, 6) or (n, 6)
            ``dq / dcue`` (actuator unit per m or rad); NaN where a probe ``step`` away on
            that axis has no solution.
        """
        cue = np.asarray(cue, dtype=float)
        poses = cue.reshape(-1, 6)
        steps = np.eye(6) * step
        probes = np.concatenate([np.zeros((1, 6)), steps, -steps])  # (13, 6)
        at = (poses[:, None, :] + probes[None]).reshape(-1, 6)
        q = np.asarray(self.inverse(self.pose_from_cue(at)), dtype=float)
        q = q.reshape(len(poses), len(probes), -1)
        J = ((q[:, 1:7] - q[:, 7:13]) / (2.0 * step)).transpose(0, 2, 1)
        if cue.ndim == 1:
            return q[0, 0], J[0]
        return q[:, 0], J

    def joint_points(self, pose: np.ndarray) -> Any:
        """The robot drawn at a robot pose ``(m,)``: its chains' points, ``k >= 2`` arrays of
        shape ``(n, 3)`` (``(n, 2)`` for a planar robot), m; the first are the base joints, the
        last the moving platform's (:mod:`motionbase.io.scene` draws them)."""
        return self.kin.joint_points(pose)

    def servo(self, q: np.ndarray) -> np.ndarray | None:
        """Hobby-servo command in integer degrees, for robots driven that way (else None)."""
        return None

    def default_output(self) -> Any:
        """The drive values of a geometry without an ``[output]`` table, an
        :class:`~motionbase.platform.output_map.OutputMapping`: degrees of each crank (rotary
        actuators) or millimetres of each length (linear ones, ``actuator_unit == "m"``)."""
        from motionbase.platform.output_map import OutputMapping

        unit = "mm" if self.actuator_unit == "m" else "deg"
        return OutputMapping.default(self.limits.lower, self.limits.upper, unit=unit)

    def _finish(self) -> None:
        """Check and freeze the attributes a subclass's constructor set."""
        for name in ("park_angles", "park_pose", "park_cue", "neutral_pose"):
            a = np.ascontiguousarray(getattr(self, name), dtype=float)
            a.setflags(write=False)
            setattr(self, name, a)
        # (writable: numba types a read-only array apart from the kernels' signature)
        self.kernel_params = np.ascontiguousarray(self.kernel_params, dtype=float)
        if not np.isfinite(self.park_angles).all() or not np.isfinite(self.park_pose).all():
            raise ConfigError(f"{self.name} geometry: the park position is not reachable")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({getattr(self.geometry, 'name', '')!r})"


@dataclass(frozen=True)
class RobotSpec:
    """One entry of :data:`ROBOTS`: how to build a robot from its name.

    Attributes
    ----------
    name : str
        Also the preset prefix: geometry presets ship as ``<preset_dir>/<name>_<preset>.toml``
        and a geometry file says it is this robot's with ``kind = "<name>"``.
    robot_class, geometry_class : str
        ``"module:Class"`` of the :class:`Robot` subclass and of its geometry (with
        ``preset``, ``from_toml``, ``from_dict`` and ``to_dict``), imported on use.
    default_preset : str
        Geometry preset used when none is given.
    planar : bool
        True for robots that render surge, sway and yaw only (``--planar``).
    description : str
        How messages name the robot (``"6-RUS"``).
    preset_dir : str or None
        The folder of the robot's geometry presets; None: motionbase's own
        (``motionbase/presets``). A plug-in outside the package ships its presets there.
    """

    name: str
    robot_class: str
    geometry_class: str
    default_preset: str
    planar: bool = False
    description: str = ""
    preset_dir: str | None = None

    @property
    def geometry_type(self) -> Any:
        """The geometry class."""
        return import_plugin(self.geometry_class, f"robot {self.name!r}'s geometry")

    @property
    def robot_type(self) -> type[Robot]:
        """The :class:`Robot` subclass."""
        return import_plugin(self.robot_class, f"robot {self.name!r}")

    def make(self, geometry: Any, **options: Any) -> Robot:
        """The robot for ``geometry`` (options: the planar mapping's scales), its attributes
        checked (:func:`check_robot`)."""
        robot = self.robot_type(geometry, **options)
        check_robot(robot, f"robot {self.name!r} ({self.robot_class})")
        return robot


#: The most actuators, and robot pose axes, the pipeline's stages have room for.
MAX_AXES = 6


def check_robot(robot: Any, what: str) -> None:
    """A ConfigError naming ``what`` (the plug-in) when ``robot`` lacks what the pipeline
    reads or has it in the wrong shape: ``n`` actuators (at most :data:`MAX_AXES`) with
    ``limits`` of that size, ``park_angles`` (n,) finite and within the limits,
    ``park_pose`` and ``neutral_pose`` (m,) finite, m at most 6, ``park_cue`` (6,) finite
    (the cue pose, not the robot pose), ``kernel_params`` a vector of numbers and a
    ``solve_kernel``. A plug-in's mistake there is otherwise a traceback deep in the
    pipeline, or worse a run that starts from a wrong park (every command held)."""

    def fail(problem: str) -> ConfigError:
        return ConfigError(f"{what}: {problem} (fix the robot class)")

    missing = [
        name
        for name in ("n", "limits", "park_angles", "park_pose", "park_cue", "neutral_pose")
        + ("kernel_params", "solve_kernel", "actuator_unit")
        if not hasattr(robot, name)
    ]
    if missing:
        raise fail(f"no attribute {', '.join(missing)}")
    n = robot.n
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_AXES:
        raise fail(f"n is {n!r}: the number of actuators, 1 to {MAX_AXES}")
    if robot.actuator_unit not in ("rad", "m"):
        raise fail(f"actuator_unit is {robot.actuator_unit!r}, not 'rad' or 'm'")

    def vector(name: str, value: Any, size: int | None, what_it_is: str) -> np.ndarray:
        try:
            a = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise fail(f"{name} is not numbers: {what_it_is}") from None
        if a.ndim != 1 or (size is not None and a.size != size) or not 1 <= a.size <= MAX_AXES:
            shape = f"{a.size} values" if a.ndim == 1 else f"shape {a.shape}"
            want = f"{size}" if size is not None else f"1 to {MAX_AXES}"
            raise fail(f"{name} has {shape}, expected {want}: {what_it_is}")
        if not np.isfinite(a).all():
            raise fail(f"{name} is not finite: {what_it_is}")
        return a

    lim = robot.limits
    for name in ("lower", "upper", "max_speed", "max_accel"):
        vector(f"limits.{name}", getattr(lim, name, None), n, f"one per actuator, n = {n}")
    park_q = vector("park_angles", robot.park_angles, n, "the actuators' park command")
    pose = vector("park_pose", robot.park_pose, None, "the parked robot pose")
    vector("neutral_pose", robot.neutral_pose, pose.size, "the robot pose of the zero cue")
    vector("park_cue", robot.park_cue, 6, "the cue pose [x, y, z, roll, pitch, yaw] of park")
    if not np.all((park_q >= lim.lower) & (park_q <= lim.upper)):
        raise fail(
            f"park_angles {park_q.tolist()} are outside the actuator limits "
            f"{np.asarray(lim.lower).tolist()} .. {np.asarray(lim.upper).tolist()}"
        )
    params = np.asarray(robot.kernel_params)
    if params.ndim != 1 or not np.issubdtype(params.dtype, np.number):
        raise fail(f"kernel_params is not a vector of numbers (shape {params.shape})")


#: Every robot motionbase drives, by name. A new robot: one module with a :class:`Robot`
#: subclass and its geometry, a preset TOML, and one entry here (a plug-in outside the
#: package adds its entry at run time, ``ROBOTS["mine"] = RobotSpec(...)``, with its own
#: ``preset_dir``).
ROBOTS: dict[str, RobotSpec] = {
    spec.name: spec
    for spec in (
        RobotSpec(
            "rus6",
            "motionbase.platform.rus6:Rus6Robot",
            "motionbase.platform.rus6_geometry:Rus6Geometry",
            DEFAULT_RUS6,
            description="6-RUS",
        ),
        RobotSpec(
            "stewart6",
            "motionbase.platform.stewart6:Stewart6Robot",
            "motionbase.platform.stewart6_geometry:Stewart6Geometry",
            "seat",
            description="6-UPS Stewart platform",
        ),
        RobotSpec(
            "rrr3",
            "motionbase.platform.rrr3:Rrr3Robot",
            "motionbase.platform.rrr3:Rrr3Geometry",
            DEFAULT_RRR3,
            planar=True,
            description="3-RRR, planar mode",
        ),
    )
}


def robot_spec(name: str) -> RobotSpec:
    """The registry entry of ``name``, or a ConfigError listing the known robots."""
    try:
        return ROBOTS[name]
    except (KeyError, TypeError):
        raise ConfigError(
            f"unknown robot {name!r} (choose one of: {', '.join(sorted(ROBOTS))})"
        ) from None


#: The robot a ``--platform`` value selects when it names none (planar mode: the first
#: planar robot of :data:`ROBOTS`).
DEFAULT_ROBOT = "rus6"


def _robot_of_file(path: str) -> str | None:
    """The robot a geometry TOML file is for (its ``kind`` naming a robot of
    :data:`ROBOTS`, else its fields), or None."""
    from motionbase.config import file_kind, read_toml

    try:
        table = read_toml(path)
    except ConfigError:  # unreadable: the geometry class says so, with its own message
        return None
    declared = table.get("kind")
    if isinstance(declared, str) and declared in ROBOTS:  # a plug-in's too
        return declared
    kind = file_kind(table)
    return kind if kind in ROBOTS else None


def _presets(robot: str) -> list[str]:
    """The geometry presets ``robot`` ships (in its :attr:`RobotSpec.preset_dir`)."""
    from motionbase.config import preset_names

    return preset_names(robot, ROBOTS[robot].preset_dir)


def _robot_of_preset(name: str, robots: list[str]) -> str | None:
    """The first of ``robots`` that ships a geometry preset ``name``, or None."""
    return next((robot for robot in robots if name in _presets(robot)), None)


def _names_a_file(text: str) -> bool:
    """:func:`motionbase.config.names_a_file`, with the plug-ins' preset folders
    (:attr:`RobotSpec.preset_dir`) beside motionbase's own."""
    return names_a_file(text, (spec.preset_dir for spec in ROBOTS.values()))


def robot_named(name_or_path: str | None) -> str | None:
    """The robot a ``--platform`` value names (the robot's name, one of its geometry presets
    or a TOML file of its geometry), or None when it names none that is known."""
    if name_or_path is None:
        return None
    text = str(name_or_path)
    if text in ROBOTS:
        return text
    if _names_a_file(text):
        return _robot_of_file(text)
    return _robot_of_preset(text, list(ROBOTS))


def names_planar_robot(name_or_path: str | None) -> bool:
    """True when a ``--platform`` value names a planar robot: the robot's name, one of its
    geometry presets or a TOML file of its geometry (for the commands that take either mode
    from the value alone, having no ``--planar``)."""
    robot = robot_named(name_or_path)
    return robot is not None and ROBOTS[robot].planar


def _other_mode(value: str, what: str, planar: bool) -> ConfigError:
    """The error for a ``--platform`` value that names a robot of the other mode: ``what``
    it names, that robot's mode, and the flag to change."""
    mode, flag = ("not a planar", "drop --planar") if planar else ("a planar", "add --planar")
    return ConfigError(f"--platform {value}: {what} {mode} robot ({flag})")


def load_geometry(name_or_path: str | None, *, planar: bool = False) -> tuple[str, Any]:
    """The robot and geometry a ``--platform`` value names.

    Parameters
    ----------
    name_or_path : str or None
        One of

        * None: the default robot's default preset (:data:`DEFAULT_ROBOT`, or in planar mode
          the planar robot's);
        * a robot's name (``rus6``, ``stewart6``): its default preset;
        * a geometry preset name of any robot of the mode (``ceart``, ``seat``; the 6-DOF
          robots are searched in :data:`ROBOTS` order);
        * a TOML path: the robot its ``kind`` field names, or else the robot whose fields
          it has (a 6-DOF robot's file given with ``planar`` is refused, and vice versa,
          with one line saying which flag to use).
    planar : bool
        Planar mode (``--planar``): a planar robot (the 3-RRR).

    Returns
    -------
    (robot name, geometry)

    Raises
    ------
    ConfigError
        Unknown preset, or a file or robot of the other mode.
    """
    from motionbase.config import resolve_preset_or_path

    candidates = [name for name, spec in ROBOTS.items() if spec.planar == planar]
    default = candidates[0] if planar else DEFAULT_ROBOT
    robot = default
    value = name_or_path
    if value in ROBOTS:
        if ROBOTS[value].planar != planar:
            raise _other_mode(value, f"the {ROBOTS[value].description} is", planar)
        robot, value = value, None
    elif value is not None:
        text = str(value)
        if _names_a_file(text):
            found = _robot_of_file(text)
            if found is not None and ROBOTS[found].planar == planar:
                robot = found
        else:
            # the mode's robots first; a preset of the other mode's is refused by name
            found = _robot_of_preset(text, candidates) or _robot_of_preset(text, list(ROBOTS))
            if found is None:
                names = sorted({name for r in candidates for name in _presets(r)})
                raise ConfigError(
                    f"unknown {default} preset {text!r} (nor any other robot's): choose a "
                    f"robot ({', '.join(candidates)}), a preset ({', '.join(names)}) or give "
                    "a path to a .toml file"
                )
            if ROBOTS[found].planar != planar:
                raise _other_mode(text, f"a preset of the {ROBOTS[found].description},", planar)
            robot = found
    spec = ROBOTS[robot]
    path = resolve_preset_or_path(robot, value or spec.default_preset, spec.preset_dir)
    return robot, spec.geometry_type.from_toml(path)
