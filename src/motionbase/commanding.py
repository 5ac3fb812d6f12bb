"""The pipeline without cueing: sources of robot poses or of actuator positions.

Teleoperation (a cursor gives the robot's pose) and the motor wiring check (a sweep of
actuator positions) run through the loop every flight runs through,
:func:`motionbase.pipeline.run`: the same clock and pacing, stop and E-stop, stop
signals, watchdog (a source's ``fresh`` mark), fault handling and parking, and the same
safety limiter (:func:`motionbase.stages.limit_stage`). Only what comes before the
limiter differs: :class:`CommandPipeline` takes the place of
:class:`~motionbase.pipeline.Pipeline` (it has the interface ``run`` drives: ``step``,
``stop``, ``estop``, ``estopped``, ``phase``, ``parked``, ``command``, ``speed``,
``robot``, ``health``, ``dt``; the shared part is :class:`~motionbase.pipeline.PipelineCore`).
Its source yields :class:`Command` samples.

Two modes
---------
``"actuators"`` (the wiring check): a command is the actuator positions themselves. The
stages are those of a flight after the cueing (:func:`motionbase.stages.after_cueing`)
with the inverse kinematics replaced by the identity: the soft start and stop blend from
park (in actuator space, over ``soft_start_s``; at once on an E-stop), then the limiter.

``"poses"`` (teleoperation): a command is a robot pose (the 3-RRR's ``[x, y, phi]``).

* While running: the robot's workspace clamp (toward neutral; ``clamp=False`` refuses
  unreachable poses instead), the inverse kinematics, the *approach* stage below, the
  limiter. A valid pose that the straight segment from neutral reaches only through
  invalid ones (udesc's pocket beyond a band near a type II singularity, which no path of
  valid poses reaches) is clamped from its first invalid point, or refused. A refused
  target (non-finite, unreachable), no input yet, or stale input (the source marks it not
  fresh) brakes the robot to rest where it is until a usable target comes: along the
  straight pose line of the approach it is moving on (below), else with every actuator's
  speed scaled alike (:func:`motionbase.stages.brake_stage`).
* Approach (far jumps): a parallel robot's actuators must move together, or the mechanism
  leaves its assembly during a large jump. When the limiter cannot reach the target in one
  tick, the target it is given is the point of the straight pose segment from the current
  pose toward the goal whose actuators lie one planned step away, the step planned by the
  limiter's own law on one virtual axis at 60 % of the limits
  (:func:`motionbase.stages.approach_stage`). When that segment leaves the valid poses (a
  workspace that is not convex), the robot goes to neutral first, to rest there, then on.
  A target that changes while the robot moves (a turn at speed the actuators cannot make
  together), or comes nearer than the robot can stop, is not approached at once: the robot
  brakes along the straight pose line it is on, each command a pose of it, until the new
  segment can be followed. The limits themselves are enforced by the limiter alone, which
  every command passes.
* Stopping (a stop or an E-stop, the end of the input): brake to rest where the robot is,
  then go home (the park pose) along the approach above, then parked. Home, not where the
  input left it: the next run starts there. When home is not reached within
  ``max_home_s`` the robot brakes to rest where it is, and the pipeline reports itself
  parked there.
* ``platform_pose`` is the pose the actuators realise: the goal when the limiter sent it
  unchanged, else forward kinematics of the command.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any, NamedTuple

import numba
import numpy as np

from motionbase import stages
from motionbase.errors import ConfigError
from motionbase.pipeline import Health, PipelineCore, PipelineOutput, check_rate
from motionbase.platform.output_map import sweep_profile
from motionbase.platform.robot import SOLVE_SIGNATURE, Robot
from motionbase.safety import ActuatorLimits
from motionbase.state import PHASES
from motionbase.stopping import StopRequest

__all__ = ["MODES", "Command", "CommandPipeline", "SweepSource", "check_sweep_range"]

MODES = ("actuators", "poses")

# Stopping in pose mode: braking to rest; going home from rest; braking to rest where it
# is after ``max_home_s``; at rest there.
_BRAKE, _HOME, _BRAKE_LAST, _DONE = range(4)


class Command(NamedTuple):
    """One sample of a command source.

    Attributes
    ----------
    t : float
        Time, s (the source's clock; the pipeline's output keeps it).
    target : ndarray or None
        Actuator positions (n,) in the robot's unit, or a robot pose (m,); None: no input
        yet (the robot holds where it is).
    info : object
        Passed through to the sinks in ``PipelineOutput.state`` (a cursor's pixel).
    """

    t: float
    target: np.ndarray | None
    info: Any = None


@numba.njit(SOLVE_SIGNATURE, cache=True)
def _as_given(G, target, cue_out, pose_out, q_out):  # pragma: no cover - compiled
    """The robot kernel of actuator mode: the target *is* the actuator command."""
    n = int(G[0])
    for i in range(6):
        cue_out[i] = target[i]
    for i in range(n):
        q_out[i] = target[i]
        pose_out[i] = target[i]
    return False


class CommandPipeline(PipelineCore):
    """The pipeline's safety stages driven by robot poses or actuator positions.

    Parameters
    ----------
    robot : Robot
    rate_hz : float
        Tick rate, Hz (as the pipeline's: 10 Hz to 10 kHz).
    mode : {"poses", "actuators"}
    soft_start_s : float
        Actuator mode: the blend from park and back, s.
    clamp : bool
        Pose mode: clamp unreachable poses toward neutral (else refuse them).
    max_home_s : float
        Pose mode: longest time given to braking and going home after a stop, s.

    Attributes
    ----------
    health : Health
        ``clamps``, ``rate_limited`` (the target could not be reached in one tick) and
        ``unsafe_commands`` (targets refused or held) count the running phase only;
        ``watchdog_fades`` counts the times the input went stale.
    no_input, stale_ticks, trims, park_ticks : int
        Pose mode: running ticks without input yet, running ticks holding on stale input,
        running ticks on which the limiter changed the (approach) command, ticks after
        the stop.
    """

    def __init__(
        self,
        robot: Robot,
        *,
        rate_hz: float,
        mode: str = "poses",
        soft_start_s: float = 2.0,
        clamp: bool = True,
        max_home_s: float = 10.0,
    ) -> None:
        if mode not in MODES:
            raise ConfigError(f"command pipeline: mode must be one of {MODES}, got {mode!r}")
        for name, value in (("soft_start_s", soft_start_s), ("max_home_s", max_home_s)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"command pipeline: {name} must be > 0, got {value!r}")
        check_rate(rate_hz, "command pipeline")
        self.robot = robot
        self.mode = mode
        self.dt = 1.0 / float(rate_hz)
        self.clamp = bool(clamp)
        self.soft_start_s = float(soft_start_s)
        self.health = Health()
        n = robot.n
        # actuator mode: the blend runs in actuator space and the "pose" is the actuators
        actuators = mode == "actuators"
        self._m = n if actuators else len(robot.park_pose)
        self.params = stages.new_params(
            robot,
            dt=self.dt,
            soft_start_s=soft_start_s,
            park_cue=robot.park_angles if actuators else np.zeros(6),
            park_pose=robot.park_angles if actuators else robot.park_pose,
        )
        self.state = np.zeros(1, dtype=stages.STATE)  # (reset below)
        self._max_home_ticks = int(round(max_home_s / self.dt))
        lim = robot.limits
        # the approach's virtual axis: progress along the path in actuator units (max
        # norm), planned at 60 % of the limits: where the path bends in actuator space the
        # limiter trims the step, and a trimmed command may be no pose at all (the linkage
        # pushed against itself). 400 jumps in teleop's default rectangle, either preset:
        # at 80 %, 9 jumps of udesc had ticks no pose held; at 60 %, none. (Across udesc's
        # whole phi = 0 workspace, not convex, 76 of 200 random jumps had some: their straight
        # path left it. Via neutral, none: tests/test_teleop_jumps.py. A new far target every
        # 0.3 s, the robot turning at speed: 99 of 300 jumps on udesc, 8 on udesc_symmetric,
        # until a trimmed plan was no longer sent while braking along the path could be)
        self._path_limits = ActuatorLimits.broadcast(
            1, -1e3, 1e3, 0.6 * float(lim.max_speed.min()), 0.6 * float(lim.max_accel.min())
        )
        self._solve = stages.kernel_list(_as_given, stages.SOLVE_LIST)
        self._G = np.array([float(n)])
        self._cue = np.zeros(6)  # actuator mode: the held target, padded to 6 (with zeros)
        self._target = np.empty(6)
        self._cue_out = np.empty(6)
        self._wanted = np.empty(n)
        self._no_cue = np.zeros(6)
        self._no_cue.setflags(write=False)
        self.reset()
        self.warm_up()

    # -- lifecycle -------------------------------------------------------------
    def reset(self) -> None:
        """Parked, at rest, no command seen; counters kept."""
        stages.reset_state(self.state, self.params)
        self._cue[: self.robot.n] = self.robot.park_angles
        self._pose = np.array(self.robot.park_pose, dtype=float)
        self._sub = _BRAKE
        self._ticks = self._deadline = 0
        self._stale = False
        self._seen: tuple[Any, np.ndarray | None] = (None, None)  # a target, its blocked_at
        self.no_input = self.stale_ticks = self.trims = self.park_ticks = 0

    def _warm_ticks(self) -> None:
        park = self.robot.park_angles if self.mode == "actuators" else self.robot.park_pose
        self.step(Command(0.0, np.array(park, dtype=float)))
        self.step(None)  # running without input: the brake stage
        # the approach's plan of a far jump (the limiter's kernel on one virtual axis)
        stages.path_step(1.0, 0.0, float(self.params[0]["dt"]), self._path_limits)
        stages.brake_speed(1.0, 1.0, 1.0)  # (and its braking distance, called from Python)
        self.stop()
        self.step(None)
        stages.brake_stage(self.params, self.state, np.empty(self.robot.n))  # (when the ticks
        # above braked along the approach's line alone, as on the 6-RUS; reset follows)

    def stop(self) -> None:
        """Head for park: actuator mode, the blend back over ``soft_start_s``; pose mode,
        brake to rest, then home."""
        s = self.state[0]
        if self.mode == "poses" and s["phase"] in (stages.STARTING, stages.RUNNING):
            s["blend"] = 0.0
            self._sub = _BRAKE
            self._deadline = self._ticks + self._max_home_ticks
        super().stop()

    def estop(self) -> None:
        """Emergency stop: actuator mode, head for park at once within the limits; pose
        mode, as :meth:`stop` (braking first is the fastest safe way for a parallel robot)."""
        if self.mode == "poses":
            self.stop()  # (then counted and flagged; phase and blend are stopping and 0 already)
        super().estop()

    @property
    def parked(self) -> bool:
        """Stopped at park and at rest (pose mode: or at rest where home was given up)."""
        return super().parked or (
            self.mode == "poses"
            and self._sub in (_BRAKE_LAST, _DONE)
            and self.state[0]["phase"] == stages.STOPPING
            and not self.speed.any()
        )

    # -- one tick --------------------------------------------------------------
    def _usable(self, cmd: Command | None, size: int) -> tuple[np.ndarray | None, bool]:
        """The command's target if usable: (target or None, rejected)."""
        if cmd is None or cmd.target is None:
            return None, False
        x = np.asarray(cmd.target, dtype=float)
        if x.shape != (size,) or not np.isfinite(x).all():
            self.health.rejected_inputs += 1
            self.health.last_rejection = f"target {np.round(x, 6).tolist()} is not {size} numbers"
            return None, True
        return x, False

    def step(self, cmd: Command | None, fresh: bool = True) -> PipelineOutput:
        """Advance one tick with the source's command (None: none, e.g. after its end).

        Parameters
        ----------
        cmd : Command or None
        fresh : bool
            False when the source says its input went stale (pose mode: hold).
        """
        self.health.samples += 1
        self._ticks += 1
        s = self.state[0]  # the time: the command's, unless it does not advance (then + dt)
        last = float(s["t"]) if s["has_t"] else -self.dt
        t = last + self.dt
        if cmd is not None and math.isfinite(cmd.t) and cmd.t > last:
            t = float(cmd.t)
        s["t"], s["has_t"] = t, True
        if self.mode == "actuators":
            return self._step_actuators(cmd, t)
        return self._step_poses(cmd, t, fresh)

    def _step_actuators(self, cmd: Command | None, t: float) -> PipelineOutput:
        n = self.robot.n
        x, rejected = self._usable(cmd, n)
        if x is not None:
            self._cue[:n] = x
        q = np.empty(n)
        act = np.empty(n)
        flags = stages.after_cueing(
            self.params, self.state, self._solve, self._G, self._cue, self._target,
            self._cue_out, act, self._wanted, q,
        )  # fmt: skip
        self.health.count(flags & ~stages.PROBLEM)
        pose = self.robot.forward(q, guess=self._pose)
        if np.isfinite(pose).all():
            self._pose = pose
        return PipelineOutput(
            t, cmd, True, cmd is not None and not rejected, self._no_cue, self._pose, False, q,
            self.robot.servo(q), bool(flags & stages.RATE_LIMITED), bool(flags & stages.HELD),
            PHASES[flags >> stages.PHASE_SHIFT], 1.0,
        )  # fmt: skip

    def _step_poses(self, cmd: Command | None, t: float, fresh: bool) -> PipelineOutput:
        P, S, robot, health = self.params, self.state, self.robot, self.health
        s = S[0]
        n, m = robot.n, self._m
        if s["phase"] == stages.STARTING:
            s["phase"] = stages.RUNNING  # no blend: the approach and the limiter pace it
        running = s["phase"] == stages.RUNNING
        goal: np.ndarray | None = None
        clamped = refused = False
        x, rejected = self._usable(cmd, m)
        if running:
            if cmd is None or cmd.target is None:
                self.no_input += 1
            elif x is None:
                refused = True
            else:
                pose = x
                if self.clamp:
                    pose, moved = robot.clamp(x)
                    pose = np.asarray(pose, dtype=float)
                    clamped = bool(moved)
                # a valid pose behind invalid ones, seen from neutral: clamped (refused) too
                if not np.array_equal(pose, self._seen[0]):  # the check, once per target
                    self._seen = (pose.copy(), stages.blocked_at(robot, robot.neutral_pose, pose))
                edge = self._seen[1]
                if edge is not None and self.clamp:
                    pose, clamped = np.asarray(robot.clamp(edge)[0], dtype=float), True
                health.clamps += clamped
                refused = not robot.reachable(pose) or edge is not None and not self.clamp
                goal = None if refused else pose
                if not fresh and not self._stale:
                    health.watchdog_fades += 1
                self._stale = not fresh
                if self._stale:
                    self.stale_ticks += 1
                    goal = None
            health.unsafe_commands += refused
        else:
            self.park_ticks += 1
            if self._sub == _BRAKE and not self.speed.any():  # at rest
                self._sub = _HOME if self._ticks <= self._deadline else _DONE
            if self._sub == _HOME and self._ticks > self._deadline:
                self._sub = _BRAKE_LAST  # home not reached in time: to rest where it is
            if self._sub == _HOME:
                goal = np.array(robot.park_pose, dtype=float)
        q = np.empty(n)
        before = self._pose
        # no goal: to rest where it is, along the approach's line if it moves on one
        along = goal is None and s["v"][:n].any() and not np.isnan(s["leg"][0])
        if goal is None and not along:
            q_prev = s["q"][:n].copy()
            flags = stages.brake_stage(P, S, q)
            new_pose = before if np.array_equal(q, q_prev) else None
        else:  # the approach toward a valid pose, counted in the health while running
            flags, limited, new_pose = stages.approach_stage(
                P, S, robot, before if along else goal, q, self._path_limits
            )
            counted = running and not along
            if limited:
                health.rate_limited += counted
                if flags:  # the limiter changed the approach's command too
                    self.trims += counted
            elif flags & stages.HELD:  # valid by the kinematics, yet a hair outside a limit
                health.unsafe_commands += counted
        if new_pose is None:  # the actuators realise another pose than the one asked
            achieved = np.asarray(robot.forward(q, guess=before), dtype=float)
            new_pose = achieved if np.isfinite(achieved).all() else before
        self._pose = np.array(new_pose, dtype=float)
        s["pose"][:m] = self._pose
        return PipelineOutput(
            t, cmd, bool(fresh), cmd is not None and not rejected, self._no_cue, self._pose,
            clamped, q, robot.servo(q), bool(flags & stages.RATE_LIMITED),
            refused or self._stale and running or bool(flags & stages.HELD), self.phase,
            0.0 if self._stale and running else 1.0,
        )  # fmt: skip


# --------------------------------------------------------------------------- the sweep

#: Steps per side of each actuator's sweep at which :func:`check_sweep_range` solves the
#: forward kinematics (each from the step before: the assembly the robot moves through).
SWEEP_CHECK_STEPS = 200


def check_sweep_range(
    robot: Robot, neutral: np.ndarray, range_: float, motors: Sequence[int] | None = None
) -> None:
    """A ConfigError unless the wiring check can move each actuator alone ``+-range_``
    about ``neutral``, the others held there, through poses the robot can take
    (:meth:`Robot.reachable`), along the assembly it is in. The range must be one that
    :func:`~motionbase.platform.output_map.sweep_profile` has found within the actuator
    limits.

    A parallel robot whose actuator moves alone moves its platform: past some offset no
    pose has every leg at its length (the 3-RRR's servos at about 12 deg from home),
    and before it the platform nears a singularity and spins. The drive would push the
    linkage against itself there, though every actuator is within its limits.

    Parameters
    ----------
    robot : Robot
    neutral : ndarray, shape (n,)
        The actuators at the neutral pose (rad or m).
    range_ : float
        Half-range of each sweep, in the robot's actuator unit (> 0).
    motors : sequence of int, optional
        The actuators swept (0-based); default every one.
    """
    linear = robot.actuator_unit == "m"
    unit, scale, option = (
        ("mm", 1e3, "--range-mm") if linear else ("deg", 180 / math.pi, "--range-deg")
    )
    shown = f"+-{range_ * scale:g} {unit}"
    lim = robot.limits
    neutral_pose = np.asarray(robot.neutral_pose, dtype=float)
    fractions = np.arange(1, SWEEP_CHECK_STEPS + 1) / SWEEP_CHECK_STEPS
    for i in range(robot.n) if motors is None else motors:
        for side in (1.0, -1.0):
            pose = neutral_pose
            for f in fractions:
                q = neutral.copy()
                q[i] += side * f * range_
                pose = robot.forward(q, guess=pose)
                ok = np.isfinite(pose).all() and np.allclose(
                    robot.inverse(pose), q, rtol=0.0, atol=1e-9
                )
                if ok and not np.all(robot.reachable(pose)):
                    # a pose at an actuator limit itself may read as a hair outside it
                    inside = q.copy()
                    inside[i] -= side * 1e-9
                    at_limit = not lim.lower[i] < q[i] < lim.upper[i]
                    probe = robot.forward(inside, guess=pose)
                    ok = (
                        at_limit
                        and np.isfinite(probe).all()
                        and bool(np.all(robot.reachable(probe)))
                    )
                if not ok:
                    raise ConfigError(
                        f"output test: actuator {i + 1} alone at {side * f * range_ * scale:+.3g} "
                        f"{unit} from neutral takes the robot out of its workspace (no pose, or "
                        f"one too near a singularity, holds its legs there): {shown} is too "
                        f"far for a sweep of one actuator at a time (choose a smaller {option})"
                    )


class SweepSource(Iterator[Command]):
    """The wiring check as a command source: actuator targets that rest at park, move to
    neutral, take each actuator in turn through ``+range, -range`` about neutral and back,
    return to park and rest (:func:`motionbase.platform.output_map.sweep_profile`), after
    :func:`check_sweep_range` has found every actuator's sweep one the robot can follow.

    Each command's ``info`` is the actuator being moved (1-based; 0 on the way from or to
    park): a display can say which (``motionbase output --test`` prints a line when it
    changes); the source itself prints nothing. Once ``stop`` is raised it holds its current
    target, with ``info`` None (the pipeline then ramps to park).

    Parameters
    ----------
    robot : Robot
    range_ : float
        Half-range about neutral, in the robot's actuator unit (rad or m).
    speed : float
        Peak speed of the sweep, unit/s (capped by the slowest actuator's limit).
    rate_hz : float
        The pipeline's rate, Hz (one target per tick).
    lead_s : float
        Rest at park first, s (give the pipeline's soft start: the sweep then starts
        when the blend from park is complete, so it is not scaled down).
    stop : StopRequest, optional
    motors : sequence of int, optional
        The actuators to sweep (0-based, in this order); default every one.

    Attributes
    ----------
    speed, accel : float
        The sweep's peak speed and acceleration, unit/s and unit/s^2.
    """

    def __init__(
        self,
        robot: Robot,
        *,
        range_: float,
        speed: float,
        rate_hz: float,
        lead_s: float,
        stop: StopRequest | None = None,
        motors: Sequence[int] | None = None,
    ) -> None:
        lim = robot.limits
        self.speed = min(float(speed), float(lim.max_speed.min()))
        self.accel = 0.5 * float(lim.max_accel.min())
        self.dt = 1.0 / rate_hz
        self.neutral = np.asarray(robot.inverse(robot.neutral_pose), dtype=float)
        targets, motor = sweep_profile(
            robot.park_angles, self.neutral, lim.lower, lim.upper, range_rad=range_,
            speed=self.speed, accel=self.accel, dt=self.dt, dwell_s=0.2,
            linear=robot.actuator_unit == "m", motors=motors,
        )  # fmt: skip
        check_sweep_range(robot, self.neutral, range_, motors)  # (in the limits: sweep_profile)
        lead = max(1, math.ceil(lead_s / self.dt))
        rest = max(1, int(0.2 / self.dt))
        self.targets = np.pad(targets, ((lead, rest), (0, 0)), mode="edge")  # rest at both ends
        self.motor = np.pad(motor, (lead, rest))  # (motor 0: none)
        self.stop = stop
        self._k = 0
        self._held: int | None = None

    def __next__(self) -> Command:
        k = self._k
        if self._held is None and self.stop:
            self._held = max(0, k - 1)  # frozen where it was
        if self._held is not None:
            self._k += 1
            return Command(k * self.dt, self.targets[self._held])
        if k >= len(self.targets):
            raise StopIteration
        self._k += 1
        return Command(k * self.dt, self.targets[k], int(self.motor[k]))
