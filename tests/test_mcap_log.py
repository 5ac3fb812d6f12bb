"""McapLogger: real files read back by the mcap library, schemas, exact floats, crash safety."""

from __future__ import annotations

import json
import math
import os
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import NonSeekingReader, make_reader
from scipy.spatial.transform import Rotation

from motionbase import __version__
from motionbase.errors import ConfigError, MotionbaseError, SinkError
from motionbase.io import mcap_log
from motionbase.io.mcap_log import McapLogger
from motionbase.io.mcap_source import read_messages
from motionbase.io.scene import SceneBuilder
from motionbase.io.schemas import TOPIC_SCHEMAS
from motionbase.physics import quaternion_from_euler_zyx
from motionbase.platform import Rus6Geometry
from motionbase.platform.rus6 import Rus6Robot

RNG = np.random.default_rng(7)
_SCENE = SceneBuilder(Rus6Robot(Rus6Geometry.preset("ceart")))
CONFIG = {
    "source": {"kind": "jsbsim", "script": "c1723", "rate_hz": 120.0},
    "geometry": {"crank": 0.184, "rod": 0.724, "pivots": np.linspace(0, 1, 6)},
    "washout": {"k_f": [0.6, 0.6, 0.5], "tilt_rate_deg": 3.0},
    "rate_hz": 120.0,
}


def _sample_messages(t: float) -> dict[str, dict]:
    """One message per topic with random values (numpy arrays, as the pipeline gives them)."""
    return {
        "/aircraft/state": {
            "specific_force": RNG.normal(size=3),
            "angular_velocity": RNG.normal(size=3),
            "attitude": RNG.normal(size=3),
            "angular_acceleration": RNG.normal(size=3),
        },
        "/washout/pose": {"pose": RNG.normal(size=6) * 0.1},
        "/platform/pose": {"pose": RNG.normal(size=6) * 0.1, "clamped": bool(RNG.random() < 0.5)},
        "/platform/actuators": {"angles": RNG.normal(size=6)},
        "/planar/pose": {"pose": RNG.normal(size=3)},
        "/planar/actuators": {
            "angles": RNG.normal(size=3),
            "servo_deg": RNG.integers(0, 181, size=3),
        },
        "/health": {
            "rejected_inputs": 1,
            "clamps": 2,
            "rate_limited": 0,
            "watchdog_fades": 0,
            "estops": 0,
            "worst_overrun_s": 0.001,
            "extra_counter": 5,
        },
        "/cursor": {"pixel": [320.0, 240.0], "target": RNG.normal(size=2) * 0.01},
        "/platform/scene": _SCENE.message(t, np.zeros(6), RNG.normal(size=6) * 0.5),
        "/cueing/mpc": {
            "t": t,
            "status": "solved",
            "iterations": 12,
            "solve_time_s": 4e-4,
            "fallback": False,
            "weight": 1.0,
            "preview": False,
            "violation": 0.0,
        },
    }


def _write_log(path: Path, n: int = 240, rate: float = 120.0) -> list[tuple[str, float, dict]]:
    written = []
    with McapLogger(path, CONFIG) as logger:
        for k in range(1, n + 1):
            t = k / rate
            for topic, msg in _sample_messages(t).items():
                logger.add(topic, t, msg)
                written.append((topic, t, msg))
            pose = RNG.normal(size=6) * 0.1
            logger.add_transform(t, pose)
            written.append(("/tf", t, {"pose": pose}))
    return written


