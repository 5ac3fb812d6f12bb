"""The pipeline's own stages, each one compiled function with named state in and out.

The tick (:meth:`motionbase.pipeline.Pipeline.step`) is::

    input_stage -> cueing.advance -> after_cueing (blend_stage -> robot.solve_kernel
                -> limit_stage, or path_stage for a coordinated robot)
                -> cueing.track (when the clamp acted while running)

Commands that are robot poses (teleoperation, :mod:`motionbase.commanding`) go through
:func:`approach_stage` (Python: it calls the robot's inverse kinematics) or
:func:`brake_stage`, each ending in :func:`limit_stage`.

The cueing and the robot are plug-ins (:mod:`motionbase.washout.cueing`,
:mod:`motionbase.platform.robot`); everything else is here. Every function works like
``scipy.signal.sosfilt``'s ``zi -> zf``: the state goes in and comes out changed, nothing
is hidden. The state and the constants are numpy *records* (structured arrays of one
element, :data:`STATE` and :data:`PARAMS`) whose fields have names, units and meanings
(below); numba reads and writes them by name.

The same functions run the real-time tick and the batch path (:func:`run_batch`, a whole
flight in compiled code), so batch equals streaming bit for bit
(``tests/test_pipeline_batch.py``).

Units: s, m/s^2, rad/s, rad; actuator positions in the robot's unit (rad or m). Arrays
of actuator values have room for 6; the first ``n`` (the robot's) are used.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types

from motionbase.physics import STANDARD_GRAVITY, brake_speed, smoothstep, track_toward
from motionbase.platform.robot import SOLVE_SIGNATURE
from motionbase.safety import ActuatorLimits, input_code, limit_command, limit_kernel
from motionbase.washout.cueing import STEP_SIGNATURE, TRACK_SIGNATURE

#: Codes of the soft start and stop's phases (``STATE.phase``; names in ``PHASES``).
STARTING, RUNNING, STOPPING, PARKED = range(4)

#: The pipeline's state, one record (units in the comments).
STATE = np.dtype(
    [
        # input stage: validation and the watchdog fade
        ("t", "f8"),  # time of the last tick, s (source clock)
        ("has_t", "?"),  # False before the first tick
        ("t_accepted", "f8"),  # time of the last accepted sample, s
        ("t_tick_accepted", "f8"),  # time of the tick that accepted it, s (later when the
        # clock of rejected ticks ran past the samples: see input_stage)
        ("has_sample", "?"),  # a sample was accepted (else the input is level flight)
        ("sample", "f8", (6,)),  # held sample: specific force (m/s^2), body rates (rad/s)
        ("fade", "f8"),  # watchdog fade in [0, 1]: share of the held sample given on
        ("stale", "?"),  # the input is stale (marked so, or nothing accepted lately)
        # soft start / stop
        ("phase", "i8"),  # STARTING, RUNNING or STOPPING
        ("blend", "f8"),  # the ramp's progress in [0, 1]; the live pose's share is
        # smoothstep(blend), or blend itself while turning
        ("blend_speed", "f8"),  # the share's rate, 1/s (> 0 only while starting)
        ("turning", "?"),  # a stop came during the start: the share brakes back to 0
        ("estop", "?"),  # an E-stop: park at the actuators' limits, no blend
        # safety limiter (actuator units)
        ("q", "f8", (6,)),  # last command
        ("v", "f8", (6,)),  # its speed, per s
        ("wanted", "f8", (6,)),  # last target the limiter accepted
        ("pose", "f8", (6,)),  # robot pose the last command realises (first m used)
        ("cue", "f8", (6,)),  # the cue pose it realises (the path stage's start)
        ("step", "f8", (6,)),  # that cue pose's last step (the path stage's braking line)
        ("leg", "f8", (6,)),  # approach: goal pose of the straight segment followed (NaN: none)
    ],
    align=True,
)

#: The pipeline's constants, one record.
PARAMS = np.dtype(
    [
        ("dt", "f8"),  # tick period, s
        ("stale_timeout", "f8"),  # s
        ("fade_step", "f8"),  # fade change per tick, dt / fade_s
        ("blend_step", "f8"),  # blend change per tick, dt / soft_start_s
        ("max_f", "f8"),  # input plausibility bounds: m/s^2, rad/s, rad
        ("max_w", "f8"),
        ("max_att", "f8"),
        ("level", "f8", (6,)),  # level flight input: (0, 0, -g, 0, 0, 0)
        ("park_cue", "f8", (6,)),  # cue pose of the park pose
        ("park_pose", "f8", (6,)),  # robot pose at park (first m used)
        ("park_q", "f8", (6,)),  # actuator command at park
        ("lower", "f8", (6,)),  # actuator limits
        ("upper", "f8", (6,)),
        ("max_speed", "f8", (6,)),
        ("max_accel", "f8", (6,)),
        ("n", "i8"),  # number of actuators
        ("m", "i8"),  # size of the robot pose
        ("path", "?"),  # the coordinated limit (path_stage) is on: robot.coordinated
    ],
    align=True,
)

# Status bits of a tick.
PROBLEM = 0xF  # input problem code (safety.INPUT_PROBLEMS), 0 = accepted
TIME_JUMP = 1 << 4
FADE_START = 1 << 5
CLAMPED = 1 << 6
RATE_LIMITED = 1 << 7
HELD = 1 << 8
CUEING_ERROR = 1 << 9
RUNNING_CLAMP = 1 << 10  # clamped while running: the cueing is to be told (anti-windup)
PATH = 1 << 11  # the path stage's command: the pose it realises is known (path_stage)
PHASE_SHIFT = 12  # two bits: the output phase (PHASES)
#: The bits the health counts (and where the limiter acted, the pose to find): rare.
RARE = PROBLEM | TIME_JUMP | FADE_START | CLAMPED | RATE_LIMITED | HELD

_STATE_T = numba.from_dtype(STATE)[::1]
_PARAMS_T = numba.from_dtype(PARAMS)[::1]
_vec = numba.float64[::1]
#: Typed lists holding one compiled plug-in function each (:func:`kernel_list`).
SOLVE_LIST = types.ListType(types.FunctionType(SOLVE_SIGNATURE))
STEP_LIST = types.ListType(types.FunctionType(STEP_SIGNATURE))
TRACK_LIST = types.ListType(types.FunctionType(TRACK_SIGNATURE))


def _holder(list_type):
    """A compiled, cached function ``kernel -> typed list [kernel]`` for one list type."""

    @numba.njit(list_type(list_type.item_type), cache=True)
    def hold(kernel):  # pragma: no cover - compiled
        out = numba.typed.List()
        out.append(kernel)
        return out

    return hold


#: One per list type (a numba function that is not compiled yet, a plug-in's lazily
#: compiled kernel, is compiled for the signature its list asks for).
_HOLDERS = {list_type: _holder(list_type) for list_type in (SOLVE_LIST, STEP_LIST, TRACK_LIST)}


def kernel_list(kernel, list_type) -> numba.typed.List:
    """A typed list holding ``kernel`` as a first-class function, what compiled stages call.

    Passing a numba dispatcher itself costs a type lookup every call (tens of us); the
    list's type is known at once, so a call through it costs about a microsecond. The list
    is built by a compiled, cached function: built from Python, numba would compile the
    typed list's methods for the item type in every process (0.5-1.4 s of start-up).
    """
    try:
        return _HOLDERS[list_type](kernel)
    except (TypeError, numba.core.errors.NumbaError):
        raise TypeError(
            f"{kernel} is not a numba function that compiles as {list_type.item_type}"
        ) from None


def bind(kernel, *args):
    """``kernel`` compiled for the types of ``args``, called without numba's dispatch.

    A numba function looks up its compiled version from its arguments' types at every call
    (about 0.1-0.5 us an array, more for a record array or a typed list); the tick calls
    its stages with the same buffers every time, so it resolves that once. The function
    returned checks nothing but each array's item size: give it arguments of exactly the
    types of ``args`` (dtype, number of dimensions, C order), the pipeline's own buffers.

    Raises
    ------
    TypeError
        ``kernel`` has declared signatures and ``args`` match none (a plug-in's read-only
        or float32 vector, say): the message gives the types it takes and those given.
    """
    types = tuple(numba.typeof(a) for a in args)
    declared = kernel.overloads.get(types)  # a kernel compiled for its declared signature
    if declared is not None:
        return declared.entry_point
    try:
        return kernel.compile(types)
    except RuntimeError:  # numba's "compilation disabled": declared signatures only, not these
        want, got = (", ".join(map(str, sig)) for sig in (kernel.signatures[0], types))
        raise TypeError(f"{kernel.__name__} takes ({want}), not ({got})") from None


def new_params(
    robot,
    *,
    dt: float,
    soft_start_s: float,
    stale_timeout_s: float = np.inf,
    fade_s: float = 1.0,
    input_limits=None,
    park_cue: np.ndarray | None = None,
    park_pose: np.ndarray | None = None,
) -> np.ndarray:
    """The :data:`PARAMS` record for a robot (:class:`~motionbase.platform.robot.Robot`).

    ``dt``, ``soft_start_s``, ``stale_timeout_s`` and ``fade_s`` in s; ``input_limits`` a
    :class:`~motionbase.safety.InputLimits` (None: no bounds, for commands that are not
    aircraft samples). ``park_cue`` (up to 6) and ``park_pose`` (m) default to the robot's;
    the size of the robot pose ``m`` is that of ``park_pose``.
    """
    park_cue = robot.park_cue if park_cue is None else park_cue
    park_pose = robot.park_pose if park_pose is None else park_pose
    n, m = robot.n, len(park_pose)
    P = np.zeros(1, dtype=PARAMS)
    p = P[0]
    p["dt"] = dt
    p["stale_timeout"] = stale_timeout_s
    p["fade_step"] = dt / fade_s
    p["blend_step"] = dt / soft_start_s
    if input_limits is not None:
        p["max_f"] = input_limits.max_specific_force
        p["max_w"] = input_limits.max_angular_velocity
        p["max_att"] = input_limits.max_attitude
    else:
        p["max_f"] = p["max_w"] = p["max_att"] = np.inf
    p["level"][2] = -STANDARD_GRAVITY
    p["park_cue"][: len(park_cue)] = park_cue
    p["park_pose"][:m] = park_pose
    p["park_q"][:n] = robot.park_angles
    for name in ("lower", "upper", "max_speed", "max_accel"):  # the actuator limits
        p[name][:n] = getattr(robot.limits, name)
    p["n"] = n
    p["m"] = m
    p["path"] = robot.coordinated
    return P


def reset_state(S: np.ndarray, P: np.ndarray) -> None:
    """Parked, at rest, no sample seen; the fade full (nothing stale yet)."""
    S[0] = np.zeros((), dtype=STATE)
    s = S[0]
    s["q"] = s["wanted"] = P[0]["park_q"]
    s["pose"] = s["leg"] = P[0]["park_pose"]
    s["cue"] = P[0]["park_cue"]
    s["phase"] = STARTING
    s["fade"] = 1.0


@numba.njit(cache=True)
def input_stage(P, S, present, t, f, w, att, fresh, u):  # pragma: no cover - compiled
    """Validation and the watchdog fade: this tick's sample to the cueing's input ``u``.

    Parameters
    ----------
    P, S : PARAMS and STATE records (arrays of one)
    present : bool
        A sample came this tick (False on the park ticks after the source ended: the
        last one is held and its time advances by ``dt``).
    t : float
        Sample time, s.
    f, w, att : ndarray, shape (3,)
        Specific force (m/s^2), body rates (rad/s), attitude (rad), body axes FRD.
    fresh : bool
        False when the source marked the sample a stale hold.
    u : ndarray, shape (6,)
        Out: ``[f, w]`` for the cueing: the held sample (level flight before any),
        faded toward level flight while the input is stale.

    Returns
    -------
    int
        Status bits: ``PROBLEM`` (why the sample was rejected: it is then replaced by
        the held one), ``TIME_JUMP``, ``FADE_START``.

    Notes
    -----
    A sample is new when it is later than the last accepted one. A rejected sample's
    time is the last tick's plus ``dt``, so output times always increase; when that guess
    runs past the source's clock (a sample sent twice: the copy is rejected), the next
    new sample is accepted, its tick's time the last tick's plus ``dt``. (Checking new
    samples against the tick clock rejected them, each rejection moving the clock on:
    one duplicate lost most of the rest of a recording.) A forward jump longer than
    ``stale_timeout`` restarts the input from level flight (the fade to 0) and fades it
    into the new samples; the cueing's filters keep their state, so its pose stays
    continuous.
    """
    p = P[0]
    s = S[0]
    flags = 0
    accepted = False
    if present:
        # new: later than the last accepted sample (not than the tick clock, which the
        # rejected ticks moved on by a guess)
        last = s.t_accepted if s.has_sample else -np.inf
        flags = input_code(t, last, f, w, att, p.max_f, p.max_w, p.max_att)
        accepted = flags == 0
    if accepted:
        if s.has_t and t - s.t > p.stale_timeout:
            flags |= TIME_JUMP
            s.fade = 0.0
        s.has_sample = True
        for i in range(3):
            s.sample[i] = f[i]
            s.sample[3 + i] = w[i]
        # the tick's time: the sample's, unless the clock of rejected ticks is past it
        s.t = t if not s.has_t or t > s.t else s.t + p.dt
        s.t_accepted = t
        s.t_tick_accepted = s.t
    else:
        s.t = (s.t if s.has_t else 0.0) + p.dt
    s.has_t = True
    # stale: marked so, or no sample accepted for longer than the timeout (on the park
    # ticks after the end only a mark counts: the park ramp is in charge)
    stale = not fresh or (present and s.t - s.t_tick_accepted > p.stale_timeout)
    if stale:
        if not s.stale:
            flags |= FADE_START
        s.fade = max(0.0, s.fade - p.fade_step)
    else:
        s.fade = min(1.0, s.fade + p.fade_step)
    s.stale = stale
    if not s.has_sample:
        for i in range(6):
            u[i] = p.level[i]
    elif s.fade == 1.0:
        for i in range(6):
            u[i] = s.sample[i]
    else:
        sf = smoothstep(s.fade)
        for i in range(6):
            u[i] = p.level[i] + sf * (s.sample[i] - p.level[i])
    return flags


@numba.njit(cache=True)
def blend_stage(P, S, cue, target):  # pragma: no cover - compiled
    """Soft start and stop: the cue pose blended from park (``target``, shape (6,)).

    The live pose's share of the target rises from 0 to 1 along a smoothstep over
    ``soft_start_s`` and the phase becomes running; stopping, it falls back the same way
    (at once on an E-stop: the limiter then paces the way to park). A stop during the
    start cannot retrace the smoothstep (the share is moving out, at up to 1.5 times its
    mean rate): the share then brakes, turns and lands on 0 within the smoothstep's own
    peak rate and acceleration (``1.5 / soft_start_s``, ``6 / soft_start_s^2``), by
    :func:`~motionbase.physics.track_toward`. Returns True when the target is park itself
    (stopping, share 0): the park command is then sent by its actuator positions exactly.
    """
    p = P[0]
    s = S[0]
    if s.phase == STARTING:
        b0 = smoothstep(s.blend)
        s.blend = min(1.0, s.blend + p.blend_step)
        s.blend_speed = (smoothstep(s.blend) - b0) / p.dt
        if s.blend >= 1.0:
            s.phase = RUNNING
            s.blend_speed = 0.0
    elif s.phase == STOPPING and not s.estop:
        if s.blend_speed > 0.0 and not s.turning:
            s.turning = True
            s.blend = smoothstep(s.blend)  # from now on the share itself
        if s.turning:
            # the smoothstep's peak speed and acceleration: 1.5 and 6 over soft_start_s (^2)
            vmax = 1.5 * p.blend_step / p.dt
            u = 6.0 * p.blend_step * p.blend_step / p.dt
            b1, _ = track_toward(s.blend, s.blend_speed, 0.0, 0.0, p.dt, 0.0, 1.0, vmax, u, 0.0)
            s.blend_speed = (b1 - s.blend) / p.dt
            s.blend = b1
        else:
            s.blend = max(0.0, s.blend - p.blend_step)
    b = s.blend if s.turning else smoothstep(s.blend)
    for i in range(6):
        target[i] = cue[i] if b >= 1.0 else p.park_cue[i] + b * (cue[i] - p.park_cue[i])
    return s.phase == STOPPING and b == 0.0


@numba.njit(cache=True)
def limit_stage(P, S, wanted, q):  # pragma: no cover - compiled
    """The safety limiter (:func:`motionbase.safety.limit_command`) on the state's command.

    ``wanted`` (n,) is the inverse kinematics' command; ``q`` (n,) receives the one sent.
    Returns ``RATE_LIMITED`` and ``HELD`` bits; updates the state's ``q``, ``v`` and
    ``wanted`` (an unsafe target is not remembered: the held command is).
    """
    p = P[0]
    s = S[0]
    n = p.n
    v = s.v[:n]  # the new speeds overwrite the old in place (the kernel allows it)
    status = limit_kernel(
        s.q[:n],
        v,
        s.wanted[:n],
        wanted,
        p.dt,
        p.lower[:n],
        p.upper[:n],
        p.max_speed[:n],
        p.max_accel[:n],
        q,
        v,
    )
    held = (status & 2) != 0
    for i in range(n):
        s.wanted[i] = q[i] if held else wanted[i]
        s.q[i] = q[i]
    return (HELD if held else 0) | (RATE_LIMITED if status & 1 else 0)


@numba.njit(cache=True)
def brake_stage(P, S, q):  # pragma: no cover - compiled
    """Coordinated braking to rest where the actuators are, through :func:`limit_stage`.

    Every actuator's speed is scaled by one factor per tick, so that all come to rest
    together in the time the slowest-braking one needs (``max |v| / max_accel``): each
    decelerates within its ``max_accel`` and keeps its direction, so a parallel robot's
    actuators stay on the path they were on. ``q`` (n,) receives the command; the
    state's ``wanted`` becomes it (nothing to feed forward). Returns
    :func:`limit_stage`'s bits.
    """
    p = P[0]
    s = S[0]
    n = p.n
    t_stop = 0.0
    for i in range(n):
        t_stop = max(t_stop, abs(s.v[i]) / p.max_accel[i])
    scale = max(0.0, 1.0 - p.dt / t_stop) if t_stop > 0.0 else 0.0
    wanted = np.empty(n)
    for i in range(n):
        wanted[i] = s.q[i] + scale * s.v[i] * p.dt
        s.wanted[i] = s.q[i]
    flags = limit_stage(P, S, wanted, q)
    for i in range(n):
        s.wanted[i] = q[i]
    s.leg[:] = np.nan  # off the approach's segment
    return flags


def approach_stage(P, S, robot, goal, q, path_limits) -> tuple[int, bool, np.ndarray | None]:
    """The limiter toward a reachable robot pose, shaped into a coordinated approach when
    the pose is out of one tick's reach (teleoperation's far jumps, the way home).

    A parallel robot's actuators must move together, or the mechanism leaves its assembly
    during a large jump. When the limiter cannot reach ``goal`` in one tick, the command it
    is given is the point of the straight pose segment from the state's pose toward the
    goal whose actuators lie one planned step away (max norm, by bisection: the inverse
    kinematics is not linear), the step planned by the limiter's own law on one virtual
    axis (:func:`path_step` with ``path_limits``), no faster than the bends of the path
    ahead allow (:func:`bend_speed`: near the edge of the valid poses a crank turns back
    while another speeds up). The limits themselves are enforced by :func:`limit_stage`
    alone, which every command passes.

    A plan is taken only when the limiter sends it unchanged (a command it trims is no pose
    of the segment, and may be none at all: a target that changed while the robot moved
    asked for a turn at speed, and the trims went off the assembly) and when it can still
    stop on the segment. Else, moving, the robot brakes along the straight pose line it is
    on (the state's ``leg``: the segment's goal, or past a goal one tick reached) with the
    plan's own law, or stops at once if the limiter allows; the new segment is tried again
    every tick. Only when none of these is kept is the least trimmed sent (from rest: the
    limiter's own approach). A goal that is the state's pose brakes to rest along the leg
    (never via neutral): how :class:`~motionbase.commanding.CommandPipeline` stops a robot
    moving on one.

    A workspace need not be convex (udesc's phi = 0 one has a band near a type II
    singularity across it): when the goal is out of one tick's reach and the straight
    segment to it leaves the valid poses (:func:`blocked_at`), the stage heads for the
    robot's neutral pose instead, and keeps on to rest there (turning at speed, the
    limiter's trims of the planned path went off the assembly near that band). From neutral
    a goal seen from it (its segment from neutral clear, as
    :class:`~motionbase.commanding.CommandPipeline` keeps them) is one straight segment away.

    Python, not compiled: it calls the robot's inverse kinematics.

    Parameters
    ----------
    P, S : ndarray
        The :data:`PARAMS` and :data:`STATE` records. Read: the state's command ``q``, its
        speed ``v``, the robot pose ``pose`` (first m) the last command realises and
        ``leg``; ``q``, ``v`` and ``wanted`` are updated as by :func:`limit_stage`
        (``wanted`` becomes the goal's actuators, fed forward next tick, unless the command
        was held), and ``leg``.
    robot : Robot
        ``inverse``, ``reachable`` and ``neutral_pose`` (robot coordinates).
    goal : ndarray, shape (m,)
        A reachable robot pose, seen from neutral.
    q : ndarray, shape (n,)
        Receives the command (rad or m).
    path_limits : ActuatorLimits
        One virtual axis: the approach's planned speed and acceleration, in actuator units
        (max norm) per s and s^2.

    Returns
    -------
    flags : int
        :func:`limit_stage`'s bits for the command sent.
    limited : bool
        The goal was out of one tick's reach (the limiter cut the direct command, or the
        stage headed for neutral).
    pose : ndarray or None
        The robot pose (m,) the command realises; None when it is not a pose the stage
        asked for (the limiter changed the command: forward kinematics tells).
    """
    p = P[0]
    s = S[0]
    n, m = int(p["n"]), int(p["m"])
    here, leg = s["pose"][:m].copy(), s["leg"][:m].copy()
    neutral = np.asarray(robot.neutral_pose, dtype=float)
    moving = bool(s["v"][:n].any())
    goal_q = np.asarray(robot.inverse(goal), dtype=float)
    saved = S.copy()  # the state before: its command and speed
    q_prev, v_prev = saved[0]["q"][:n], saved[0]["v"][:n]
    flags = limit_stage(P, S, goal_q, q)
    # a goal one tick reaches is commanded as its own pose: not routed (a goal jittering on
    # the valid poses' edge went home and back, again and again, never reached); the leg's
    # own goal was checked when the leg began
    routed = (
        moving and np.array_equal(leg, neutral)
        or bool(flags & RATE_LIMITED) and not np.array_equal(goal, leg)
        and blocked_at(robot, here, goal) is not None
    ) and not (np.array_equal(goal, neutral) or np.array_equal(goal, here))  # fmt: skip
    if routed:  # via neutral, to rest there (no corner at speed)
        goal = neutral
        goal_q = np.asarray(robot.inverse(goal), dtype=float)
        S[0] = saved[0]
        flags = limit_stage(P, S, goal_q, q)
    limited = not flags & HELD and bool(flags & RATE_LIMITED)
    pose: np.ndarray | None = None if flags & HELD else goal
    wanted = goal_q
    dt = float(p["dt"])
    u = float(path_limits.max_accel[0]) * dt  # the plan's speed change a tick
    if limited:  # on the new segment, else braking along the leg, if the limiter keeps it
        speed = float(np.max(np.abs(v_prev)))
        dist = float(np.max(np.abs(goal_q - q_prev)))  # (the plan must stop on the segment)
        stoppable = (1.0 + 1e-9) * dt * brake_speed(dist, u, dt)
        # no faster than the bends of the path ahead allow (a crank reversing near the edge)
        cap = max(bend_speed(robot, here, goal, float(path_limits.max_accel[0])), speed - u)
        lim = path_limits
        if cap < float(path_limits.max_speed[0]):
            lim = ActuatorLimits.broadcast(1, -1e3, 1e3, cap, float(path_limits.max_accel[0]))
        plans = [(goal, path_step(dist, speed, dt, lim))]
        plans += [(leg, path_step(0.0, speed, dt, path_limits)), (here, 0.0)] * moving
        trimmed = []  # (how far the limiter moved the command, plan, state, command, bits)
        for i, (end, step) in enumerate(plans):
            found = _point_along(robot, here, end, q_prev, step) if step > 0 else None
            found = (here, q_prev) if step == 0 else found
            if found is not None and (i or step < dist and step <= stoppable):
                S[0] = saved[0]
                s["wanted"][:n] = q_prev  # from the current command: no feed-forward
                flags = limit_stage(P, S, found[1], q)
                if not flags:
                    pose, wanted = found
                    goal = leg if i else goal
                    break
                trimmed.append((float(np.max(np.abs(q - found[1]))), i, S.copy(), q.copy(), flags))
        else:  # none kept: the least trimmed (braking: still by the leg), else its own approach
            S[0] = saved[0]
            flags, i = limit_stage(P, S, goal_q, q), 0
            if trimmed:
                _, i, S[:], q[:], flags = min(trimmed, key=lambda c: c[0])
            goal = leg if i else np.full(m, np.nan)
    if not flags & HELD:
        s["wanted"][:n] = goal_q  # the goal's own speed is fed forward next tick
        if not limited:  # a tick's reach: the line of its move, as far as the plan brakes
            goal = goal + (goal - here) * (1.0 + path_limits.max_speed[0] / u)
        s["leg"][:m] = goal
    if not np.array_equal(q, wanted):
        pose = None
    return int(flags), limited or routed, pose


_FRACTIONS = np.linspace(0.0, 1.0, 101)[:, None]  # (made once: linspace costs 10 us)


def blocked_at(
    robot, a: np.ndarray, b: np.ndarray, f: np.ndarray = _FRACTIONS
) -> np.ndarray | None:
    """The first of the points ``a + f (b - a)`` (``f``: rising fractions, shape (k, 1);
    101 evenly spaced by default) that is not a valid pose (``robot.reachable``) after one
    that is, or None: the straight path does not leave the valid poses (it may start outside
    them, after a trim)."""
    points = a + f * (b - a)
    bad = ~np.asarray(robot.reachable(points), dtype=bool)
    bad[: int(np.argmin(bad))] = False
    return points[int(np.argmax(bad))] if bad.any() else None


def bend_speed(robot, a: np.ndarray, b: np.ndarray, accel: float, f=_FRACTIONS) -> float:
    """The largest speed (actuator units a second, max norm) at ``a`` from which the straight
    pose path ``a -> b`` can be followed, braking at ``accel`` along it, with its bends
    needing no more than ``2 accel / 3`` of any actuator (the rest of the limiter's
    acceleration above the plan's ``accel``, 60 % of it): where an actuator's path bends
    (``q'' = d^2 q / ds^2``, ``s`` the path's length in max norm) at speed ``v`` it needs
    ``|q''| v^2``. Inf for a path without bends (or of one point); up to its first pose
    without actuators."""
    qs = np.asarray(robot.inverse(a + f * (b - a)), dtype=float)
    qs = qs[: int(np.argmin(np.isfinite(qs).all(axis=1))) or len(qs)]  # (up to a NaN)
    d = np.diff(qs, axis=0)
    ds = np.max(np.abs(d), axis=1)
    keep = ds > 1e-12
    if keep.sum() < 2:
        return np.inf
    d, ds = d[keep], ds[keep]
    s = np.concatenate(([0.0], np.cumsum(ds)))
    bend = np.max(np.abs(np.diff(d / ds[:, None], axis=0)), axis=1) / (0.5 * (ds[1:] + ds[:-1]))
    cap2 = (2.0 / 3.0) * accel / np.maximum(bend, 1e-12) + 2.0 * accel * s[1:-1]
    return float(np.sqrt(cap2.min()))


def path_step(distance: float, speed: float, dt: float, limits: ActuatorLimits) -> float:
    """Progress allowed this tick toward a fixed target ``distance`` away on one virtual
    axis moving at ``speed`` (the limiter's own law, :func:`motionbase.safety.limit_command`,
    with ``limits`` of one axis): the approach stage's plan, not a limit."""
    d = np.array([distance])
    step, _, _ = limit_command(np.zeros(1), np.array([speed]), d, d, dt, limits)
    return float(step[0])


def _point_along(
    robot, pose: np.ndarray, goal: np.ndarray, q: np.ndarray, step: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """The point of the pose segment ``pose -> goal`` whose actuators lie ``step`` (max
    norm) from ``q``, by bisection on the fraction (16 steps); ``(pose, actuators)`` or
    None."""
    lo, hi = 0.0, 1.0
    best = None
    for _ in range(16):
        f = 0.5 * (lo + hi)
        candidate = pose + f * (goal - pose)
        if bool(robot.reachable(candidate)):
            qc = np.asarray(robot.inverse(candidate), dtype=float)
            if np.isfinite(qc).all() and float(np.max(np.abs(qc - q))) <= step:
                lo, best = f, (candidate, qc)
                continue
        hi = f
    return best


@numba.njit(cache=True)
def at_park(P, S):  # pragma: no cover - compiled
    """Stopped, with every actuator at park and at rest."""
    p = P[0]
    s = S[0]
    if not (s.phase == STOPPING and s.blend == 0.0):
        return False
    for i in range(p.n):
        if not (s.q[i] == p.park_q[i] and s.v[i] == 0.0):
            return False
    return True


@numba.njit(cache=True)
def _path_point(P, solve, G, q0, v0, ql, c0, c1, f, c, x, w, b):  # pragma: no cover - compiled
    """The point ``f`` of the cue segment ``c0 -> c1`` (written: cue ``c``, robot pose ``x``,
    actuators ``w``; ``b`` scratch of 12 + 3n + m) for :func:`path_stage`: 0 when it is a valid
    pose whose actuators the limiter passes unchanged from ``q0, v0`` and from which the
    robot, braking, still stops within the valid poses; 1 when it is too far, -1 too near."""
    p = P[0]
    n = p.n
    qt, vt, probe = b[12 : 12 + n], b[12 + n : 12 + 2 * n], b[6:12]
    for i in range(6):
        c[i] = c1[i] if f == 1.0 else c0[i] + f * (c1[i] - c0[i])
    if solve[0](G, c, b[:6], x, w):  # the kernel clamped it: not a valid pose
        return 1
    low, up, vmax, amax = p.lower[:n], p.upper[:n], p.max_speed[:n], p.max_accel[:n]
    for i in range(n):  # no actuator further than the limiter alone takes it
        if (w[i] - q0[i]) * (ql[i] - q0[i]) > 0.0 and abs(w[i] - q0[i]) > abs(ql[i] - q0[i]):
            return 1
    if limit_kernel(q0, v0, q0, w, p.dt, low, up, vmax, amax, qt, vt):
        for i in range(n):  # the limiter shortened a step (a reversal counts as short)
            if (w[i] - q0[i]) * (qt[i] - w[i]) < 0.0:
                return 1
        return -1
    # braking from here takes the slowest actuator k ticks, the pose about (k + 1) / 2 of
    # this tick's steps: k + 3 of them must be valid (the actuators' paths bend near the edge)
    k = 0.0
    for i in range(n):
        k = max(k, abs(vt[i]) / (amax[i] * p.dt))
    reach = f * (k + 3.0)
    for i in range(6):
        probe[i] = c0[i] + reach * (c1[i] - c0[i])
    return 1 if solve[0](G, probe, b[:6], b[12 + 2 * n : 12 + 2 * n + p.m], qt) else 0


@numba.njit(cache=True)
def _cue_of(P, solve, G, q, c, b):  # pragma: no cover - compiled
    """The cue pose ``c`` (6,; in: a guess) whose actuators are ``q`` (Gauss-Newton on the
    robot's kernel; ``b`` scratch of 6 + n + m): False when none is found unclamped."""
    n = P[0].n
    w, wj, x, jac = b[6 : 6 + n], np.empty(n), b[6 + n : 6 + n + P[0].m], np.empty((n, 6))
    for _ in range(10):
        if solve[0](G, c, b[:6], x, w):
            return False
        if np.max(np.abs(q - w)) < 1e-12:
            return True
        for j in range(6):
            e = c.copy()
            e[j] += 1e-7
            solve[0](G, e, b[:6], x, wj)
            jac[:, j] = (wj - w) / 1e-7
        c += np.linalg.pinv(jac) @ (q - w)
    return not solve[0](G, c, b[:6], x, w) and np.max(np.abs(q - w)) < 1e-9


#: Bisection steps of :func:`path_stage` (a point within 2^-20 of the segment's length).
PATH_STEPS = 20


@numba.njit(cache=True)
def path_stage(P, S, solve, G, cue, pose, wanted, q):  # pragma: no cover - compiled
    """:func:`limit_stage` for a robot whose actuators, each limited alone, can leave its
    valid poses (``P.path``): the command is a valid pose, the limiter passes it unchanged.

    Near a chain's type I singularity (the workspace's edge) an actuator must move ever
    faster for the same motion of the pose: limited alone it lagged, the others went on,
    then it overshot, and the command made a pose the robot refuses (a chain straightened,
    its elbow flipped). Here the command is the furthest point (by bisection) of the cue
    segment from the cue pose the last command realised (the state's ``cue``) toward
    ``cue`` (the robot's, ``pose`` and ``wanted`` its pose and actuators) such that:

    * the robot's kernel does not clamp it (a valid pose);
    * no actuator goes further than :func:`limit_stage` alone takes it (its braking toward
      the target), and the limiter passes it unchanged from this tick's command and speed
      (nothing fed forward: within the speed and acceleration limits);
    * braking from it, the pose stays valid over the slowest actuator's stopping ticks ``k``
      along the segment's line (``k + 3`` of this tick's steps: about twice what braking
      covers, as an actuator's path bends near the edge), so the robot slows before it.

    When the segment has none (a target behind the robot's motion), the nearest such point
    of the line the robot moves on (its last step continued) brakes it; when neither has
    one, :func:`brake_stage` brakes the actuators together, and the cue pose its command
    realises is found (:func:`_cue_of`), for the next tick to start from (left stale, no
    later tick found a point: the limiter alone drove on and a chain left its assembly),
    unless it is no unclamped pose (the pose is then found by forward kinematics). The limits
    are enforced by :func:`limit_stage` alone, which every command passes.

    Returns :func:`limit_stage`'s bits, with ``PATH`` (and ``RATE_LIMITED``) when the
    command is a point short of the target (written to ``pose``; ``wanted`` stays the
    target's, whose speed is fed forward next tick); the state's ``pose``, ``cue`` and
    ``step`` (the realised cue's) follow the commands whose pose is known.
    """
    p = P[0]
    s = S[0]
    n, m = p.n, p.m
    q0, v0, c0 = s.q[:n].copy(), s.v[:n].copy(), s.cue.copy()
    flags = limit_stage(P, S, wanted, q)
    if flags & HELD:
        return flags
    c, x, w, b = np.empty(6), np.empty(m), np.empty(n), np.empty(12 + 3 * n + m)
    best = -1.0
    for line in range(2):  # the target's segment (furthest point), then braking (nearest)
        end = cue if line == 0 else c0 + s.step
        ql = q.copy() if line == 0 else np.full(n, np.nan)  # (braking: no limiter's bound)
        lo, hi, f = 0.0, 1.0, 1.0 - 0.5 * line
        for _ in range(PATH_STEPS + 1):
            code = _path_point(P, solve, G, q0, v0, ql, c0, end, f, c, x, w, b)
            best = f if code == 0 else best
            if code > 0 or code == 0 and line:
                hi = f
            else:
                lo = f
            if lo >= hi:
                break
            f = 0.5 * (lo + hi)
        if best >= 0.0:
            break
    if best < 0.0:  # braking together, from its cue next tick
        c[:] = c0
        s.q[:n], s.v[:n], s.wanted[:n] = q0, v0, q0
        flags = brake_stage(P, S, q) | RATE_LIMITED  # (not the target's command)
        if not flags & HELD and _cue_of(P, solve, G, q, c, b):
            s.step[:] = c - c0
            s.cue[:] = c
            s.pose[:m] = pose[:] = x
            flags |= PATH
        return flags
    if code != 0:  # (else ``c``, ``x``, ``w`` hold the point chosen: the last evaluated)
        _path_point(P, solve, G, q0, v0, ql, c0, end, best, c, x, w, b)
    s.q[:n], s.v[:n], s.wanted[:n] = q0, v0, q0
    limit_stage(P, S, w, q)
    s.wanted[:n] = wanted  # the target's own speed is fed forward next tick
    s.pose[:m] = pose[:] = x
    s.step[:] = c - c0
    s.cue[:] = c
    return 0 if best == 1.0 and line == 0 else PATH | RATE_LIMITED


@numba.njit(cache=True)
def after_cueing(P, S, solve, G, cue, target, cue_out, pose, wanted, q):  # pragma: no cover
    """The robot's side of a tick: soft start/stop, clamp + inverse kinematics, limiter.

    Parameters
    ----------
    P, S : records
    solve : typed list of one robot kernel (:data:`SOLVE_LIST`)
    G : ndarray
        The robot's kernel parameters.
    cue : ndarray, shape (6,)
        The cueing's pose.
    target, cue_out : ndarray, shape (6,)
        Out: the blended target, and the cue pose the robot realises (anti-windup).
    pose : ndarray, shape (m,)
        Out: the robot pose commanded.
    wanted, q : ndarray, shape (n,)
        Out: the inverse kinematics' command and the limiter's (sent).

    Returns
    -------
    int
        ``CLAMPED``, ``RUNNING_CLAMP``, ``RATE_LIMITED``, ``HELD``, ``PATH`` and the output
        phase (``<< PHASE_SHIFT``). When the limiter changed the command (and ``PATH`` is not
        set), the state's ``pose`` keeps the last tick's (the caller finds the achieved one by
        forward kinematics). With ``P.path``, :func:`path_stage` chooses the command.
    """
    p = P[0]
    s = S[0]
    flags = 0
    if blend_stage(P, S, cue, target):
        pose[:] = p.park_pose[: p.m]
        wanted[:] = p.park_q[: p.n]
        cue_out[:] = p.park_cue
    elif solve[0](G, target, cue_out, pose, wanted):
        flags |= CLAMPED
        if s.phase == RUNNING:
            flags |= RUNNING_CLAMP
    if p.path:
        flags |= path_stage(P, S, solve, G, cue_out, pose, wanted, q)
    else:
        flags |= limit_stage(P, S, wanted, q)
        if not (flags & (HELD | RATE_LIMITED)):
            s.pose[: p.m] = pose
    phase = PARKED if at_park(P, S) else s.phase
    return flags | (phase << PHASE_SHIFT)


_BATCH_SIGNATURE = numba.int64(
    _PARAMS_T,
    _STATE_T,
    STEP_LIST,
    TRACK_LIST,
    _vec,
    _vec,
    SOLVE_LIST,
    _vec,
    _vec,  # t
    numba.float64[:, ::1],  # f, w, att
    numba.float64[:, ::1],
    numba.float64[:, ::1],
    numba.boolean[::1],  # fresh
    numba.float64[:, ::1],  # out: cue poses (N, 6)
    numba.float64[:, ::1],  # out: robot poses (N, m)
    numba.float64[:, ::1],  # out: commands (N, n)
    numba.int64[::1],  # out: status bits (N,)
)


@numba.njit(_BATCH_SIGNATURE, cache=True)
def run_batch(P, S, step, track, cp, cs, solve, G, t, f, w, att, fresh, cues, poses, qs, flags):
    """Every stage over a whole flight, in compiled code: the same
    functions, in the same order, as :meth:`motionbase.pipeline.Pipeline.step`.

    Returns the number of ticks run: ``len(t)``, or fewer when the cueing met a
    non-finite input (the tick that failed has ``CUEING_ERROR`` set and is not counted).
    Rows of the outputs are the ticks. Rejected samples are held and their ``PROBLEM``
    code set, as in the tick; the achieved pose after the limiter acted is not solved
    (``RATE_LIMITED`` or ``HELD`` say where it differs).
    """  # pragma: no cover - compiled
    u = np.empty(6)
    target = np.empty(6)
    cue_out = np.empty(6)
    wanted = np.empty(P[0].n)
    for k in range(t.shape[0]):
        bits = input_stage(P, S, True, t[k], f[k], w[k], att[k], fresh[k], u)
        if not step[0](cp, cs, u, cues[k]):
            flags[k] = bits | CUEING_ERROR
            return k
        bits |= after_cueing(P, S, solve, G, cues[k], target, cue_out, poses[k], wanted, qs[k])
        if bits & RUNNING_CLAMP:
            track[0](cp, cs, cue_out)
        flags[k] = bits
    return t.shape[0]
