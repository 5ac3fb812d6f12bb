"""The live view: a Foxglove WebSocket client watches a run and gets what the log holds.

The client here is written from Foxglove's WebSocket protocol (``websockets`` package,
subprotocol ``foxglove.sdk.v1`` or the older ``foxglove.websocket.v1``): it reads the server's
``serverInfo`` and ``advertise`` JSON messages (these at any time, as Foxglove does: a topic is
advertised with its first message), sends ``subscribe`` with a subscription id per channel as
it is advertised, and decodes binary message frames (opcode 0x01, subscription id u32 LE, log time
u64 LE, payload). The runs are real ``motionbase`` processes on loopback (port 0: the process
prints the port it got), stopped with SIGINT once the client has what it needs; the MCAP file
of the same run is read back with the ``mcap`` reader. The live feed is the log at a screen's
rate: each topic at most 60 messages per second of source time, so a 120 Hz run serves every
other tick, and the 30 Hz scene every scene. The scene's points are checked against the
robot's own ``joint_points`` of the logged pose, computed here from the logged messages.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from drive_wire import UdpDrive
from mcap.reader import make_reader
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from motionbase import app
from motionbase.app import load_config
from motionbase.cli import main
from motionbase.errors import ConfigError
from motionbase.io.mcap_log import LiveAddress, McapLogger, encode_message
from motionbase.io.mcap_source import read_messages, read_metadata
from motionbase.io.scene import NEAR_LIMIT_DEG, SceneBuilder
from motionbase.pipeline import Pipeline, PipelineConfig
from motionbase.platform import Rrr3, Rrr3Geometry, Rus6, Rus6Geometry
from motionbase.platform.rrr3 import Rrr3Robot
from motionbase.platform.rus6 import Rus6Robot
from motionbase.state import AircraftState

ROOT = Path(__file__).resolve().parents[1]
PLANAR_RECORDING = ROOT / "recordings" / "c1723_planar_15s.mcap"
RUS6_RECORDING = ROOT / "recordings" / "c1723_30s.mcap"
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
#: the topics a flight of a 6-DOF robot logs, classical cueing
STEWART_FLIGHT_TOPICS = {"/aircraft/state", "/washout/pose", "/platform/pose",
                         "/platform/actuators", "/tf", "/platform/scene", "/health"}  # fmt: skip


# --------------------------------------------------------------------------- helpers


def _start(
    args: list[str], tmp_path: Path, program: list[str] | None = None
) -> tuple[subprocess.Popen, str]:
    """Start ``motionbase ARGS --live 127.0.0.1:0`` (or ``PROGRAM ARGS ...``, a script that
    calls the command line); return it and the URL it prints."""
    proc = subprocess.Popen(
        [sys.executable, *(program or ["-m", "motionbase.cli"]), *args, "--live", "127.0.0.1:0"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    lines = []
    for line in proc.stderr:  # the run says where it serves before its loop starts
        lines.append(line)
        found = re.search(r"live view: (ws://\S+)", line)
        if found:
            return proc, found.group(1)
    proc.wait()
    pytest.fail(f"no live view line; exit {proc.returncode}: {''.join(lines)}")


class _Feed:
    """What a Foxglove client keeps of one connection ``ws``: channels are advertised at any
    time (a topic's with its first message), and each one of ``topics`` (None: every one) is
    subscribed to as soon as it is; message frames are kept as (log time, payload) per topic.

    Attributes: ``channels`` (topic -> its advertised channel), ``advertised`` (the topics of
    each advertise message, in order), ``got`` (topic -> messages received)."""

    def __init__(self, ws, topics: set[str] | None = None) -> None:
        self.ws, self.topics = ws, topics
        self.channels: dict[str, dict] = {}
        self.advertised: list[set[str]] = []
        self.got: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics or ()}
        self._by_sub: dict[int, str] = {}  # subscription id -> topic

    def handle(self, msg: str | bytes) -> None:
        """Take one message from the server (serverInfo, status, unadvertise are ignored)."""
        if isinstance(msg, bytes):
            assert msg[0] == MESSAGE_DATA
            sub, log_time = struct.unpack_from("<IQ", msg, 1)
            self.got[self._by_sub[sub]].append((log_time, bytes(msg[13:])))
            return
        msg = json.loads(msg)
        if msg["op"] != "advertise":
            return
        self.advertised.append({c["topic"] for c in msg["channels"]})
        subs = []
        for c in msg["channels"]:
            if c["topic"] not in self.channels and c["topic"] in (self.topics or [c["topic"]]):
                self.channels[c["topic"]] = c
                self.got.setdefault(c["topic"], [])
                self._by_sub[len(self._by_sub) + 1] = c["topic"]
                subs.append({"id": len(self._by_sub), "channelId": c["id"]})
        if subs:
            self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))


def _watch(
    url: str, topics: set[str], enough, proc: subprocess.Popen, advertised: set | None = None
) -> dict[str, list]:
    """Subscribe to ``topics`` as they are advertised; collect (log_time, payload) per topic
    until ``enough(got)``, then SIGINT the run and keep reading until the server closes the
    connection. Every topic the server advertises goes into ``advertised``."""
    with connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        assert json.loads(ws.recv(timeout=30))["op"] == "serverInfo"
        feed = _Feed(ws, topics)
        interrupted = False
        with contextlib.suppress(ConnectionClosed):  # the server stopped: the run ended
            while True:
                feed.handle(ws.recv(timeout=60))
                if not interrupted and enough(feed.got):
                    proc.send_signal(signal.SIGINT)
                    interrupted = True
    if advertised is not None:
        advertised.update(*feed.advertised)
    return feed.got


def _logged(path: Path, topics: set[str]) -> dict[str, dict[int, bytes]]:
    """Log time -> payload per topic, read back with the ``mcap`` reader."""
    out: dict[str, dict[int, bytes]] = {t: {} for t in topics}
    with open(path, "rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages(topics=sorted(topics)):
            out[channel.topic][message.log_time] = message.data
    return out


def _received_as_logged(got: list, logged: dict[int, bytes], topic: str) -> tuple[list, list]:
    """Every received message is the logged one of its time; (received times, logged times
    of the received span)."""
    times = [t for t, _ in got]
    assert times, f"no {topic} message received"
    assert times == sorted(set(times))
    for t, payload in got:
        assert payload == logged[t], f"{topic} at {t} ns differs from the log"
    return times, [t for t in sorted(logged) if times[0] <= t <= times[-1]]


def _assert_same_as_logged(got: list, logged: dict[int, bytes], topic: str) -> None:
    """A topic slower than the live rate (the 30 Hz scene): every logged message of the span."""
    times, span = _received_as_logged(got, logged, topic)
    assert span == times


def _assert_every_other_tick(got: list, logged: dict[int, bytes], topic: str) -> None:
    """A 120 Hz topic served at 60 Hz: every second logged message of the span, none between."""
    times, span = _received_as_logged(got, logged, topic)
    assert len(times) >= 2
    assert times == span[::2]


def _finish(proc: subprocess.Popen) -> str:
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    return out


def _serve(
    args: list[str], tmp_path: Path, topics: set[str], enough, advertised: set | None = None
) -> tuple[dict, str]:
    """Run ``motionbase ARGS --live``, watch ``topics`` until ``enough(got)``, stop it with
    SIGINT; return what was received per topic and the run's stdout (the topics advertised
    into ``advertised``)."""
    proc, url = _start(args, tmp_path)
    try:
        got = _watch(url, topics, enough, proc, advertised)
    except BaseException:
        proc.kill()
        raise
    return got, _finish(proc)


def _assert_served_as_logged(got: dict, path: Path, at_120_hz: tuple[str, ...] = ()) -> None:
    """Every topic received is the log's, message for message, over the span received: every
    logged message of a topic slower than the live rate, every other one of ``at_120_hz``."""
    logged = _logged(path, set(got))
    for topic in got:
        check = _assert_every_other_tick if topic in at_120_hz else _assert_same_as_logged
        check(got[topic], logged[topic], topic)


def _scene_points(entity: dict) -> tuple[list, list, list]:
    crank, rod = entity["lines"]
    (p, q), (q2, r) = ([(v["x"], v["y"], v["z"]) for v in line["points"]] for line in (crank, rod))
    assert q == q2
    return p, q, r


def _check_scenes(path: Path, planar: bool) -> int:
    """Every logged scene's leg endpoints are the robot's joint points of the logged pose."""
    config = PipelineConfig.from_dict(read_metadata(path)["pipeline_config"])
    msgs = read_messages(path)
    poses = {m["t"]: m["pose"] for m in msgs["/planar/pose" if planar else "/platform/pose"]}
    angles = {
        m["t"]: m["angles"] for m in msgs["/planar/actuators" if planar else "/platform/actuators"]
    }
    robot = Rrr3(config.geometry) if planar else Rus6(config.geometry)
    if planar:
        lo, hi = np.asarray(robot.angle_limits).T
    else:
        lo, hi = robot.angle_limits
    scenes = msgs["/platform/scene"]
    assert scenes
    for scene in scenes:
        t = scene["t"]
        pivots, tips, joints = robot.joint_points(np.array(poses[t]))
        if planar:  # the thesis's plane, z = 0
            pivots, tips, joints = (
                np.column_stack([v, np.zeros(3)]) for v in (pivots, tips, joints)
            )
        legs = [e for e in scene["entities"] if e["id"].startswith("leg")]
        assert [e["id"] for e in legs] == [f"leg{i + 1}" for i in range(len(pivots))]
        for i, leg in enumerate(legs):
            assert leg["frame_id"] == ("world" if planar else "base")
            p, q, r = _scene_points(leg)
            np.testing.assert_allclose(p, pivots[i], rtol=0, atol=1e-12)
            np.testing.assert_allclose(q, tips[i], rtol=0, atol=1e-12)
            np.testing.assert_allclose(r, joints[i], rtol=0, atol=1e-12)
            # the rod keeps its length: the drawing is a closed mechanism
            rod = robot.geometry.rod if planar else np.broadcast_to(robot.geometry.rod, 6)[i]
            assert math.dist(q, r) == pytest.approx(rod, abs=1e-9)
            a = angles[t][i]
            near = min(a - lo[i], hi[i] - a) < math.radians(NEAR_LIMIT_DEG)
            assert (
                leg["lines"][0]["color"]["r"] > 0.8 and leg["lines"][0]["color"]["g"] < 0.2
            ) == near
    return len(scenes)


# --------------------------------------------------------------------------- live runs


def test_live_fly_serves_the_logged_actuators_and_scene(tmp_path):
    out = tmp_path / "live.mcap"
    got, summary = _serve(
        ["fly", "c1723", "--realtime", "--duration", "60", "--out", str(out)],
        tmp_path,
        {"/platform/actuators", "/platform/scene"},
        lambda g: len(g["/platform/actuators"]) >= 60 and len(g["/platform/scene"]) >= 5,
    )
    assert "stopped by SIGINT" in summary
    _assert_served_as_logged(got, out, at_120_hz=("/platform/actuators",))
    # received scenes are what the robot's joint points say (checked on the whole log)
    assert _check_scenes(out, planar=False) >= 5


def test_live_replay_of_the_planar_recording(tmp_path):
    """The topics advertised are the log's (the run advertised every topic: the 6-DOF
    platform's and the MPC's too, never written by a planar run without MPC)."""
    out = tmp_path / "replay.mcap"
    advertised: set[str] = set()
    got, _ = _serve(
        ["replay", str(PLANAR_RECORDING), "--out", str(out)],
        tmp_path,
        {"/planar/actuators", "/platform/scene"},
        lambda g: len(g["/planar/actuators"]) >= 30,
        advertised,
    )
    with open(out, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert advertised == {c.topic for c in summary.channels.values()}
    assert "/planar/pose" in advertised and "/platform/pose" not in advertised
    ticks = np.diff(sorted(_logged(out, {"/planar/actuators"})["/planar/actuators"]))
    assert np.median(ticks) == pytest.approx(1e9 / 120, abs=1)  # a 120 Hz recording
    _assert_served_as_logged(got, out, at_120_hz=("/planar/actuators",))
    assert _check_scenes(out, planar=True) >= 1


def test_live_teleop_serves_the_logged_planar_actuators(tmp_path):
    rows = [
        (k / 100, 655 + 200 * math.sin(k / 50), 357 + 100 * math.cos(k / 50)) for k in range(3000)
    ]
    csv = tmp_path / "cursor.csv"
    csv.write_text("t,x,y\n" + "".join(f"{t!r},{u!r},{v!r}\n" for t, u, v in rows))
    out = tmp_path / "teleop.mcap"
    got, _ = _serve(
        ["teleop", "--input", f"file:{csv}", "--out", str(out)],
        tmp_path,
        {"/planar/actuators", "/platform/scene"},
        lambda g: len(g["/planar/actuators"]) >= 30,
    )
    _assert_served_as_logged(got, out)
    # the scene is the robot of the log's geometry at the logged pose
    geometry = read_metadata(out)["geometry"]
    robot = Rrr3(Rrr3Geometry.from_dict(geometry))
    msgs = read_messages(out)
    poses = {m["t"]: m["pose"] for m in msgs["/planar/pose"]}
    for scene in msgs["/platform/scene"]:
        _, tips, joints = robot.joint_points(np.array(poses[scene["t"]]))
        legs = [e for e in scene["entities"] if e["id"].startswith("leg")]
        for i, leg in enumerate(legs):
            _, q, r = _scene_points(leg)
            np.testing.assert_allclose(q[:2], tips[i], rtol=0, atol=1e-12)
            np.testing.assert_allclose(r[:2], joints[i], rtol=0, atol=1e-12)


def test_live_replay_without_out_serves_from_a_temporary_log(tmp_path):
    got, _ = _serve(
        ["replay", str(PLANAR_RECORDING)],
        tmp_path,
        {"/planar/pose"},
        lambda g: len(g["/planar/pose"]) >= 10,
    )
    assert len(got["/planar/pose"]) >= 10
    assert list(tmp_path.iterdir()) == []  # nothing left behind


# --------------------------------------------------------------------------- scene and checks


def test_scene_of_a_flight_is_the_robot_drawn_at_the_logged_pose(tmp_path):
    out = tmp_path / "f.mcap"
    app.fly("c1723", duration_s=3.0, out=out, progress=False)
    n = _check_scenes(out, planar=False)
    # 30 scenes per second of source time (+ the last pose), not one per tick
    msgs = read_messages(out)
    ticks = len(msgs["/platform/pose"])
    span = msgs["/platform/pose"][-1]["t"] - msgs["/platform/pose"][0]["t"]
    assert n < ticks / 2
    assert abs(n - (30 * span + 1)) <= 2


def test_scene_drawn_on_the_logs_thread_leaves_the_same_file(tmp_path):
    """The log draws scenes on a thread of its own: the same outputs still give the very same
    file, scene messages at their own times, one per 30 Hz grid point."""
    from motionbase.io.pipeline_log import PipelineLog

    pipeline = Pipeline(load_config(rate_hz=120.0))
    outs = [pipeline.step(AircraftState(k / 120, (1.0, -0.5, -9.0), (0.1, 0.0, 0.2), (0, 0, 0)))
            for k in range(1, 400)]  # fmt: skip
    files = []
    for name in ("a.mcap", "b.mcap"):
        with PipelineLog(tmp_path / name, {"kind": "test"}, robot=pipeline.robot) as log:
            for out in outs:
                log.write(out)
        files.append((tmp_path / name).read_bytes())
    assert files[0] == files[1]
    scenes = [m["t"] for m in read_messages(tmp_path / "a.mcap")["/platform/scene"]]
    assert scenes == sorted(scenes) and scenes[0] == outs[0].t and scenes[-1] == outs[-1].t
    assert len(scenes) == pytest.approx(30 * (outs[-1].t - outs[0].t) + 2, abs=1)


def test_scene_colours_a_leg_near_its_limit_red():
    robot = Rus6(Rus6Geometry.preset("ceart"))
    lo, hi = robot.angle_limits
    angles = robot.inverse(np.zeros(6)).copy()
    angles[1] = lo[1] + math.radians(NEAR_LIMIT_DEG - 1)  # 4 deg from the lower limit
    angles[4] = hi[4] - math.radians(NEAR_LIMIT_DEG + 1)  # 6 deg from the upper limit
    scene = SceneBuilder(Rus6Robot(robot.geometry)).message(0.0, np.zeros(6), angles, clamped=True)
    legs = [e for e in scene["entities"] if e["id"].startswith("leg")]
    red = [i for i, e in enumerate(legs) if e["lines"][0]["color"] == e["lines"][1]["color"]]
    assert red == [1]
    plate = next(e for e in scene["entities"] if e["id"] == "platform")
    assert plate["triangles"][0]["color"]["r"] == 1.0  # clamped: orange


def test_the_logged_scene_is_the_general_encoders_bytes(tmp_path):
    """The log's writer process builds /platform/scene from SceneBuilder.parts: the file holds
    the very bytes the general JSON encoder makes of SceneBuilder.message, for reachable poses,
    poses near limits, a clamped plate, a pose the legs cannot reach (NaN crank tips, written
    as "NaN"), and the planar robot."""
    rng = np.random.default_rng(17)
    robot = Rus6(Rus6Geometry.preset("ceart"))
    scene = SceneBuilder(Rus6Robot(robot.geometry))
    lo, hi = robot.angle_limits
    cases = []  # (builder, pose, angles, clamped), logged at increasing random times
    for k in range(300):
        pose = rng.normal(size=6) * [0.05, 0.05, 0.03, 0.1, 0.1, 0.2]
        cases.append((scene, pose, rng.uniform(lo, hi), bool(k % 2)))
    far = np.array([0.0, 0.0, -0.6, 0.0, 0.0, 0.0])  # 0.6 m up: no crank reaches
    assert np.isnan(robot.joint_points(far)[1]).any()
    cases.append((scene, far, robot.inverse(np.zeros(6)), False))
    planar = SceneBuilder(Rrr3Robot(Rrr3Geometry()))
    home = np.array([0.13, 0.26 * math.sqrt(3) / 6, 0.0])
    for _ in range(50):
        pose = home + rng.normal(size=3) * [0.01, 0.01, 0.1]
        cases.append((planar, pose, rng.uniform(0.0, math.pi, 3), False))
    times = np.sort(rng.uniform(0.0, 5000.0, len(cases)))
    with McapLogger(tmp_path / "scene.mcap", {}) as logger:
        for t, (builder, pose, angles, clamped) in zip(times, cases, strict=True):
            logger.add_scene(float(t), builder.parts(float(t), pose, angles, clamped))
    with open(tmp_path / "scene.mcap", "rb") as fh:
        logged = [m.data for _, _, m in make_reader(fh).iter_messages(["/platform/scene"])]
    expected = [
        encode_message(builder.message(float(t), pose, angles, clamped))
        for t, (builder, pose, angles, clamped) in zip(times, cases, strict=True)
    ]
    assert logged == expected
    assert b'"NaN"' in logged[300] and b'"frame_id":"world"' in logged[-1]


def test_live_feed_is_the_log_at_60_hz_per_topic(tmp_path):
    """Two seconds of a 1 kHz log with a client subscribed to everything: the file keeps every
    tick; the client gets each fast topic on a 60 Hz grid of log time (16 or 17 ms apart,
    60 per second), the 30 Hz scene and the once-a-second messages all, each message the very
    bytes the file holds."""
    rate, seconds = 1000, 2
    logger = McapLogger(tmp_path / "live.mcap", {}, live=LiveAddress("127.0.0.1", 0)).start()
    url = f"ws://127.0.0.1:{logger.live_port}"
    topics = {"/platform/actuators", "/tf", "/platform/scene", "/health"}
    client = _Client(url, topics)
    client.start()
    scene = SceneBuilder(Rus6Robot(Rus6Geometry.preset("ceart")))
    try:
        # a topic is advertised with its first message and the server applies a subscription
        # on its own thread: each topic every 20 ms (on the 60 Hz grid) until the client has
        # one of each, then the test's ticks from a whole second at least 1 s later (the
        # world -> base transform is due again there)
        deadline = time.monotonic() + 30  # a watchdog, not a bound
        k = 0
        while not all(client.feed.got[t] for t in topics):
            assert time.monotonic() < deadline, "the subscriptions never took effect"
            t = k * 0.02
            logger.add("/platform/actuators", t, {"t": t, "angles": np.full(6, t)})
            logger.add_transform(t, np.zeros(6))
            logger.add_scene(t, scene.parts(t, np.zeros(6), np.zeros(6)))
            logger.add("/health", t, {"t": t, "samples": 0})
            logger.flush()
            k += 1
            time.sleep(0.01)
        t0 = float(math.ceil(k * 0.02 + 1.0))
        t0_ns = round(t0 * 1e9)
        for k in range(rate * seconds):
            t = t0 + k / rate
            pose = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.1 * math.sin(t)])
            logger.add("/platform/actuators", t, {"t": t, "angles": np.full(6, t)})
            logger.add_transform(t, pose)
            if k % 33 == 0:
                logger.add_scene(t, scene.parts(t, pose, np.zeros(6)))
            if k % rate == 0:
                logger.add("/health", t, {"t": t, "samples": k})
            if k % 50 == 0:
                time.sleep(0.002)  # let the server's queue drain (its backlog is 1024)
        logger.flush()  # the last records to the writer process (it gets them in batches)
        deadline = time.monotonic() + 10  # the server sends on its own thread: let it
        acts = client.feed.got["/platform/actuators"]
        while sum(n >= t0_ns for n, _ in acts) < 60 * seconds and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        logger.finish()
        client.join(60)
    # from t0 on: the warm-up's messages left out
    got = {t: [(n, p) for n, p in m if n >= t0_ns] for t, m in client.feed.got.items()}
    logged = {
        t: {n: p for n, p in m.items() if n >= t0_ns}
        for t, m in _logged(tmp_path / "live.mcap", topics).items()
    }
    assert len(logged["/platform/actuators"]) == rate * seconds  # the file: every tick
    acts, _ = _received_as_logged(got["/platform/actuators"], logged["/platform/actuators"],
                                     "/platform/actuators")  # fmt: skip
    gaps = np.diff(acts) / 1e6  # ms
    assert set(gaps.round(3)) <= {16.0, 17.0}
    assert acts[0] == t0_ns and len(acts) == 60 * seconds
    _assert_same_as_logged(got["/platform/scene"], logged["/platform/scene"], "/platform/scene")
    _assert_same_as_logged(got["/health"], logged["/health"], "/health")
    # /tf: the platform frame on the 60 Hz grid, world -> base every second
    tf = [(t, json.loads(p)) for t, p in got["/tf"]]
    assert [t for t, m in tf if m["child_frame_id"] == "base"] == [t0_ns, t0_ns + 1_000_000_000]
    platform = [t for t, m in tf if m["child_frame_id"] == "platform"]
    assert platform == acts
    with open(tmp_path / "live.mcap", "rb") as fh:
        file_tf = [(m.log_time, m.data) for _, _, m in make_reader(fh).iter_messages(["/tf"])]
    assert all((t, p) in file_tf for t, p in got["/tf"])


def test_replay_check_of_a_recording_without_scene_still_passes():
    result = app.replay(RUS6_RECORDING, check=True, progress=False)
    assert not result.failed, "\n".join(result.notes)


def test_replay_check_compares_scenes_when_both_have_them():
    a = {"/platform/scene": [{"t": 0.0, "entities": [{"id": "leg1", "x": 1.0}]}]}
    b = {"/platform/scene": [{"t": 0.0, "entities": [{"id": "leg1", "x": 1.5}]}]}
    assert not app.compare_recordings(a, b).identical
    assert app.compare_recordings(a, {}).identical  # a recording from before the scene


def test_layout_names_fields_the_log_has(tmp_path):
    """Every topic and message path of the shipped Foxglove layout exists in a real log."""
    layout = json.loads((ROOT / "layouts" / "motionbase_layout.json").read_text())
    out = tmp_path / "f.mcap"
    app.fly("c1723", duration_s=1.0, out=out, progress=False)
    msgs = read_messages(out)
    paths = []
    for panel_id, config in layout["configById"].items():
        assert panel_id.split("!")[0] in {"3D", "Plot", "RawMessages"}
        paths += [p["value"] for p in config.get("paths", [])]
        paths += [config["topicPath"]] if "topicPath" in config else []
        paths += list(config.get("topics", {}))
    assert "/platform/scene" in paths and "/health" in paths
    for path in paths:
        found = re.fullmatch(r"(/[\w/]+)(?:\.(\w+)\[(\d+)\])?", path)
        assert found, path
        topic, field, index = found.groups()
        assert msgs.get(topic), f"{topic} is not in the log"
        if field is not None:
            assert len(msgs[topic][-1][field]) > int(index), path
    # the panels the layout's tree shows are the ones it configures
    tree = json.dumps(layout["layout"])
    assert sorted(re.findall(r'"(\w+![\w]+)"', tree)) == sorted(layout["configById"])


def test_layout_and_help_name_a_linear_actuator_s_lengths(capsys):
    """Every robot's log has ``/platform/actuators.angles``; a Stewart platform's holds lengths
    in m. The shipped layout titled that plot "actuator angles (rad)" with lines "crank 1".."crank
    6", and ``--output``'s help said it sends "crank angles", whatever the robot."""
    layout = json.loads((ROOT / "layouts" / "motionbase_layout.json").read_text())
    plot = layout["configById"]["Plot!actuators"]
    assert "(m)" in plot["title"] and "(rad)" in plot["title"]
    assert [p["label"] for p in plot["paths"]] == [f"actuator {i}" for i in range(1, 7)]
    with pytest.raises(SystemExit):
        main(["fly", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "send the safe actuator commands (crank angles, or lengths of linear" in text


# --------------------------------------------------------------------------- user mistakes


def test_live_address():
    assert LiveAddress.parse("8765") == LiveAddress("127.0.0.1", 8765)
    assert LiveAddress.parse("0.0.0.0:9000") == LiveAddress("0.0.0.0", 9000)
    assert LiveAddress.parse("[::1]:9000").url() == "ws://[::1]:9000"
    for bad in ("http", "70000", "127.0.0.1:x"):
        with pytest.raises(ConfigError, match="--live"):
            LiveAddress.parse(bad)


def test_port_in_use_is_one_line_and_exit_2(tmp_path, capsys):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = tmp_path / "x.mcap"
        code = main(["replay", str(PLANAR_RECORDING), "--out", str(out), "--live", str(port)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "in use" in err and str(port) in err
    assert not out.exists()


def test_fly_live_needs_realtime(capsys):
    assert main(["fly", "c1723", "--live", "8765"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--realtime" in err


def _stalled_client(ws, topics: set[str]) -> _Feed:
    """Read ``ws`` (:func:`_slow_connection`) until every one of ``topics`` is advertised,
    subscribing to each as it is (:class:`_Feed`); it reads nothing more."""
    feed = _Feed(ws, topics)
    while set(feed.channels) != topics:
        feed.handle(ws.recv(timeout=30))
    return feed


def _slow_connection(port: int):
    """A client connection that reads as little as it can: a tiny socket receive buffer, one
    message read ahead at most, no keepalive (it never leaves on its own). Its close does not
    wait for the server's (gone, behind the unread data): it waited 10 s, most of a test."""
    import socket

    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    url = f"ws://127.0.0.1:{port}"
    return connect(url, sock=sock, subprotocols=SUBPROTOCOLS, max_size=None, max_queue=1,
                   ping_interval=None, close_timeout=0.1)  # fmt: skip


def test_a_client_that_stops_reading_does_not_hold_the_logs_end(tmp_path):
    """A client that subscribes and then stops reading (a frozen Foxglove, a dead link): the
    log finishes as usual, every message in the file, and its writer process ends. The
    server's stop waited for such a client to leave (forever, without keepalive): the log's
    close then failed after 5 s ("the writer process took nothing more"), the run ended with
    status 2 and the writer process stayed on, holding the port."""
    logger = McapLogger(tmp_path / "slow.mcap", {}, live=LiveAddress("127.0.0.1", 0)).start()
    with _slow_connection(logger.live_port) as ws:
        scene = SceneBuilder(Rus6Robot(Rus6Geometry.preset("ceart")))
        n = 3000  # 100 s of scenes at 30 Hz, about 15 MB: far more than the sockets hold
        for k in range(n):
            t = k / 30
            pose = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.1 * math.sin(t)])
            logger.add_scene(t, scene.parts(t, pose, np.zeros(6)))
            if k % 30 == 0:
                logger.add("/health", t, {"t": t, "samples": k})
            if k == 0:  # both topics advertised with their first message: subscribe, stall
                logger.flush()
                _stalled_client(ws, {"/platform/scene", "/health"})
        pid = logger.writer_pid
        logger.finish()  # raised SinkError
    with pytest.raises(ChildProcessError):  # the writer is gone (reaped by finish)
        os.waitpid(pid, os.WNOHANG)
    assert len(_logged(tmp_path / "slow.mcap", {"/platform/scene"})["/platform/scene"]) == n


class _Client(threading.Thread):
    """A client on its own thread: its ``feed`` (:class:`_Feed`) of every topic (or of
    ``topics``) until the server closes the connection."""

    def __init__(self, url: str, topics: set[str] | None = None) -> None:
        super().__init__(daemon=True)
        self.url, self.feed = url, _Feed(None, topics)

    def run(self) -> None:
        with connect(self.url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
            assert json.loads(ws.recv(timeout=30))["op"] == "serverInfo"
            self.feed.ws = ws
            with contextlib.suppress(ConnectionClosed):
                while True:
                    self.feed.handle(ws.recv(timeout=60))


@pytest.mark.parametrize("robot", ["stewart6", "heave3"])
def test_live_view_of_a_robot_with_linear_actuators(robot, tmp_path):
    """A 6-UPS Stewart platform and the plug-in robot of tests/heave3_robot.py (registered by
    a script that imports it, as the README's "Adding a robot" says), flown live with two
    clients, the second connecting mid-run: each advertised the log's channels, the second
    at once those made before it connected; each channel's schema is the log's, every message
    matches it and is the log's, byte for byte; the scene draws one straight leg per actuator, base
    joint to platform joint, as long as the length logged for that tick (m), the base
    joints fixed and the platform joints fixed in the platform frame of the /tf served."""
    import jsonschema

    script = tmp_path / "run.py"
    script.write_text(
        f"import sys\nsys.path.insert(0, {str(ROOT / 'tests')!r})\nimport heave3_robot\n"
        "heave3_robot.register()\nfrom motionbase.cli import main\nsys.exit(main())\n"
    )
    out = tmp_path / "live.mcap"
    args = ["fly", "c1723", "--platform", robot, "--realtime", "--duration", "60"]
    proc, url = _start([*args, "--out", str(out)], tmp_path, program=[str(script)])
    try:
        first = _Client(url)
        first.start()
        late = None
        deadline = time.monotonic() + 120  # a watchdog, not a bound
        while late is None or len(late.feed.got["/platform/actuators"]) < 30:
            assert time.monotonic() < deadline and first.is_alive()
            if late is None and len(first.feed.got.get("/platform/actuators", ())) >= 60:
                made = set(first.feed.channels.copy())  # on the server before late connects
                late = _Client(url, {"/platform/actuators", "/tf"})
                late.start()
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        _finish(proc)
    except BaseException:
        proc.kill()
        raise
    first.join(60)
    late.join(60)
    with open(out, "rb") as fh:
        summary = make_reader(fh).get_summary()
    in_file = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
    assert "/platform/pose" in made and late.feed.advertised[0] >= made
    for client in (first, late):
        assert set().union(*client.feed.advertised) == set(in_file)
        logged = _logged(out, set(client.feed.got))
        for topic, got in client.feed.got.items():
            channel = client.feed.channels[topic]
            assert channel["encoding"] == "json" and channel["schemaEncoding"] == "jsonschema"
            assert channel["schemaName"] == in_file[topic].name
            assert channel["schema"].encode() == in_file[topic].data
            schema = json.loads(channel["schema"])
            validator = jsonschema.validators.validator_for(schema)
            validator.check_schema(schema)  # once a topic (validate() checks it each call)
            validator = validator(schema)
            for _, payload in got:
                validator.validate(json.loads(payload))
            if topic == "/tf":  # two transforms at some times: each one of the file's
                with open(out, "rb") as fh:
                    tf = {
                        (m.log_time, m.data) for _, _, m in make_reader(fh).iter_messages(["/tf"])
                    }
                assert got and set(got) <= tf
            elif got:
                _received_as_logged(got, logged[topic], topic)
    late_tf, first_tf = late.feed.got["/tf"], first.feed.got["/tf"]
    assert late_tf[0][0] > first_tf[0][0]  # it came late ...
    world = [t for t, p in late_tf if json.loads(p)["child_frame_id"] == "base"]
    assert world and world[0] - late_tf[0][0] <= 1_000_000_000  # ... and got the world
    # the scene, against the logged lengths and the served /tf
    msgs = read_messages(out)
    lengths = {m["t"]: np.array(m["angles"]) for m in msgs["/platform/actuators"]}
    frames = {
        m["timestamp"]["sec"] + m["timestamp"]["nsec"] / 1e9: m
        for m in msgs["/tf"]
        if m["child_frame_id"] == "platform"
    }
    scenes = [json.loads(p) for _, p in first.feed.got["/platform/scene"]]
    assert len(scenes) >= 10
    # heave3 takes its actuators as vertical (it neglects their lean at a tilt, see its file):
    # its drawn tops move in the plate frame by the cosine error of the tilt, under 1 mm here
    atol = 1e-9 if robot == "stewart6" else 1e-3
    local = None
    for scene in scenes:
        q = lengths[scene["t"]]
        legs = [e for e in scene["entities"] if e["id"].startswith("leg")]
        assert [e["id"] for e in legs] == [f"leg{i + 1}" for i in range(len(q))]
        ends = []
        for leg in legs:
            (line,) = leg["lines"]  # no crank: one straight actuator
            (a, b) = [np.array([p["x"], p["y"], p["z"]]) for p in line["points"]]
            ends.append((a, b))
            assert leg["frame_id"] == "base" and len(leg["spheres"]) == 2
        base, top = (np.array(v) for v in zip(*ends, strict=True))
        np.testing.assert_allclose(np.linalg.norm(top - base, axis=1), q, rtol=0, atol=1e-9)
        tf = min(frames.items(), key=lambda kv: abs(kv[0] - scene["t"]))[1]
        r, x = tf["rotation"], tf["translation"]
        rot = _rotation(r["w"], r["x"], r["y"], r["z"])
        in_platform = (top - [x["x"], x["y"], x["z"]]) @ rot  # R^T (p - t), row by row
        if local is None:
            local, base0 = in_platform, base
        np.testing.assert_allclose(base, base0, rtol=0, atol=1e-12)
        np.testing.assert_allclose(in_platform, local, rtol=0, atol=atol)


def _rotation(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The rotation matrix of a unit quaternion (w, x, y, z), written out."""
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_a_stalled_client_does_not_stop_a_flight_that_drives_motors(tmp_path):
    """``fly --realtime --output`` to a drive with ``--live``, and a client that subscribes
    to every topic and then reads nothing: the flight runs to its end and parks, the drive
    gets every command to park, the log holds every tick, another client gets the live feed
    whole, and the run ends with status 0 (it ended with status 2: "the MCAP log's writer
    process took nothing more for 5 s")."""
    drive = UdpDrive(n=6)
    out = tmp_path / "f.mcap"
    args = ["fly", "c1723", "--platform", "stewart6", "--realtime", "--duration", "8"]
    proc, url = _start([*args, "--output", drive.url(100), "--out", str(out)], tmp_path)
    try:
        with _slow_connection(int(url.rsplit(":", 1)[1])) as ws:
            stalled = _stalled_client(ws, STEWART_FLIGHT_TOPICS)
            other = _Client(url, {"/platform/actuators"})  # and one that reads
            other.start()
            summary = _finish(proc)
    finally:
        proc.kill()
        drive.close()
    other.join(60)
    logged = _logged(out, {"/platform/actuators"})["/platform/actuators"]
    _assert_every_other_tick(other.feed.got["/platform/actuators"], logged, "/platform/actuators")
    assert "stopped by duration" in summary
    with open(out, "rb") as fh:  # the stalled client subscribed to every topic of the run
        assert {c.topic for c in make_reader(fh).get_summary().channels.values()} == set(
            stalled.channels
        )
    msgs = read_messages(out)
    ticks = len(msgs["/platform/actuators"])
    assert ticks == len(msgs["/platform/pose"]) and msgs["/platform/actuators"][-1]["t"] > 8.0
    park = np.array(msgs["/platform/actuators"][-1]["angles"]) * 1000  # mm
    last = np.array(drive.frames[-1][1].decode().split(","), dtype=float)
    np.testing.assert_allclose(last, park, atol=1e-4)