def test_every_message_reads_back_with_mcap_and_validates(tmp_path: Path) -> None:
    path = tmp_path / "all.mcap"
    written = _write_log(path)
    validators = {
        name: jsonschema.Draft202012Validator(schema) for name, schema in TOPIC_SCHEMAS.values()
    }
    for schema in TOPIC_SCHEMAS.values():
        jsonschema.Draft202012Validator.check_schema(schema[1])
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == len(written) + 2  # + world->base transforms
        assert summary.statistics.chunk_count >= 2  # 2 s of data, 1 s per chunk
        topics = {ch.topic for ch in summary.channels.values()}
        assert topics == set(TOPIC_SCHEMAS)
        count = 0
        for schema, channel, message in reader.iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            assert json.loads(schema.data) == TOPIC_SCHEMAS[channel.topic][1]
            decoded = json.loads(message.data)
            validators[schema.name].validate(decoded)
            assert message.publish_time == message.log_time
            if channel.topic == "/tf":
                ts = decoded["timestamp"]
                assert ts["sec"] * 10**9 + ts["nsec"] == message.log_time
            else:
                assert message.log_time == round(decoded["t"] * 1e9)
            count += 1
        assert count == summary.statistics.message_count
        (meta,) = list(reader.iter_metadata())
    assert meta.name == "motionbase"
    assert meta.metadata["version"] == __version__
    config = json.loads(meta.metadata["config"])
    assert config["geometry"]["pivots"] == np.linspace(0, 1, 6).tolist()
    assert config["washout"] == CONFIG["washout"]

    # the values are the ones written, exactly, in the same order per topic
    by_topic = read_messages(path)
    for topic in TOPIC_SCHEMAS:
        if topic == "/tf":
            continue
        expected = [(t, m) for tp, t, m in written if tp == topic]
        got = by_topic[topic]
        assert len(got) == len(expected)
        for (t, msg), back in zip(expected, got, strict=True):
            assert back["t"] == t
            for key, value in msg.items():
                np.testing.assert_array_equal(np.asarray(back[key]), np.asarray(value))


def test_streaming_reader_reads_the_same_messages(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    _write_log(path, n=130)
    with open(path, "rb") as fh:
        seeking = [
            (c.topic, m.log_time, m.data)
            for _, c, m in make_reader(fh).iter_messages(log_time_order=False)
        ]
    with open(path, "rb") as fh:
        streaming = [
            (c.topic, m.log_time, m.data)
            for _, c, m in NonSeekingReader(fh, validate_crcs=True).iter_messages(
                log_time_order=False
            )
        ]
    assert seeking == streaming and len(seeking) > 0


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=60, deadline=None)
@given(values=st.lists(finite, min_size=6, max_size=6), t=st.floats(0, 1e5))
def test_floats_round_trip_bit_for_bit(tmp_path_factory, values: list[float], t: float) -> None:
    path = tmp_path_factory.mktemp("rt") / "rt.mcap"
    special = [0.1, -0.0, 5e-324, 1.7976931348623157e308, 2.2250738585072014e-308, 1 / 3]
    with McapLogger(path, {}) as logger:
        logger.add("/washout/pose", t, {"pose": np.array(values)})
        logger.add("/platform/actuators", t, {"angles": special})
    back = read_messages(path)
    got = back["/washout/pose"][0]
    assert got["t"] == t
    assert struct.pack("<6d", *got["pose"]) == struct.pack("<6d", *values)
    assert struct.pack("<6d", *back["/platform/actuators"][0]["angles"]) == struct.pack(
        "<6d", *special
    )


def test_one_tick_with_a_non_finite_number_keeps_every_other_number_exact(tmp_path: Path) -> None:
    # a tick's messages travel to the writer process as one batch; one NaN among them sends
    # the whole batch through the standard library's encoder: the other numbers stay exact
    path = tmp_path / "batch.mcap"
    exact = [0.1, -0.0, 5e-324, 1.7976931348623157e308, 1e-5, 1 / 3]
    bad = {"specific_force": [math.nan, 1e-5, -9.81], "angular_velocity": [0.0] * 3}
    with McapLogger(path, {}) as logger:
        logger.add_many(
            0.25,
            [
                ("/aircraft/state", {**bad, "attitude": [0.0] * 3}),
                ("/washout/pose", {"pose": exact}),
            ],
            transform=exact,
        )
    back = read_messages(path)
    assert struct.pack("<6d", *back["/washout/pose"][0]["pose"]) == struct.pack("<6d", *exact)
    force = back["/aircraft/state"][0]["specific_force"]
    assert math.isnan(force[0]) and force[1:] == [1e-5, -9.81]
    (tf,) = [m for m in back["/tf"] if m["child_frame_id"] == "platform"]
    assert [tf["translation"][k] for k in "xyz"] == exact[:3]


