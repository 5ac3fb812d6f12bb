"""The pipeline log writes every output exactly: topics, fields, log times, exact floats.

:class:`PipelineLog` turns each :class:`~motionbase.pipeline.PipelineOutput` into the
topics of the README's log table. Real pipeline outputs (strong and calm stretches,
rejected NaN and infinite samples, samples without angular acceleration, with and without
a flight phase, stale marks, the park ramp) are logged, read back with the ``mcap``
library, and compared with the outputs themselves, value by value (finite floats bit for
bit). Also
``AircraftState.from_vector`` against the constructor.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from motionbase import tick_record
from motionbase.app import load_config
from motionbase.io.mcap_log import encode_message
from motionbase.io.mcap_source import decode_message
from motionbase.io.pipeline_log import PipelineLog
from motionbase.pipeline import Pipeline
from motionbase.state import AircraftState

G = 9.80665


def _outputs(planar: bool, n: int = 900) -> list:
    """Real pipeline outputs: strong and calm stretches, NaN samples (and three whose time is
    not finite), no angular acceleration on some, the flight phase on some (on the ground or
    in the air), stale marks, then the park ramp (state None)."""
    rng = np.random.default_rng(3)
    pipeline = Pipeline(load_config(planar=planar, rate_hz=120.0))
    outs = []
    for k in range(1, n):
        s = 2.0 if (k // 150) % 2 else 0.2
        f = rng.normal(size=3) * 20 * s + (0.0, 0.0, -G)
        w = rng.normal(size=3) * 2 * s
        att = rng.uniform(-3, 3, 3)
        if k % 101 == 7:
            f[1] = math.nan  # rejected, logged as text
        if k % 131 == 9:
            w[2] = math.inf
        acc = None if k % 3 == 0 else rng.normal(size=3)
        ground = (None, True, False)[k % 5 % 3]  # (with and without acceleration)
        t = {200: math.inf, 400: -math.inf, 600: math.nan}.get(k, k / 120.0)  # rejected
        state = AircraftState(t, f, w, att, angular_acceleration=acc, on_ground=ground)
        outs.append(pipeline.step(state, fresh=(k // 40) % 9 != 4))
    pipeline.stop()
    while not pipeline.parked and len(outs) < n + 600:
        outs.append(pipeline.step(None))
    return outs


def _write(path: Path, outs: list) -> int:
    """Log ``outs``; returns how many /health messages the counter callback gave."""
    calls = []

    def health() -> dict:
        calls.append(len(calls))
        return {"samples": len(calls)}

    with PipelineLog(path, {"kind": "test"}, health=health) as log:
        for out in outs:
            log.write(out)
    return len(calls)


def _read(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        return [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]


def _same(got, expected) -> None:
    """Equal values; floats bit for bit (NaN equal to NaN)."""
    a, b = np.asarray(got), np.asarray(expected)
    assert a.shape == b.shape and a.dtype.kind == b.dtype.kind, (got, expected)
    np.testing.assert_array_equal(a, b, strict=True)


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_every_output_is_logged_exactly(tmp_path, planar):
    outs = _outputs(planar)
    assert any(o.state is not None and not o.accepted for o in outs)
    assert any(o.state is None for o in outs)
    path = tmp_path / "log.mcap"
    health_calls = _write(path, outs)
    records = _read(path)

    by_time: dict[int, dict[str, list]] = {}
    for topic, ns, data in records:
        by_time.setdefault(ns, {}).setdefault(topic, []).append(decode_message(data))
    assert sorted(by_time) == [round(o.t * 1e9) for o in outs]  # one log time per tick

    pose_topic, act_topic = (
        ("/planar/pose", "/planar/actuators")
        if planar
        else (
            "/platform/pose",
            "/platform/actuators",
        )
    )
    worlds = 0
    for out in outs:
        got = by_time[round(out.t * 1e9)]
        expected_topics = {"/washout/pose", pose_topic, act_topic}
        if out.state is not None:
            expected_topics.add("/aircraft/state")
        if not planar:
            expected_topics.add("/tf")
        assert set(got) - {"/health"} == expected_topics

        if out.state is not None:
            (st,) = got["/aircraft/state"]
            assert st["t"] == out.t
            _same(st["source_t"], out.state.t)  # a non-finite time too, as a JSON string
            assert st["fresh"] is out.fresh and st["accepted"] is out.accepted
            _same(st["specific_force"], out.state.specific_force)
            _same(st["angular_velocity"], out.state.angular_velocity)
            _same(st["attitude"], out.state.attitude)
            if out.state.angular_acceleration is None:
                assert "angular_acceleration" not in st
            else:
                _same(st["angular_acceleration"], out.state.angular_acceleration)
            if out.state.on_ground is None:
                assert "on_ground" not in st
            else:
                assert st["on_ground"] is out.state.on_ground
        (wp,) = got["/washout/pose"]
        assert wp["t"] == out.t
        _same(wp["pose"], out.washout_pose)
        (pp,) = got[pose_topic]
        _same(pp["pose"], out.platform_pose)
        for key in ("t", "clamped", "rate_limited", "held", "phase", "fade"):
            assert pp[key] == getattr(out, key) and type(pp[key]) is type(getattr(out, key))
        (act,) = got[act_topic]
        _same(act["angles"], out.angles)
        if planar:
            _same(act["servo_deg"], out.servo_deg.tolist())
        else:
            tfs = got["/tf"]
            plat = [m for m in tfs if m["child_frame_id"] == "platform"]
            (tf,) = plat
            assert tf["parent_frame_id"] == "base"
            assert [tf["translation"][k] for k in "xyz"] == out.platform_pose[:3].tolist()
            roll, pitch, yaw = out.platform_pose[3:]
            ref = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
            r = Rotation.from_quat([tf["rotation"][k] for k in "xyzw"]).as_matrix()
            assert np.allclose(r, ref, atol=1e-12)
            worlds += len(tfs) - 1

    # /health: the first tick, then once per second of source time, then at the end
    assert sum(topic == "/health" for topic, _, _ in records) == health_calls
    duration = outs[-1].t - outs[0].t
    assert health_calls in (math.floor(duration) + 2, math.floor(duration) + 3)
    if not planar:  # the world -> base transform: at the first tick, then once per second
        assert worlds in (math.floor(duration) + 1, math.floor(duration) + 2)

    # the rejected samples' non-finite values are kept, as JSON strings
    raw = [d for topic, _, d in records if topic == "/aircraft/state"]
    assert any(b'"NaN"' in d for d in raw) and any(b'"Infinity"' in d for d in raw)
    for bad in (b'"source_t":"Infinity"', b'"source_t":"-Infinity"', b'"source_t":"NaN"'):
        assert sum(bad in d for d in raw) == 1, bad  # the source's own time, not a null


def test_state_from_vector_equals_the_constructor():
    v = np.array([1.5, -2.25, -9.8, 0.1, 0.2, 0.3, 0.4, -0.5, 3.0, 7.0, 8.0, 9.0])
    a = AircraftState.from_vector(2.5, v.copy())
    b = AircraftState(2.5, v[0:3], v[3:6], v[6:9], angular_acceleration=v[9:12])
    for name in ("specific_force", "angular_velocity", "attitude", "angular_acceleration"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == (3,) and np.array_equal(x, y)
        assert not x.flags.writeable
    assert a.t == b.t and type(a.t) is float
    c = AircraftState.from_vector(1.0, v[:9].copy())
    assert c.angular_acceleration is None and c.is_finite()


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros(9, dtype=np.float32),  # another dtype
        np.zeros(9, dtype=np.int64),  # the same item size, another dtype
        np.zeros((3, 3)),  # two dimensions
        np.zeros(18)[::2],  # strided
        np.zeros(6),  # too short: the fields would lie beyond it
        [0.0] * 9,  # not an array
    ],
)
def test_state_from_vector_refuses_what_the_compiled_stages_cannot_read(bad):
    """The pipeline's tick reads a sample's fields as C-ordered float64 vectors of 3 without
    checking them again (its stages are bound to those types): from_vector checks."""
    with pytest.raises(TypeError, match="C-contiguous float64"):
        AircraftState.from_vector(0.0, bad)


def test_a_tick_record_carries_the_cueing_status_and_diagnostics_and_refuses_other_types():
    """The record the tick sends the log's writer (:mod:`motionbase.tick_record`): a cue
    status and diagnostics (numpy values, a non-finite number) come back as the cueing gave
    them, on the diagnostics' topic with the tick's time; a record of float32 numbers
    (another robot's arrays) is refused, not read as other numbers."""
    out = _outputs(False, n=30)[-1]
    status = {"profile": "air", "profile_weights": np.array([0.25, 0.75])}
    diagnostics = {"status": "solved", "iterations": np.int64(12), "violation": math.inf}
    out = out._replace(cue_status=status)
    items, pose = tick_record.messages(
        tick_record.pack(out, diagnostics, "/cueing/test", encode_message)
    )
    got = dict(items)
    assert got["/washout/pose"]["profile"] == "air"
    assert got["/washout/pose"]["profile_weights"] == [0.25, 0.75]
    assert got["/cueing/test"] == {
        "t": out.t, "status": "solved", "iterations": 12, "violation": "Infinity"
    }  # fmt: skip
    assert pose == out.platform_pose.tolist()
    bad = out._replace(angles=out.angles.astype(np.float32))
    with pytest.raises(ValueError, match="tick record"):
        tick_record.messages(tick_record.pack(bad, None, "", encode_message))


@pytest.mark.parametrize(
    ("platform", "neutral_height"),
    [("ceart", 0.648), ("stewart6", None)],
    ids=["rus6", "stewart6"],
)
def test_tf_places_the_platform_frame_at_the_platform(tmp_path, platform, neutral_height):
    """``/tf``'s ``platform`` frame sits where the platform is: DESIGN.md puts the platform
    frame's origin at the centroid of the platform joints and the base origin in the base
    joint (crank pivot) plane, so at a pose ``p`` the frame is at ``(0, 0, -h) + p[:3]``
    (h the neutral height: 0.648 m for ceart per DESIGN.md's geometry table; for the
    Stewart seat, ``sqrt(L^2 - d^2)`` with L = 0.75 m the neutral leg length and d the
    horizontal reach of a leg between the 0.50 m and 0.35 m circles). It used to be at
    ``p[:3]`` alone: the frame rode 0.65 m below the plate that /platform/scene draws."""
    pipeline = Pipeline(load_config(platform=platform, rate_hz=120.0))
    robot = pipeline.robot
    outs = []
    for k in range(1, 240):
        f = (2.0 * math.sin(k / 20.0), -1.5, -G + 1.0)
        outs.append(pipeline.step(AircraftState(k / 120.0, f, (0.2, -0.1, 0.3), (0.0, 0.0, 0.0))))
    path = tmp_path / "tf.mcap"
    with PipelineLog(path, {"kind": "test"}, robot=robot) as log:
        for out in outs:
            log.write(out)
    if neutral_height is None:  # Stewart seat: pairs at 0/120/240 deg (+-12) and 60/180/300
        b = 0.50 * np.array([math.cos(math.radians(-12.0)), math.sin(math.radians(-12.0))])
        c = 0.35 * np.array([math.cos(math.radians(-48.0)), math.sin(math.radians(-48.0))])
        neutral_height = math.sqrt(0.75**2 - float(np.sum((c - b) ** 2)))
    by_ns = {round(o.t * 1e9): o for o in outs}
    n = 0
    for topic, ns, data in _read(path):
        msg = decode_message(data)
        if topic != "/tf" or msg["child_frame_id"] != "platform":
            continue
        pose = by_ns[ns].platform_pose
        got = np.array([msg["translation"][k] for k in "xyz"])
        # the independent figure (DESIGN.md's rounded neutral height, or the hand computation)
        np.testing.assert_allclose(got, pose[:3] + (0.0, 0.0, -neutral_height), atol=1e-3)
        # and exactly the centroid of the platform joints the scene draws at that pose
        joints = robot.joint_points(np.asarray(pose))[-1]
        np.testing.assert_allclose(got, joints.mean(axis=0), atol=1e-12)
        n += 1
    assert n == len(outs)
