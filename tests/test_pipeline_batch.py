"""One pipeline: the batch path equals the tick, and cueing plug-ins need no pipeline change.

* :meth:`Pipeline.run_batch` (every stage over a whole flight, compiled) gives the same
  numbers as :meth:`Pipeline.step` tick by tick, bit for bit, on a flight that makes every
  stage act: rejected samples, stale marks, a time jump, clamping, rate limiting.
* A cueing plug-in written here, registered with ``register_cueing``, runs through ``fly``
  and ``replay`` (the command line's ``--cueing``): the logged cue pose is the plug-in's
  law applied to the logged aircraft samples (computed here, independently), and the replay
  reproduces the log bit for bit.
"""

from __future__ import annotations

import math

import jsonschema
import numba
import numpy as np
import pytest
from mcap.reader import make_reader

from motionbase import app, stages
from motionbase.app import load_config
from motionbase.cli import main
from motionbase.io.mcap_source import read_messages, read_metadata
from motionbase.pipeline import Pipeline
from motionbase.state import PHASES, AircraftState
from motionbase.washout.cueing import CUEINGS, STEP_SIGNATURE, TRACK_SIGNATURE, Cueing, CueingSpec
from motionbase.washout.params import WashoutParams

G = 9.80665
LEVEL = np.array([0.0, 0.0, -G, 0.0, 0.0, 0.0])
#: The test cueing's law: pose = GAIN * (u - level flight), per axis.
GAIN = np.array([0.02, 0.02, 0.01, 0.05, 0.05, 0.05])