def test_encoding_round_trips_and_handles_non_finite() -> None:
    encode = mcap_log.encode_message
    values = RNG.normal(size=50) * 10.0 ** RNG.integers(-300, 300, size=50)
    plain = json.loads(encode({"t": 1.5, "x": values}))
    assert plain["x"] == values.tolist()
    odd = json.loads(encode({"t": 0.0, "x": [math.nan, math.inf, -math.inf, 1.0]}))
    assert odd["x"] == ["NaN", "Infinity", "-Infinity", 1.0]
    odd32 = json.loads(encode({"x": np.array([np.nan, 2.5], dtype=np.float32)}))
    assert odd32["x"] == ["NaN", 2.5]
    strided = json.loads(encode({"x": np.arange(10.0)[::3]}))
    assert strided["x"] == [0.0, 3.0, 6.0, 9.0]


def test_non_finite_aircraft_state_is_valid_json_and_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "nan.mcap"
    with McapLogger(path, {}) as logger:
        logger.add(
            "/aircraft/state",
            0.5,
            {
                "specific_force": [math.nan, math.inf, -9.81],
                "angular_velocity": [0.0, -math.inf, 0.0],
                "attitude": [0.0, 0.0, 0.0],
            },
        )
    with open(path, "rb") as fh:
        (item,) = list(make_reader(fh).iter_messages())
    raw = item[2].data.decode()
    assert "NaN" in raw and "Infinity" in raw
    decoded = json.loads(raw, parse_constant=lambda c: pytest.fail(f"bare {c} in JSON"))
    jsonschema.validate(decoded, TOPIC_SCHEMAS["/aircraft/state"][1])
    back = read_messages(path)["/aircraft/state"][0]
    assert math.isnan(back["specific_force"][0]) and back["specific_force"][1] == math.inf
    assert back["angular_velocity"][1] == -math.inf


@pytest.mark.parametrize("angles", [(0.1, -0.2, 0.3), (1.2, 0.7, -2.5), (0.0, 0.0, 3.1)])
def test_transform_is_the_zyx_rotation(tmp_path: Path, angles: tuple[float, float, float]) -> None:
    roll, pitch, yaw = angles
    q = np.array(quaternion_from_euler_zyx(roll, pitch, yaw))
    ref = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()  # (x, y, z, w)
    assert np.allclose(q, ref) or np.allclose(q, -ref)
    # and it maps platform vectors to base axes as R = Rz(yaw) Ry(pitch) Rx(roll)
    c, s = np.cos, np.sin
    rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    assert np.allclose(Rotation.from_quat(q).as_matrix(), rz @ ry @ rx)

    path = tmp_path / "tf.mcap"
    pose = [0.01, -0.02, -0.05, roll, pitch, yaw]
    with McapLogger(path, {}) as logger:
        logger.add_transform(2.25, np.array(pose))
    tfs = read_messages(path)["/tf"]
    validator = jsonschema.Draft202012Validator(TOPIC_SCHEMAS["/tf"][1])
    for msg in tfs:
        validator.validate(msg)
        assert msg["timestamp"] == {"sec": 2, "nsec": 250_000_000}
    world = next(m for m in tfs if m["parent_frame_id"] == "world")
    assert world["child_frame_id"] == "base"
    # world is z-up: the base's z (down) axis must map to world -z, x stays forward
    r_wb = Rotation.from_quat([world["rotation"][k] for k in "xyzw"]).as_matrix()
    assert np.allclose(r_wb @ [0, 0, 1], [0, 0, -1]) and np.allclose(r_wb @ [1, 0, 0], [1, 0, 0])
    plat = next(m for m in tfs if m["child_frame_id"] == "platform")
    assert plat["parent_frame_id"] == "base"
    assert [plat["translation"][k] for k in "xyz"] == pose[:3]
    assert np.allclose([plat["rotation"][k] for k in "xyzw"], q)


