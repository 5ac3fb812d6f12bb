"""Bad input through the command line (issue 13): one line naming the problem, exit 2, nothing
lost, and motors driven only with the limits of the user's own geometry.

Each test runs ``motionbase.cli.main`` in-process (the console script's code path) and checks
the exit status and stderr; recordings are crafted with the ``mcap`` writer.
"""

from __future__ import annotations

import json
import logging
import math
import os
import socket
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from motionbase import cli
from motionbase.app import load_config
from motionbase.io.mcap_source import McapSource, read_messages
from motionbase.io.motor_output import DEFAULT_TEXT, parse_format
from motionbase.platform import Rus6Geometry

G = 9.80665
RATE = 120.0


@pytest.fixture
def run_cli(capsys, monkeypatch):
    """``run_cli(*args) -> (exit status, stdout, stderr)``, warnings included in stderr."""
    # cli.main installs its warning handler on the stderr of the moment: this test's
    monkeypatch.setattr(logging.getLogger("motionbase"), "handlers", [])

    def run(*args: str) -> tuple[int, str, str]:
        try:
            code = cli.main([str(a) for a in args])
        except SystemExit as exc:  # argparse errors exit through SystemExit
            code = exc.code
        captured = capsys.readouterr()
        return code, captured.out, captured.err

    return run


def one_line(err: str, *needles: str) -> str:
    """The single line of ``err``, which must contain every needle (case-insensitive)."""
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    for n in needles:
        assert n.lower() in lines[0].lower(), (n, lines[0])
    return lines[0]


# --------------------------------------------------------------------------- recordings


def _state(k: int) -> dict:
    t = k / RATE
    return {
        "t": t,
        "specific_force": [1.5 * math.sin(2.0 * t), 1.0 * math.cos(1.5 * t), -G],
        "angular_velocity": [0.2 * math.sin(3.0 * t), 0.0, 0.1],
        "attitude": [0.0, 0.0, 0.0],
    }


def write_recording(path: Path, pipeline_config: dict | None, n: int = 240) -> Path:
    """A recording of ``n`` aircraft states with ``pipeline_config`` as its stored settings."""
    config = {"source": {"kind": "test"}}
    if pipeline_config is not None:
        config["pipeline_config"] = pipeline_config
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        writer.add_metadata("motionbase", {"config": json.dumps(config)})
        sid = writer.register_schema("state", "jsonschema", b"{}")
        cid = writer.register_channel("/aircraft/state", "json", sid)
        for k in range(1, n + 1):
            ns = round(k / RATE * 1e9)
            writer.add_message(cid, ns, json.dumps(_state(k)).encode(), ns)
        writer.finish()
    return path


def ceart_config() -> dict:
    return load_config(rate_hz=RATE).to_dict()


def loosened_config() -> dict:
    """The ceart settings with 3x the speed and acceleration limits and wider angle limits."""
    cfg = ceart_config()
    geo = cfg["geometry"]
    geo["max_speed"] = [3 * v for v in geo["max_speed"]]
    geo["max_accel"] = [3 * v for v in geo["max_accel"]]
    geo["angle_min"] = [math.radians(-80.0)] * 6
    geo["angle_max"] = [math.radians(80.0)] * 6
    return cfg


def udp_listener() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    return sock


def received(sock: socket.socket) -> list[bytes]:
    frames = []
    while True:
        try:
            frames.append(sock.recv(65536))
        except BlockingIOError:
            return frames


# --------------------------------------------------------------------------- item 7


def test_replay_output_without_platform_is_refused_and_sends_nothing(tmp_path, run_cli):
    rec = write_recording(tmp_path / "loose.mcap", loosened_config())
    sock = udp_listener()
    port = sock.getsockname()[1]
    out = tmp_path / "out.mcap"
    code, stdout, err = run_cli("replay", rec, "--output", f"udp:127.0.0.1:{port}", "--out", out)
    assert code == 2
    one_line(err, "replay", "--output", "--platform")
    assert received(sock) == [] and not out.exists()
    sock.close()