def hard_flight(dt: float, seconds: float = 12.0):
    """Samples that make every stage act: strong manoeuvring (clamps, rate limits), a NaN,
    a repeated time, a stale stretch, a 2 s gap (a time jump)."""
    n = int(seconds / dt)
    t = np.arange(1, n + 1) * dt
    t[n // 2 :] += 2.0  # a gap: the input restarts from level flight
    s = np.sin(2 * math.pi * 0.6 * t)
    f = np.column_stack([30 * s, 25 * np.cos(2 * math.pi * 0.4 * t), -G + 15 * s])
    w = np.column_stack([3 * s, 2.5 * s, 2 * np.cos(2 * math.pi * 0.3 * t)])
    att = np.zeros((n, 3))
    f[100, 1] = np.nan  # rejected, held
    t[200] = t[199]  # time did not advance: rejected
    fresh = np.ones(n, dtype=bool)
    fresh[300:420] = False  # a stale stretch: the fade
    return t, f, w, att, fresh


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_batch_equals_the_tick_bit_for_bit(planar):
    # the SIMONA set: the flight makes it clamp (the tuned default is sized never to)
    config = load_config(planar=planar, washout="default")
    t, f, w, att, fresh = hard_flight(config.dt)
    streamed = Pipeline(config)
    outs = [
        streamed.step(AircraftState(t[k], f[k], w[k], att[k]), bool(fresh[k]))
        for k in range(len(t))
    ]
    batch_pipe = Pipeline(config)
    batch = batch_pipe.run_batch(t, f, w, att, fresh)
    # every stage acted
    kinds = {
        "rejected": not all(o.accepted for o in outs),
        "clamped": any(o.clamped for o in outs),
        "rate limited": any(o.rate_limited for o in outs),
        "faded": any(o.fade < 1 for o in outs),
    }
    assert all(kinds.values()), kinds
    assert np.array_equal(batch.cue_poses, np.array([o.washout_pose for o in outs]))
    assert np.array_equal(batch.commands, np.array([o.angles for o in outs]))
    assert np.array_equal(batch.accepted, [o.accepted for o in outs])
    assert np.array_equal(batch.clamped, [o.clamped for o in outs])
    assert np.array_equal(batch.limited, [o.rate_limited or o.held for o in outs])
    phases = [PHASES[p] for p in batch.phases]
    assert phases == [o.phase for o in outs]
    poses = np.array([o.platform_pose for o in outs])
    free = ~batch.limited
    assert np.array_equal(batch.poses[free], poses[free])
    # where the limiter acted, both solved the achieved pose by forward kinematics from
    # different starting guesses
    np.testing.assert_allclose(batch.poses, poses, atol=1e-8)
    # the counters agree, and the state each leaves is the same
    assert batch_pipe.health.as_dict() == streamed.health.as_dict()
    assert batch_pipe.state.tobytes() == streamed.state.tobytes()
    assert np.array_equal(
        batch_pipe.cueing.kernel_state, streamed.cueing.kernel_state
    )  # the washout's own state


def test_batch_continues_where_the_ticks_left_off():
    """A batch run from the middle of a flight carries the state on: ticks then a batch equal
    one batch over the whole flight."""
    config = load_config()
    t, f, w, att, fresh = hard_flight(config.dt, seconds=6.0)
    whole = Pipeline(config).run_batch(t, f, w, att, fresh)
    p = Pipeline(config)
    half = len(t) // 3
    for k in range(half):
        p.step(AircraftState(t[k], f[k], w[k], att[k]), bool(fresh[k]))
    rest = p.run_batch(t[half:], f[half:], w[half:], att[half:], fresh[half:])
    assert np.array_equal(rest.commands, whole.commands[half:])


# --------------------------------------------------------------------------- plug-ins


class LinearCue(Cueing):
    """A test cueing plug-in: the pose is a fixed gain times the input's deviation from
    level flight (no filter, no tilt); it counts the anti-windup calls it gets."""

    name = "test_linear"
    diagnostics_schema = (
        "test.LinearDiagnostics",
        {
            "type": "object",
            "properties": {"tracked": {"type": "integer", "minimum": 0}},
            "required": ["tracked"],
        },
    )

    def __init__(self, params: WashoutParams, dt: float) -> None:
        self.params = params
        self.dt = dt
        self.tracked = 0

    def diagnostics(self) -> dict[str, int]:
        return {"tracked": self.tracked}

    def reset(self) -> None:
        pass

    def advance(self, u: np.ndarray, out: np.ndarray) -> bool:
        if not np.isfinite(u).all():
            return False
        out[:] = GAIN * (u - LEVEL)
        return True

    def track(self, achieved: np.ndarray) -> None:
        self.tracked += 1


@numba.njit(STEP_SIGNATURE, cache=True)
def _linear_step(params, state, u, out):  # pragma: no cover - compiled
    for i in range(6):
        if not np.isfinite(u[i]):
            return False
    for i in range(6):
        out[i] = params[i] * (u[i] - params[6 + i])
    state[0] += 1.0  # ticks seen
    return True


@numba.njit(TRACK_SIGNATURE, cache=True)
def _linear_track(params, state, achieved):  # pragma: no cover - compiled
    state[1] += 1.0  # anti-windup calls


class CompiledLinearCue(LinearCue):
    """The same law with compiled kernels: the batch path runs it in compiled code."""

    name = "test_linear_compiled"
    step_kernel = staticmethod(_linear_step)
    track_kernel = staticmethod(_linear_track)

    def __init__(self, params: WashoutParams, dt: float) -> None:
        super().__init__(params, dt)
        self.kernel_params = np.concatenate([GAIN, LEVEL])
        self.kernel_state = np.zeros(2)

    def reset(self) -> None:
        self.kernel_state[:] = 0.0

    def advance(self, u: np.ndarray, out: np.ndarray) -> bool:
        return _linear_step(self.kernel_params, self.kernel_state, u, out)

    def track(self, achieved: np.ndarray) -> None:
        _linear_track(self.kernel_params, self.kernel_state, achieved)


@pytest.fixture
def plugins():
    """Register the test cueings for one test (any parameter file of the classical kind)."""
    names = []
    for cls in (LinearCue, CompiledLinearCue):
        CUEINGS[cls.name] = CueingSpec(
            cls.name, cls, "motionbase.washout.params:WashoutParams", preset_kind="washout"
        )
        names.append(cls.name)
    yield names
    for name in names:
        del CUEINGS[name]


def test_a_compiled_plugin_runs_the_batch_path_as_the_tick(plugins):
    config = load_config(cueing="test_linear_compiled")
    t, f, w, att, fresh = hard_flight(config.dt, seconds=6.0)
    streamed = Pipeline(config)
    q = np.array(
        [
            streamed.step(AircraftState(t[k], f[k], w[k], att[k]), bool(fresh[k])).angles
            for k in range(len(t))
        ]
    )
    batch_pipe = Pipeline(config)
    batch = batch_pipe.run_batch(t, f, w, att, fresh)
    assert np.array_equal(batch.commands, q)
    assert batch.clamped.any()
    # the plug-in's own state: every tick stepped it, every clamp while running told it
    assert np.array_equal(batch_pipe.cueing.kernel_state, streamed.cueing.kernel_state)
    running_clamps = (batch.clamped & (batch.phases == stages.RUNNING)).sum()
    assert batch_pipe.cueing.kernel_state[1] == running_clamps > 0


@pytest.mark.parametrize(
    ("spoil", "given"),
    [
        (lambda c: c.kernel_params.setflags(write=False), "(readonly array(float64, 1d, C), "),
        (lambda c: setattr(c, "kernel_params", c.kernel_params.astype(np.float32)), "float32"),
        (lambda c: setattr(c, "kernel_state", np.zeros((1, 2))), "array(float64, 2d, C)"),
    ],
)
def test_a_plugin_whose_kernel_vectors_do_not_fit_its_signature_is_told_so(spoil, given):
    """A compiled cueing's vectors must be exactly what its declared signature says
    (writable, C-ordered float64 vectors): building the pipeline says what it takes and what
    it was given, in one line."""
    config = load_config()
    cueing = CompiledLinearCue(config.cueing_params, config.dt)
    spoil(cueing)
    with pytest.raises(TypeError, match=r"^_linear_step takes \(array\(float64, 1d, C\), ") as err:
        Pipeline(config, cueing=cueing)
    message = str(err.value)
    assert given in message.split(", not ")[1] and "\n" not in message


def test_a_plugin_cueing_flies_and_replays_with_no_pipeline_change(plugins, tmp_path):
    out = tmp_path / "linear.mcap"
    code = main(
        [
            "fly",
            "c1723",
            "--cueing",
            "test_linear",
            "--duration",
            "6",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    msgs = read_messages(out)
    meta = read_metadata(out)
    assert meta["pipeline_config"]["cueing"] == "test_linear"
    # the plug-in's law on the logged aircraft samples, where the input was the sample itself
    states = {m["t"]: m for m in msgs["/aircraft/state"]}
    poses = {m["t"]: m for m in msgs["/platform/pose"]}
    checked = 0
    for m in msgs["/washout/pose"]:
        s = states.get(m["t"])
        if s is None or not s["accepted"] or poses[m["t"]]["fade"] != 1.0:
            continue
        u = np.concatenate([s["specific_force"], s["angular_velocity"]])
        np.testing.assert_allclose(m["pose"], GAIN * (u - LEVEL), rtol=0, atol=1e-12)
        checked += 1
    assert checked > 500
    # its diagnostics, on a topic of its own with its schema: one a tick, the count of
    # anti-windup calls never falling
    diagnostics = msgs["/cueing/test_linear"]
    assert len(diagnostics) == len(msgs["/washout/pose"])
    for m in diagnostics:
        jsonschema.validate(m, LinearCue.diagnostics_schema[1])
    tracked = [m["tracked"] for m in diagnostics]
    assert tracked == sorted(tracked)
    with open(out, "rb") as fh:
        schemas = {
            channel.topic: schema.name
            for schema, channel, _ in make_reader(fh).iter_messages(topics=["/cueing/test_linear"])
        }
    assert schemas == {"/cueing/test_linear": "test.LinearDiagnostics"}
    # replay takes the cueing from the recording and reproduces the log bit for bit
    result = app.replay(out, check=True, progress=False)
    assert not result.failed, "\n".join(result.notes)


def test_a_recording_of_an_unknown_cueing_is_refused_in_one_line(plugins, tmp_path, capsys):
    out = tmp_path / "linear.mcap"
    assert (
        main(["fly", "c1723", "--cueing", "test_linear", "--duration", "2", "--out", str(out)]) == 0
    )
    del CUEINGS["test_linear"]
    try:
        code = main(["replay", str(out), "--check"])
    finally:
        CUEINGS["test_linear"] = CueingSpec(
            "test_linear", LinearCue, "motionbase.washout.params:WashoutParams", "washout"
        )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "test_linear" in err[0] and "cueing" in err[0]


def test_an_unknown_cueing_name_is_one_line_and_exit_2(capsys):
    code = main(["fly", "c1723", "--cueing", "nope", "--duration", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "nope" in err[0] and "classical" in err[0]