def test_unknown_topic_is_named(tmp_path: Path) -> None:
    with McapLogger(tmp_path / "u.mcap", {}) as logger:
        with pytest.raises(MotionbaseError, match="/platform/posee"):
            logger.add("/platform/posee", 0.0, {"pose": [0] * 6})


def test_bad_times_and_lifecycle_errors(tmp_path: Path) -> None:
    logger = McapLogger(tmp_path / "l.mcap", {})
    with pytest.raises(SinkError, match="start"):
        logger.add("/washout/pose", 0.0, {"pose": [0.0] * 6})
    logger.start()
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(SinkError, match="finite and >= 0"):
            logger.add("/washout/pose", bad, {"pose": [0.0] * 6})
    logger.finish()
    logger.finish()  # idempotent
    with pytest.raises(SinkError, match="finished"):
        logger.add("/washout/pose", 0.0, {"pose": [0.0] * 6})
    with pytest.raises(ConfigError, match="compression"):
        McapLogger(tmp_path / "x.mcap", {}, compression="gzip")


def test_extra_topics_are_logged_with_their_schema_and_bad_ones_refused(tmp_path: Path) -> None:
    """A plug-in's topic (``topics=``) gets a channel with its JSON Schema; a built-in topic
    keeps its own schema; an entry that is not (name, schema of an object) is refused."""
    schema = {"type": "object", "properties": {"n": {"type": "integer"}}, "required": ["n"]}
    path = tmp_path / "extra.mcap"
    other = {"type": "object"}
    with McapLogger(
        path, {}, topics={"/cueing/mine": ("my.Diag", schema), "/health": ("x.Other", other)}
    ) as logger:
        logger.add("/cueing/mine", 0.5, {"n": 3})
        logger.add("/washout/pose", 0.5, {"pose": [0.0] * 6})
        assert logger.topics["/health"] == TOPIC_SCHEMAS["/health"]
    with open(path, "rb") as fh:
        seen = {
            channel.topic: (s.name, json.loads(s.data), json.loads(m.data))
            for s, channel, m in make_reader(fh).iter_messages()
        }
    assert seen["/cueing/mine"] == ("my.Diag", schema, {"t": 0.5, "n": 3})
    assert seen["/washout/pose"][0] == TOPIC_SCHEMAS["/washout/pose"][0]
    for bad in (("", schema), ("my.Diag", {"type": "array"}), "my.Diag", ("a", "b", "c")):
        with pytest.raises(ConfigError, match="/cueing/mine"):
            McapLogger(tmp_path / "x.mcap", {}, topics={"/cueing/mine": bad})
    with pytest.raises(ConfigError, match="'mine'"):
        McapLogger(tmp_path / "x.mcap", {}, topics={"mine": ("my.Diag", schema)})


def test_a_transform_that_is_not_six_finite_numbers_is_a_sink_error(tmp_path: Path) -> None:
    """The writer process builds /tf from the pose: a pose it could not turn into a
    rotation is refused where it is given, in one line, and the log goes on."""
    path = tmp_path / "tf.mcap"
    with McapLogger(path, {}) as logger:
        for k, bad in enumerate(
            ([0.0, 0.0, 0.0, math.nan, 0.0, 0.0], [0.0, math.inf, 0, 0, 0, 0], [0.0] * 5)
        ):
            with pytest.raises(SinkError) as err:
                logger.add_transform(1.0 + k, bad)
            assert "\n" not in str(err.value) and "6 finite numbers" in str(err.value)
        logger.add_transform(5.0, [0.0, 0.0, -0.1, 0.0, 0.0, 0.0])
    tfs = read_messages(path)["/tf"]
    assert [m["child_frame_id"] for m in tfs] == ["base", "platform"]
    assert tfs[1]["translation"] == {"x": 0.0, "y": 0.0, "z": -0.1}