def test_replay_output_drives_with_the_users_geometry_not_the_recordings(tmp_path, run_cli):
    """The recording loosens every limit; the wire and the log keep ceart's."""
    rec = write_recording(tmp_path / "loose.mcap", loosened_config())
    sock = udp_listener()
    port = sock.getsockname()[1]
    out = tmp_path / "out.mcap"
    code, stdout, err = run_cli(
        "replay", rec, "--platform", "ceart", "--output", f"udp:127.0.0.1:{port}", "--out", out
    )
    assert code == 0, err
    ceart = Rus6Geometry.preset("ceart")
    with McapSource(out) as src:
        used = src.metadata["pipeline_config"]["geometry"]
    assert Rus6Geometry.from_dict(used) == ceart
    # the logged commands respect ceart's limits (the recording allowed 3x)
    q = np.array([m["angles"] for m in read_messages(out)["/platform/actuators"]])
    dt = 1 / RATE
    park = np.full(6, ceart.park_angle)
    q0 = np.vstack([park, park, q])
    v = np.diff(q0, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    assert np.abs(v).max() <= max(ceart.max_speed) + 1e-9
    assert np.abs(a).max() <= max(ceart.max_accel) + 1e-6
    # and every frame on the wire (degrees, the default text format) is within ceart's range
    frames = received(sock)
    sock.close()
    assert frames
    fmt, _ = parse_format(DEFAULT_TEXT)
    lo, hi = np.degrees(ceart.angle_min), np.degrees(ceart.angle_max)
    for frame in frames:
        values = np.array(fmt.decode(frame), dtype=float)
        assert (values >= lo - 1e-9).all() and (values <= hi + 1e-9).all(), frame


def _tampered(edit) -> dict:
    cfg = ceart_config()
    edit(cfg)
    return cfg


@pytest.mark.parametrize(
    ("edit", "needles"),
    [
        (lambda c: c["pipeline"]["input_limits"].update(max_attitude=math.nan), "max_attitude"),
        (
            lambda c: c["pipeline"]["input_limits"].update(max_specific_force=-150.0),
            "max_specific_force",
        ),
        (lambda c: c["pipeline"]["input_limits"].update(max_angular_velocity="20"), "max_ang"),
        (lambda c: c["geometry"].update(max_speed=[math.nan] * 6), "max_speed"),
        (lambda c: c["geometry"].update(max_accel=[-30.0] * 6), "max_accel"),
        (lambda c: c["geometry"].update(max_accel=[math.inf] * 6), "max_accel"),
        (
            lambda c: c["geometry"].update(angle_min=[1.0] * 6, angle_max=[-1.0] * 6),
            "angle_min",
        ),
        (lambda c: c["geometry"].update(angle_max=[math.nan] * 6), "angle_max"),
        (lambda c: c["geometry"].pop("max_accel"), "max_accel"),
        (lambda c: c["pipeline"].update(rate_hz=True), "rate_hz"),
        (lambda c: c["pipeline"].update(planar_scale_m=math.nan), "planar_scale_m"),
        (lambda c: c["pipeline"].update(surprise=1), "surprise"),
        (lambda c: c.update(pipeline=[1, 2]), "pipeline"),
        (lambda c: c.update(robot="hexapod"), "robot"),
    ],
)
def test_recorded_settings_with_bad_limits_are_refused(tmp_path, run_cli, edit, needles):
    rec = write_recording(tmp_path / "bad.mcap", _tampered(edit))
    code, stdout, err = run_cli("replay", rec, "--out", tmp_path / "out.mcap")
    assert code == 2
    one_line(err, "bad.mcap", needles)
    assert not (tmp_path / "out.mcap").exists()


def test_recorded_settings_that_are_not_a_table_are_refused(tmp_path, run_cli):
    rec = write_recording(tmp_path / "bad.mcap", [1, 2, 3])  # type: ignore[arg-type]
    code, stdout, err = run_cli("replay", rec, "--check")
    assert code == 2
    one_line(err, "bad.mcap", "pipeline_config")


# --------------------------------------------------------------------------- item 11


def test_replay_refuses_to_overwrite_its_own_input(tmp_path, run_cli):
    rec = write_recording(tmp_path / "rec.mcap", ceart_config())
    before = rec.read_bytes()
    (tmp_path / "sub").mkdir()
    link = tmp_path / "link.mcap"
    link.symlink_to(rec)
    hard = tmp_path / "hard.mcap"
    os.link(rec, hard)
    spellings = [
        rec,
        tmp_path / "sub" / ".." / "rec.mcap",
        link,  # a symlink to the input
        hard,  # another name of the same file
    ]
    for out in spellings:
        code, stdout, err = run_cli("replay", rec, "--out", out)
        assert code == 2, (out, err)
        one_line(err, "--out", "recording being replayed")
        assert rec.read_bytes() == before
    # and the other way round: the input given through the link
    code, stdout, err = run_cli("replay", link, "--out", rec)
    assert code == 2 and rec.read_bytes() == before
    # a different file is fine
    code, stdout, err = run_cli("replay", rec, "--out", tmp_path / "other.mcap")
    assert code == 0, err
    assert rec.read_bytes() == before