def test_time_beyond_mcaps_u64_nanoseconds_is_a_sink_error(tmp_path: Path) -> None:
    """MCAP log times are u64 ns: 2**64 ns is about 1.8e10 s; later times cannot be logged."""
    path = tmp_path / "far.mcap"
    last_ok = (2**64 - 2**12) / 1e9  # a double just below 2**64 ns
    with McapLogger(path, {}) as logger:
        logger.add("/washout/pose", 1.0, {"pose": [0.0] * 6})
        for bad in (2**64 / 1e9, 1e12, 1e300):
            for call, args in (
                (logger.add, ("/washout/pose", bad, {"pose": [0.0] * 6})),
                (logger.add_many, (bad, [("/washout/pose", {"pose": [0.0] * 6})])),
                (logger.add_transform, (bad, [0.0] * 6)),
            ):
                with pytest.raises(SinkError) as err:
                    call(*args)
                msg = str(err.value)
                assert "\n" not in msg and str(path) in msg and "u64" in msg, msg
        logger.add("/washout/pose", last_ok, {"pose": [0.0] * 6})  # the log goes on
    with open(path, "rb") as fh:
        times = [m.log_time for _, _, m in make_reader(fh).iter_messages()]
    assert times == [10**9, round(last_ok * 1e9)] and times[-1] < 2**64


def test_lz4_and_uncompressed_files_read_back(tmp_path: Path) -> None:
    for compression in ("lz4", "none"):
        path = tmp_path / f"{compression}.mcap"
        with McapLogger(path, {}, compression=compression) as logger:
            for k in range(300):
                logger.add("/washout/pose", k / 100, {"pose": [k * 0.001] * 6})
        with open(path, "rb") as fh:
            reader = make_reader(fh, validate_crcs=True)
            assert {c.compression for c in reader.get_summary().chunk_indexes} == {
                "" if compression == "none" else compression
            }
            assert len(list(reader.iter_messages())) == 300


def test_unwritable_path_gives_one_line_naming_the_file(tmp_path: Path) -> None:
    target = tmp_path / "no-such-folder" / "run.mcap"
    with pytest.raises(SinkError) as err:
        McapLogger(target, {}).start()
    msg = str(err.value)
    assert str(target) in msg and "\n" not in msg


def test_disk_full_gives_one_line_naming_the_file() -> None:
    assert os.path.exists("/dev/full"), "this test needs Linux's /dev/full (always full)"
    with pytest.raises(SinkError) as err:
        with McapLogger("/dev/full", {}) as logger:
            for k in range(1000):
                logger.add("/washout/pose", k / 100, {"pose": [0.0] * 6})
    msg = str(err.value)
    assert "/dev/full" in msg and "disk full" in msg and "\n" not in msg


def test_exception_inside_with_still_finishes_the_file(tmp_path: Path) -> None:
    path = tmp_path / "exc.mcap"
    with pytest.raises(RuntimeError, match="boom"):
        with McapLogger(path, CONFIG) as logger:
            for k in range(50):
                logger.add("/washout/pose", k / 120, {"pose": [0.0] * 6})
            raise RuntimeError("boom")
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_summary().statistics.message_count == 50


def test_open_log_is_on_disk_up_to_the_last_second(tmp_path: Path) -> None:
    """While the logger runs, a reader already sees every chunk older than ~1 s."""
    path = tmp_path / "live.mcap"
    logger = McapLogger(path, CONFIG).start()
    rate = 120
    for k in range(1, int(3.5 * rate) + 1):
        logger.add("/washout/pose", k / rate, {"pose": [k * 1e-4] * 6})
    # the file has no footer yet: it reads like a cut file. The writer process
    # gets each chunk to the OS within moments (30 s: a watchdog, not a bound)
    deadline = time.monotonic() + 30.0
    while True:
        times = [m["t"] for m in read_messages(path).get("/washout/pose", [])]
        if (times and times[-1] >= 3.5 - 1.0 - 1 / rate) or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    assert times == [k / rate for k in range(1, len(times) + 1)]  # a prefix, no gap
    assert times[-1] >= 3.5 - 1.0 - 1 / rate
    logger.finish()
    assert len(read_messages(path)["/washout/pose"]) == int(3.5 * rate)


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_unfinished_chunk_on_disk_reads_as_a_cut(tmp_path: Path, compression: str) -> None:
    """The chunk in progress reaches the disk before it is finished (the writer streams
    it, with a placeholder length): a reader of the live file stops before it."""
    path = tmp_path / "unfinished.mcap"
    rng = np.random.default_rng(5)
    logger = McapLogger(path, {}, chunk_size=64 << 20, compression=compression).start()
    for k in range(1, 201):
        logger.add("/washout/pose", k / 1000, {"pose": rng.normal(size=6)})
    logger.flush()
    flushed = path.stat().st_size
    for k in range(201, 1000):  # 0.8 s more: no flush due, the chunk only grows
        logger.add("/washout/pose", k / 1000, {"pose": rng.normal(size=6)})
    deadline = time.monotonic() + 30.0  # the writer process takes the records as they come
    while path.stat().st_size <= flushed + 10_000 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert path.stat().st_size > flushed + 10_000, "the unfinished chunk is not on disk"
    times = [m["t"] for m in read_messages(path)["/washout/pose"]]
    assert times == [k / 1000 for k in range(1, 201)]
    logger.finish()
    assert len(read_messages(path)["/washout/pose"]) == 999


_CHILD = """
import sys, time
from motionbase.io.mcap_log import McapLogger
logger = McapLogger(sys.argv[1], {"rate_hz": 120.0}).start()
k = 0
while True:
    k += 1
    t = k / 120
    logger.add("/aircraft/state", t, {"specific_force": [0.0, 0.0, -9.80665],
               "angular_velocity": [0.0, 0.0, 0.0], "attitude": [0.0, 0.0, t]})
    logger.add("/washout/pose", t, {"pose": [t, 0.0, 0.0, 0.0, 0.0, 0.0]})
    print(repr(t), flush=True)
    time.sleep(0.0005)
"""


def test_killed_writer_leaves_a_readable_prefix(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(path)], stdout=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + 20
        last = 0.0
        assert proc.stdout is not None
        while last < 3.0 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            last = float(line)
        assert last >= 3.0, "child did not get going"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    got = read_messages(path)  # at once: the writer process may still be finishing the file
    times = [m["t"] for m in got["/aircraft/state"]]
    assert times == [k / 120 for k in range(1, len(times) + 1)]
    # at most about a second (one chunk) is lost
    assert times[-1] >= last - 1.0 - 1 / 120
    assert len(got["/washout/pose"]) in (len(times), len(times) - 1)
    # the writer process reads to the end of its input and finishes the file: only what the
    # killed process had not handed over is lost (at most 16 KiB, here about 30 ticks)
    summary = _finished_summary(path, timeout_s=20)
    got = read_messages(path)
    times = [m["t"] for m in got["/aircraft/state"]]
    assert times == [k / 120 for k in range(1, len(times) + 1)]
    assert times[-1] >= last - 0.5
    assert summary.statistics.message_count == sum(len(v) for v in got.values())


def _finished_summary(path: Path, timeout_s: float):
    """The summary of ``path`` once its writer has finished it (None before the timeout)."""
    deadline = time.monotonic() + timeout_s
    while True:
        with open(path, "rb") as fh:
            try:
                summary = make_reader(fh).get_summary()
            except Exception:  # noqa: BLE001 - not finished yet: no footer to read
                summary = None
        if summary is not None or time.monotonic() > deadline:
            return summary
        time.sleep(0.05)


def _writer_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as fh:  # a zombie is not alive
        return fh.read().rsplit(")", 1)[1].split()[0] != "Z"


def test_the_writer_process_ignores_the_terminals_signals(tmp_path: Path) -> None:
    """Ctrl-C at a terminal signals the whole foreground group: the writer is not in it, and
    a stop signal sent to it straight does not cut the log either (the pipeline's close
    ends it)."""
    path = tmp_path / "signals.mcap"
    with McapLogger(path, CONFIG) as logger:
        pid = logger.writer_pid
        assert pid is not None and pid != os.getpid()
        assert os.getsid(pid) != os.getsid(0) and os.getpgid(pid) != os.getpgid(0)
        for k in range(1, 121):
            logger.add("/washout/pose", k / 120, {"pose": [k * 1e-3] * 6})
            if k == 60:
                for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT):
                    os.kill(pid, sig)
        logger.flush()
        assert _writer_alive(pid)
    assert not _writer_alive(pid)  # finish() waited for it
    assert len(read_messages(path)["/washout/pose"]) == 120


def test_a_vanished_writer_process_is_one_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "vanished.mcap"
    logger = McapLogger(path, CONFIG).start()
    for k in range(1, 241):  # two seconds: one chunk on disk
        logger.add("/washout/pose", k / 120, {"pose": [k * 1e-3] * 6})
    logger.flush()
    os.kill(logger.writer_pid, signal.SIGKILL)
    with pytest.raises(SinkError) as err:
        for k in range(241, 120 * 60):  # the records reach the pipe 16 KiB at a time
            logger.add("/washout/pose", k / 120, {"pose": [k * 1e-3] * 6})
    msg = str(err.value)
    assert str(path) in msg and "writer process" in msg and "\n" not in msg
    with pytest.raises(SinkError, match="writer process"):  # the same error after it
        logger.add("/washout/pose", 100.0, {"pose": [0.0] * 6})
    logger.finish()  # reported already: no second error
    times = [m["t"] for m in read_messages(path)["/washout/pose"]]
    assert times[: 2 * 120] == [k / 120 for k in range(1, 241)]  # what was on disk stays


_CHILD_FULL = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))
from motionbase.errors import SinkError
from motionbase.io.mcap_log import McapLogger
try:
    with McapLogger(sys.argv[1], {}) as logger:
        for k in range(1, 120 * 60):
            logger.add("/washout/pose", k / 120, {"pose": [k * 1e-3] * 6})
    print("no error")
except SinkError as err:
    print("SinkError:", err)
"""


def test_file_size_limit_mid_run_is_reported_and_the_log_stays_readable(tmp_path: Path) -> None:
    """The disk fills up mid-run (a 60 kB file-size limit): one clear error, a readable log."""
    path = tmp_path / "full.mcap"
    result = subprocess.run(
        [sys.executable, "-c", _CHILD_FULL, str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    out = result.stdout.strip()
    assert result.returncode == 0, result.stderr
    assert out.startswith("SinkError:") and str(path) in out and "\n" not in out, out
    times = [m["t"] for m in read_messages(path)["/washout/pose"]]
    assert len(times) > 120 and times == [k / 120 for k in range(1, len(times) + 1)]


def _process_state(pid: int) -> str:
    """The state letter of process ``pid`` (``T``: stopped)."""
    with open(f"/proc/{pid}/stat") as fh:
        return fh.read().rsplit(")", 1)[1].split()[0]


def test_a_stopped_writer_never_holds_up_a_real_time_logger(tmp_path: Path) -> None:
    """The writer process stopped (SIGSTOP; a disk that hangs does the same): a real-time
    logger's calls go on, its records waiting in memory; a backlog past BACKLOG_BYTES is one
    SinkError, finish() leaves the stopped writer be, and once the writer runs again it
    finishes the file with what it was handed. (A call that waits on the full pipe would
    hold up the pipeline's tick, and the platform with it, as long as the writer is stopped.)
    """
    path = tmp_path / "stopped.mcap"
    logger = McapLogger(path, CONFIG, realtime=True).start()
    pid = logger.writer_pid
    assert pid is not None
    os.kill(pid, signal.SIGSTOP)
    # a logger that waits for the writer would wait forever: let the writer go on after a
    # minute, so that such a logger fails below instead of hanging the test
    rescue = threading.Timer(60.0, os.kill, (pid, signal.SIGCONT))
    rescue.start()
    added = 0
    try:
        with pytest.raises(SinkError) as err:
            for k in range(1, 400_000):
                logger.add("/washout/pose", k / 1000, {"pose": [k * 1e-3] * 6})
                added = k
        with pytest.raises(SinkError, match="writer process"):  # the same error after it
            logger.add("/washout/pose", 1000.0, {"pose": [0.0] * 6})
        logger.finish()  # reported already: no second error, and no wait for the writer
        state = _process_state(pid)
    finally:
        rescue.cancel()
        os.kill(pid, signal.SIGCONT)
    assert state == "T", "finish() or an add() waited until the writer ran again"
    msg = str(err.value)
    assert str(path) in msg and "writer process" in msg and "\n" not in msg
    summary = _finished_summary(path, timeout_s=30)  # the writer finishes the file on its own
    assert summary is not None
    times = [m["t"] for m in read_messages(path)["/washout/pose"]]
    assert len(times) > 0 and times == [k / 1000 for k in range(1, len(times) + 1)]
    assert summary.statistics.message_count == len(times)
    # the file has what the pipe took; the calls went on far beyond it while it was stopped
    assert added > 4 * len(times)


def test_actuator_schema_gives_the_stewart_platforms_unit():
    """A 6-UPS Stewart platform logs its actuator *lengths* (m, joint centre to joint centre,
    0.60-0.90 m on the seat preset) on /platform/actuators; the schema Foxglove shows must
    not call every value a crank angle in rad (it did: 0.75 "rad" for a 0.75 m leg)."""
    from motionbase.io.schemas import TOPIC_SCHEMAS

    _, schema = TOPIC_SCHEMAS["/platform/actuators"]
    text = schema["description"] + " " + schema["properties"]["angles"]["description"]
    assert "rad" in text and ", m" in text and "Stewart" in text


def test_a_writer_stopped_with_its_pipe_full_ends_a_real_time_finish_with_a_sink_error(
    tmp_path: Path,
) -> None:
    """The writer process stopped with its pipe full and a backlog short of BACKLOG_BYTES
    (a run's last seconds): a real-time finish() gives up after its patience with the one
    SinkError naming the writer, and the writer, run again, still finishes the file. (The
    give-up cleared the backlog while a view of it was held: a BufferError, a traceback.)"""
    path = tmp_path / "full.mcap"
    logger = McapLogger(path, CONFIG, realtime=True).start()
    pid = logger.writer_pid
    assert pid is not None
    os.kill(pid, signal.SIGSTOP)
    rescue = threading.Timer(60.0, os.kill, (pid, signal.SIGCONT))  # (against a hang)
    rescue.start()
    try:
        for k in range(1, 40_001):  # about 4 MB: the 1 MiB pipe full, the rest waiting
            logger.add("/washout/pose", k / 1000, {"pose": [k * 1e-3] * 6})
        with pytest.raises(SinkError) as err:
            logger.finish()
    finally:
        rescue.cancel()
        os.kill(pid, signal.SIGCONT)
    msg = str(err.value)
    assert str(path) in msg and "writer process" in msg and "\n" not in msg
    assert _finished_summary(path, timeout_s=30) is not None  # finished on its own


def test_the_platform_schemas_take_six_values_exactly_and_a_plugins_its_own():
    """/platform/pose and /platform/actuators of the 6-DOF platforms take 6 values, no fewer
    (a robot plug-in of fewer axes had made them take 1 to 6 for every robot); a plug-in's
    log stores its own, sized to it (``platform_topics``)."""
    from motionbase.io.schemas import platform_topics

    for sizes, good in (((6, 6), 6), ((3, 3), 3)):
        topics = TOPIC_SCHEMAS if sizes == (6, 6) else platform_topics(*sizes)
        for topic, field in (("/platform/pose", "pose"), ("/platform/actuators", "angles")):
            schema = topics[topic][1]
            jsonschema.validate({"t": 0.0, "clamped": False, field: [0.0] * good}, schema)
            for wrong in (good - 1, good + 1):
                with pytest.raises(jsonschema.ValidationError):
                    bad = {"t": 0.0, "clamped": False, field: [0.0] * wrong}
                    jsonschema.validate(bad, schema)
