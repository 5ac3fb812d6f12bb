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
import re
import socket
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from motionbase import cli
from motionbase.app import load_config
from motionbase.io.mcap_source import McapSource, read_messages
from motionbase.io.motor_output import DEFAULT_TEXT
from motionbase.platform import Rus6Geometry

G = 9.80665
RATE = 120.0


@pytest.fixture
def run_cli(capfd, fresh_logger):
    """``run_cli(*args) -> (exit status, stdout, stderr)``, warnings included in stderr (the
    logger as a fresh process has it: ``fresh_logger``), and what C code wrote to the file
    descriptors too."""

    def run(*args: str) -> tuple[int, str, str]:
        try:
            code = cli.main([str(a) for a in args])
        except SystemExit as exc:  # argparse errors exit through SystemExit
            code = exc.code
        captured = capfd.readouterr()
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


#: The default frame, FlyPT Mover style (``A{1}B{2}C{3}D{4}E{5}F{6}\n``: motor N's drive value
#: as a decimal integer after its letter), read by its own pattern, not the library's format.
_DEFAULT_FRAME = re.compile(rb"A(-?\d+)B(-?\d+)C(-?\d+)D(-?\d+)E(-?\d+)F(-?\d+)\n")


def default_frame_values(frame: bytes) -> np.ndarray:
    """The six drive values of a frame in the default text format."""
    assert DEFAULT_TEXT == r"A{1}B{2}C{3}D{4}E{5}F{6}\n"  # the format this reader reads
    m = _DEFAULT_FRAME.fullmatch(frame)
    assert m is not None, f"not a frame of the default format: {frame!r}"
    return np.array([int(x) for x in m.groups()], dtype=float)


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
    lo, hi = np.degrees(ceart.angle_min), np.degrees(ceart.angle_max)
    for frame in frames:
        values = default_frame_values(frame)
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


@pytest.mark.parametrize("flag", ["script", "--platform", "--params"])
def test_fly_out_may_not_overwrite_the_script_geometry_or_washout_file(tmp_path, run_cli, flag):
    """``fly --out`` naming the script, the ``--platform`` or the ``--params`` file: the
    flight read it, then wrote its log over it (exit 0), so the user's geometry, washout or
    script was gone. Refused with one line, the file untouched."""
    import jsbsim

    sources = {
        "script": Path(jsbsim.get_default_root_dir()) / "scripts" / "c1723.xml",
        "--platform": Path(cli.__file__).parent / "presets" / "rus6_ceart.toml",
        "--params": Path(cli.__file__).parent / "presets" / "washout_gentle.toml",
    }
    victim = tmp_path / f"mine{sources[flag].suffix}"
    victim.write_bytes(sources[flag].read_bytes())
    before = victim.read_bytes()
    script = victim if flag == "script" else "c1723"
    given = [] if flag == "script" else [flag, victim]
    out = tmp_path / "sub" / ".." / victim.name  # another spelling of the same file
    (tmp_path / "sub").mkdir()
    code, _, err = run_cli("fly", script, *given, "--duration", "3", "--out", out)
    assert code == 2, err
    one_line(err, "--out", flag, "destroy")
    assert victim.read_bytes() == before


def _tlog(path: Path) -> Path:
    """A telemetry log of 2 s: HIGHRES_IMU and ATTITUDE at 100 Hz, each behind its
    receive time in microseconds (the .tlog layout)."""
    from mavlink_sender import send_good
    from pymavlink import mavutil

    class Frames(list):
        def write(self, data: bytes) -> None:
            self.append(bytes(data))

    frames = Frames()
    mav = mavutil.mavlink.MAVLink(frames, srcSystem=1, srcComponent=1)
    with open(path, "wb") as fh:
        for i in range(200):
            frames.clear()
            send_good(mav, i)
            for frame in frames:
                fh.write((1_700_000_000_000_000 + i * 10_000).to_bytes(8, "big") + frame)
    return path


@pytest.mark.parametrize("flag", ["--mavlink", "--signing-key", "--platform", "--params"])
def test_stream_out_may_not_overwrite_the_log_it_reads_or_its_other_files(tmp_path, run_cli, flag):
    """``stream --mavlink flight.tlog --fast --out flight.tlog``: the stream opened the log
    for its states, then wrote its own over it (the user's flight was gone, and the error
    that followed said the .tlog had no MAVLink messages). The key, geometry and washout
    files went the same way. Refused with one line, the file untouched."""
    presets = Path(cli.__file__).parent / "presets"
    tlog = _tlog(tmp_path / "flight.tlog")
    files = {
        "--mavlink": tlog,
        "--signing-key": tmp_path / "key.bin",
        "--platform": tmp_path / "rig.toml",
        "--params": tmp_path / "washout.toml",
    }
    files["--signing-key"].write_bytes(bytes(range(32)))
    files["--platform"].write_bytes((presets / "rus6_ceart.toml").read_bytes())
    files["--params"].write_bytes((presets / "washout_telemetry.toml").read_bytes())
    victim = files[flag]
    before = victim.read_bytes()
    given = [] if flag == "--mavlink" else [flag, victim]
    code, _, err = run_cli("stream", "--mavlink", tlog, "--fast", *given, "--out", victim)
    assert code == 2, err
    one_line(err, "--out", flag, "destroy")
    assert victim.read_bytes() == before
    # the same log to another file streams (the log above is a readable one)
    code, _, err = run_cli("stream", "--mavlink", tlog, "--fast", "--out", tmp_path / "o.mcap")
    assert code == 0, err
    assert read_messages(tmp_path / "o.mcap")["/aircraft/state"]


# --------------------------------------------------------------------------- item 13


def test_a_huge_format_width_is_one_line_not_a_memory_error(tmp_path, run_cli):
    rec = write_recording(tmp_path / "rec.mcap", ceart_config())
    out = tmp_path / "out.mcap"
    for spec, needle in (("%7B1:>99999999999%7D", "width"), ("%7B1:.999999999f%7D", "precision")):
        url = f"udp:127.0.0.1:9?format=text:{spec}"
        code, stdout, err = run_cli(
            "replay", rec, "--platform", "ceart", "--output", url, "--out", out
        )
        assert code == 2
        one_line(err, needle, "64 characters")
        assert not out.exists()
    # the widest allowed field still works
    from motionbase.io.motor_output import MAX_FIELD_WIDTH, TextFormat

    fmt = TextFormat("{1:>" + str(MAX_FIELD_WIDTH) + "}", 6)
    assert len(fmt.encode([1.0] * 6)) == MAX_FIELD_WIDTH


@pytest.mark.parametrize("suffix", [".bin", ".tlog"])
def test_a_garbage_log_is_one_line(tmp_path, run_cli, suffix):
    """pymavlink printed a 'bad header' line per byte (2,385 lines) before the error."""
    garbage = tmp_path / f"garbage{suffix}"
    garbage.write_bytes(np.random.default_rng(7).bytes(50_000))
    code, stdout, err = run_cli(
        "stream", "--mavlink", garbage, "--fast", "--out", tmp_path / "g.mcap"
    )
    assert code == 2
    one_line(err, f"garbage{suffix}", "no ")
    assert stdout == ""


@pytest.mark.parametrize("command", ["replay", "report"])
def test_a_mavlink_log_given_for_a_recording_says_how_it_streams(tmp_path, run_cli, command):
    """A .tlog given to replay or report was only "not an MCAP file"."""
    from pymavlink import mavutil

    log = tmp_path / "flight.tlog"
    link = mavutil.mavlogfile(str(log), write=True)
    link.mav.heartbeat_send(1, 3, 0, 0, 0)  # a real MAVLink frame in a real telemetry log
    link.close()
    code, stdout, err = run_cli(command, log)
    assert code == 2
    one_line(err, "flight.tlog: not an MCAP file", "stream --mavlink FILE --fast")


LINK = "udpin:127.0.0.1:14552"


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        # an unknown KIND: once said "invalid literal for int()"
        (["--mavlink", "foo:bar"], ("unknown kind of link 'foo'", "udpin:HOST:PORT", "serial")),
        # an ordinary file ran as a serial port that never spoke, until killed
        (["--mavlink", "NOTES", "--fast"], ("empty.toml", ".tlog", ".bin", "character device")),
        # --mavlink was silently ignored beside --source
        (["--mavlink", LINK, "--source", "xplane:127.0.0.1:49000"], ("one source at a time",)),
        # --fast on a live link was taken and meant nothing (refused with --source already)
        (["--mavlink", LINK, "--fast"], (f"--fast replays MAVLink log files; {LINK} is live",)),
        # a misspelt log name was called a live link ("is live: drop --fast")
        (["--mavlink", "flight.tlg", "--fast"], ("flight.tlg: no such log", ".tlog", "path")),
    ],
)
def test_stream_source_mistakes_are_one_line(args, needles, tmp_path, run_cli):
    notes = tmp_path / "empty.toml"
    notes.write_text("")
    out = tmp_path / "x.mcap"
    args = [str(notes) if a == "NOTES" else a for a in args]
    code, stdout, err = run_cli("stream", *args, "--duration", "1", "--out", out)
    assert code == 2, args
    one_line(err, *needles)
    assert not out.exists()


def test_a_component_id_out_of_range_says_what_to_type(tmp_path, run_cli):
    """It said "1..255 or None": None is what the library takes, not what one types."""
    out = tmp_path / "x.mcap"
    code, stdout, err = run_cli("stream", "--compid", "300", "--duration", "1", "--out", out)
    assert code == 2
    line = one_line(err, "compid", "1..255, got 300", "leave it out")
    assert "None" not in line and not out.exists()


def _closed_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now: a connection is refused
    return port


def test_a_refused_tcp_link_is_one_line_without_retry_chatter(tmp_path, run_cli):
    port = _closed_port()
    out = tmp_path / "t.mcap"
    code, stdout, err = run_cli("stream", "--mavlink", f"tcp:127.0.0.1:{port}", "--out", out)
    assert code == 2
    one_line(err, f"tcp:127.0.0.1:{port}", "connection refused")
    assert "sleeping" not in stdout + err and stdout == ""
    assert not out.exists()


def test_an_output_that_will_not_open_leaves_no_stub_log(tmp_path, run_cli):
    rec = write_recording(tmp_path / "rec.mcap", ceart_config())
    out = tmp_path / "out.mcap"
    url = f"serial:{tmp_path / 'nonexistent'}"
    code, stdout, err = run_cli("replay", rec, "--platform", "ceart", "--output", url, "--out", out)
    assert code == 2
    one_line(err, "nonexistent")
    assert not out.exists()


def _shifted_recording(path: Path, shift_s: float, which: slice) -> Path:
    """States whose times in ``which`` are moved by ``shift_s`` (log times stay positive)."""
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        writer.add_metadata("motionbase", {"config": json.dumps({"rate_hz": RATE})})
        sid = writer.register_schema("state", "jsonschema", b"{}")
        cid = writer.register_channel("/aircraft/state", "json", sid)
        shifted = set(range(240)[which])
        for k in range(1, 241):
            msg = _state(k)
            if k - 1 in shifted:
                msg["t"] += shift_s
            ns = round(k / RATE * 1e9)
            writer.add_message(cid, ns, json.dumps(msg).encode(), ns)
        writer.finish()
    return path


def test_negative_recording_times_name_the_input_not_the_output(tmp_path, run_cli):
    out = tmp_path / "out.mcap"
    # a clock that starts before 0 s: refused up front, naming the recording
    rec = _shifted_recording(tmp_path / "neg.mcap", -1.0, slice(None))
    code, stdout, err = run_cli("replay", rec, "--out", out)
    assert code == 2
    line = one_line(err, "neg.mcap", "0 s")
    assert "out.mcap" not in line and not out.exists()
    # one negative time in the middle: rejected, counted and held, a warning names the input
    rec = _shifted_recording(tmp_path / "one.mcap", -5.0, slice(100, 101))
    code, stdout, err = run_cli("replay", rec, "--out", out)
    assert code == 0, err
    line = one_line(err, "one.mcap", "negative")
    assert "out.mcap" not in line
    assert read_messages(out)["/health"][-1]["rejected_inputs"] == 1
    accepted = [m["accepted"] for m in read_messages(out)["/aircraft/state"]]
    assert accepted[100] is False and accepted.count(False) == 1


def test_the_top_level_parser_and_unknown_options_name_the_right_command(run_cli):
    code, stdout, err = run_cli("fly", "--speed", "2")
    assert code == 2
    line = one_line(err, "unrecognized arguments: --speed")
    assert line.startswith("motionbase fly: error:") and "motionbase motionbase" not in line
    code, stdout, err = run_cli("--bogus")
    assert code == 2
    assert one_line(err, "--bogus").startswith("motionbase: error:")
    code, stdout, err = run_cli("flyy")
    assert code == 2
    assert one_line(err, "flyy").startswith("motionbase: error:")


def test_a_file_of_the_wrong_kind_is_named_for_what_it_is(tmp_path, run_cli):
    from motionbase.config import preset_path

    washout = preset_path("washout", "default")
    rus6 = preset_path("rus6", "ceart")
    rrr3 = preset_path("rrr3", "udesc")
    mpc = preset_path("mpc", "ceart")
    cases = [
        # an MPC file has a [tilt] table as a washout file does: it was read as a washout
        # file with an unknown field 'horizon', and as a --platform named a washout file
        (["--washout", mpc], ("mpc_ceart.toml", "MPC cueing parameter file", "--cueing mpc")),
        (["--platform", mpc], ("mpc_ceart.toml", "MPC cueing parameter file", "--cueing mpc")),
        (["--platform", washout], ("washout_default.toml", "washout parameter file", "--washout")),
        (["--washout", rus6], ("rus6_ceart.toml", "6-RUS geometry file", "--platform")),
        (["--platform", rrr3], ("rrr3_udesc.toml", "3-RRR geometry file", "--planar")),
        (["--planar", "--platform", rus6], ("rus6_ceart.toml", "6-RUS geometry file")),
    ]
    for args, needles in cases:
        code, stdout, err = run_cli("stream", *args, "--out", tmp_path / "x.mcap")
        assert code == 2, args
        line = one_line(err, *needles)
        assert "unknown field" not in line
    assert not (tmp_path / "x.mcap").exists()


def test_bad_host_or_port_says_which(tmp_path, run_cli):
    rec = write_recording(tmp_path / "rec.mcap", ceart_config())
    bad_host = "notahost.invalid"  # RFC 6761: never resolves
    out = ["--out", tmp_path / "x.mcap"]
    replay = ["replay", rec, "--platform", "ceart"]
    cases = [
        (
            [*replay, "--output", f"udp:{bad_host}:99999", *out],
            ("out of range", "does not resolve"),
        ),
        ([*replay, "--output", "udp:127.0.0.1:99999", *out], ("port 99999 is out of range",)),
        ([*replay, "--output", f"udp:{bad_host}:4000", *out], (f"{bad_host}' does not resolve",)),
        (["stream", "--mavlink", f"udpout:{bad_host}:14550", *out], ("does not resolve",)),
        (["stream", "--mavlink", "udpin:127.0.0.1:99999", *out], ("out of range (1..65535)",)),
        (["stream", "--mavlink", "udpout:127.0.0.1:0", *out], ("port 0 is out of range",)),
        (["stream", "--mavlink", "udpin:127.0.0.1:-1", *out], ("port -1 is out of range",)),
        (["stream", "--live", "-5", *out], ("port -5 is out of range",)),
        (["stream", "--mavlink", f"udp:{bad_host}:99999", *out], ("out of range", "resolve")),
        (["stream", "--mavlink", f"tcp:{bad_host}:5760", *out], ("does not resolve",)),
        # not preceded by a warning that it listens on 0.0.0.0 to hear that host
        (["stream", "--source", f"xplane:{bad_host}:49000", *out], ("does not resolve",)),
        (["teleop", "--input", f"udp:{bad_host}:99999"], ("out of range", "does not resolve")),
        # a port 0 to listen on would be a free port shown nowhere: nothing could send to it
        *(
            (["stream", *source, "--duration", "1", *out], ("port 0 is out of range (1..65535)",))
            for source in (
                ["--mavlink", "udpin:127.0.0.1:0"],
                ["--source", "fgnative:udp:127.0.0.1:0"],
                ["--source", "xplane:127.0.0.1:49000?listen=0"],
                ["--source", "xplane:127.0.0.1:49000?listen=127.0.0.1:0"],
            )
        ),
        (["stream", "--source", "fgnative:udp:127.0.0.1:70000", *out], ("(1..65535)",)),
        (["stream", "--live", "70000", *out], ("(1..65535, or 0 for any free port)",)),
    ]
    for args, needles in cases:
        code, stdout, err = run_cli(*args)
        assert code == 2, args
        line = one_line(err, *needles)
        assert "choose another port" not in line and "expected udp:HOST:PORT" not in line
    assert not (tmp_path / "x.mcap").exists()


def _unsigned_vehicle(port: int, stop, key: bytes | None) -> None:
    from mavlink_sender import send_good

    from motionbase.io.mavlink_source import mavutil

    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1)
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True, link_id=1)
    i = 0
    try:
        while not stop.is_set():
            send_good(conn.mav, i)
            i += 1
            stop.wait(0.02)
    finally:
        conn.close()


@pytest.mark.parametrize("vehicle_key", [None, bytes(32 * [0xAA])], ids=["unsigned", "other key"])
def test_signature_rejections_are_named_in_the_warning(tmp_path, caplog, vehicle_key):
    """Messages that arrive but fail the signature check: the warning says so, it does not
    ask whether the vehicle is sending at all."""
    import threading

    from motionbase.io.mavlink_source import MavlinkSource

    key_file = tmp_path / "key.bin"
    key_file.write_bytes(bytes(range(32)))
    stop = threading.Event()
    caplog.set_level(logging.WARNING, logger="motionbase")
    with MavlinkSource(
        "udpin:127.0.0.1:0",
        rate_hz=50.0,
        duration_s=2.5,
        signing_key=key_file,
        request_timeout_s=0.5,
    ) as src:
        port = src.local_address[1]
        th = threading.Thread(target=_unsigned_vehicle, args=(port, stop, vehicle_key))
        th.start()
        try:
            ticks = [src.fresh for _ in src]
        finally:
            stop.set()
            th.join(timeout=5)
        stats = src.stats
    assert not any(ticks) and stats.accepted == 0 and stats.rejected_signature > 0
    warned = [r.getMessage() for r in caplog.records if "signature" in r.getMessage()]
    assert len(warned) == 1, [r.getMessage() for r in caplog.records]
    assert "--signing-key" in warned[0]
    assert not any("is the vehicle sending" in r.getMessage() for r in caplog.records)


def test_a_format_file_with_wrong_types_is_one_line(tmp_path, run_cli):
    """``rate_hz = true`` once became 1 frame per second; ``text = 5`` a template "5"."""
    rec = write_recording(tmp_path / "rec.mcap", ceart_config())
    for body, needle in (
        ('text = "A{1}B{2}\\\\n"\nrate_hz = true\n', "'rate_hz'"),
        ('text = "A{1}B{2}\\\\n"\nrate_hz = "250"\n', "'rate_hz'"),
        ("binary = 5\n", "'binary'"),
    ):
        fmt = tmp_path / "drive.toml"
        fmt.write_text(body)
        url = f"udp:127.0.0.1:9?format={fmt}"
        code, stdout, err = run_cli(
            "replay", rec, "--platform", "ceart", "--output", url, "--out", tmp_path / "x.mcap"
        )
        assert code == 2, body
        one_line(err, "drive.toml", needle)
    assert not (tmp_path / "x.mcap").exists()


def test_a_mistake_said_to_a_reader_that_went_away_still_exits_2(tmp_path):
    """The one line goes to stderr; when nobody reads it any more (its pipe's reader gone,
    a closed terminal) the status must still be 2, not a traceback's 1."""
    import subprocess
    import sys

    read_end, write_end = os.pipe()
    os.close(read_end)  # every write to the pipe now fails (EPIPE)
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "motionbase.cli", "fly", "no_such_script"],
            cwd=tmp_path,
            stdout=subprocess.DEVNULL,
            stderr=write_end,
            timeout=120,
        )
    finally:
        os.close(write_end)
    assert proc.returncode == 2


# --------------------------------------------------------------------------- review: config


def run_process(*args: object, setup: str = "", cwd: Path | None = None) -> tuple[int, str]:
    """``motionbase ARGS`` in a process of its own, as a user's script runs it: ``setup``
    (Python) first, then ``motionbase.cli.main``. Returns (exit status, stderr)."""
    import subprocess
    import sys

    import motionbase

    code = f"{setup}\nimport sys\nfrom motionbase import cli\nsys.exit(cli.main(sys.argv[1:]))"
    here = str(Path(motionbase.__file__).parents[1])  # the motionbase under test, not another
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([here, os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run(
        [sys.executable, "-c", code, *[str(a) for a in args]],
        cwd=cwd,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        timeout=300,
    )
    return proc.returncode, proc.stderr


@pytest.mark.parametrize(
    "cueing_class, needles",
    [
        ("no_such_module_for_motionbase:Proportional", ("no_such_module_for_motionbase",)),
        ("motionbase.washout.classical:NoSuchCueing", ("NoSuchCueing",)),
    ],
    ids=["module missing", "class missing"],
)
def test_a_cueing_plug_in_that_will_not_import_is_one_line(tmp_path, cueing_class, needles):
    """A plug-in registered as the README shows, whose package is not installed (or whose
    registration names a class its module lacks), is a set-up mistake: one line naming the
    cueing and the reference, exit 2, and no log."""
    setup = (
        "from motionbase.washout.cueing import CUEINGS, CueingSpec\n"
        f"CUEINGS['plug'] = CueingSpec('plug', {cueing_class!r}, "
        "'motionbase.washout.params:WashoutParams', preset_kind='washout')"
    )
    out = tmp_path / "x.mcap"
    code, err = run_process(
        "fly", "c1723", "--duration", "1", "--cueing", "plug", "--out", out, setup=setup
    )
    assert code == 2, err
    one_line(err, "cueing 'plug'", "cannot import", *needles)
    assert not out.exists()


def test_a_robot_plug_in_that_will_not_import_is_one_line(tmp_path):
    """The same for a robot: its registration (here the 6-RUS's, pointed at a package that
    is not installed, its preset kept) names classes that cannot be imported."""
    setup = (
        "from motionbase.platform.robot import ROBOTS, RobotSpec\n"
        "ROBOTS['rus6'] = RobotSpec('rus6', 'no_such_module_for_motionbase:Arm', "
        "'no_such_module_for_motionbase:ArmGeometry', 'ceart')"
    )
    code, err = run_process("workspace", "--platform", "rus6", setup=setup, cwd=tmp_path)
    assert code == 2, err
    one_line(err, "robot 'rus6'", "cannot import", "no_such_module_for_motionbase")


@pytest.mark.parametrize(
    "section, key, value, needle",
    [
        ("horizon", "step_s", 1e-100, "horizon.step_s"),
        ("horizon", "step_s", 1e30, "horizon.step_s"),
        ("solver", "max_iter", 2**31, "solver.max_iter"),
        ("weights", "specific_force", [1e300] * 3, "[weights]"),
        ("", "g", 1e300, "overflow"),
    ],
)
def test_mpc_values_the_solver_cannot_take_are_one_line(tmp_path, section, key, value, needle):
    """A prediction step far outside any horizon a cue needs made OSQP's set-up fail with a
    traceback (and its C library's own lines), and so did an iteration limit past its 32-bit
    integer, a weight of 1e300 and a g of 1e300 (the model's matrices overflowed, with numpy's
    warnings on stderr too): one line naming the file and what to fix, exit 2, no log."""
    import tomllib

    import tomli_w

    from motionbase.config import preset_path

    with open(preset_path("mpc", "tuned_ceart"), "rb") as fh:
        params = tomllib.load(fh)
    (params[section] if section else params)[key] = value
    path = tmp_path / "mpc_steps.toml"
    path.write_bytes(tomli_w.dumps(params).encode())
    out = tmp_path / "x.mcap"
    code, err = run_process(
        "fly", "c1723", "--duration", "1", "--cueing", "mpc", "--params", path, "--out", out
    )
    assert code == 2, err
    one_line(err, "mpc_steps.toml", needle)
    assert not out.exists()


def test_a_servo_zero_of_many_turns_is_refused_not_flown(tmp_path):
    """A 3-RRR servo zero of 1e300 deg was taken: the joint angles measured from it had no
    precision left and servo 1's command stayed at one value whatever the pose (a flight
    of the planar robot exited 0 with that servo frozen). One line naming the field."""
    import tomllib

    import tomli_w

    from motionbase.config import preset_path

    with open(preset_path("rrr3", "udesc_symmetric"), "rb") as fh:
        geometry = tomllib.load(fh)
    geometry["servo"]["zero_deg"] = [1e300, 122.0, 242.0]
    path = tmp_path / "rrr3_far.toml"
    path.write_bytes(tomli_w.dumps(geometry).encode())
    out = tmp_path / "x.mcap"
    code, err = run_process(
        "fly", "c1723", "--duration", "1", "--planar", "--platform", path, "--out", out
    )
    assert code == 2, err
    one_line(err, "rrr3_far.toml", "servo.zero_deg", "servo 1")
    assert not out.exists()


def test_a_frequency_above_the_nyquist_frequency_names_the_file_and_the_profile(tmp_path):
    """A washout frequency the pipeline's rate cannot sample is only found when the cueing
    is built at that rate: the line said ``washout: filter frequency ...`` without the file
    the user gave, nor the profile whose value it was."""
    import tomllib

    import tomli_w

    from motionbase.config import preset_path

    with open(preset_path("washout", "default"), "rb") as fh:
        params = tomllib.load(fh)
    # 500 rad/s: above pi * 120 Hz = 377 rad/s, fly's rate
    params["profile"] = {"ground": {"translational": {"wn": [500.0, 1.5, 4.0]}}}
    path = tmp_path / "fast_ground.toml"
    path.write_bytes(tomli_w.dumps(params).encode())
    out = tmp_path / "x.mcap"
    code, err = run_process("fly", "c1723", "--duration", "1", "--params", path, "--out", out)
    assert code == 2, err
    one_line(err, "fast_ground.toml", "[profile.ground]", "translational.wn", "Nyquist")
    assert not out.exists()


def test_a_park_angle_past_the_lowest_pose_is_refused_not_flown(tmp_path):
    """Crank limits looser than the geometry allows (-179 .. 179 deg on ceart's dimensions)
    put the default park angle, the lowest limit plus 5 deg, past the lowest pure-heave pose:
    the platform parked 5 cm above neutral with its cranks in an assembly the inverse
    kinematics never commands, and every start swung them through the lowest pose at the
    full speed limit (exit 0). One line naming the file and the field; no log."""
    import tomllib

    import tomli_w

    from motionbase.config import preset_path

    with open(preset_path("rus6", "ceart"), "rb") as fh:
        geometry = tomllib.load(fh)
    geometry["angle_min_deg"], geometry["angle_max_deg"] = -179.0, 179.0
    del geometry["park_angle_deg"]
    path = tmp_path / "wide.toml"
    path.write_bytes(tomli_w.dumps(geometry).encode())
    out = tmp_path / "x.mcap"
    code, err = run_process("fly", "c1723", "--duration", "1", "--platform", path, "--out", out)
    assert code == 2, err
    one_line(err, "wide.toml", "park_angle", "lowest pure-heave pose")
    assert not out.exists()
    # an explicit park angle that the inverse kinematics gives back is flown
    geometry["park_angle_deg"] = -55.0
    path.write_bytes(tomli_w.dumps(geometry).encode())
    code, err = run_process("fly", "c1723", "--duration", "1", "--platform", path, "--out", out)
    assert code == 0, err


@pytest.mark.parametrize(
    "args",
    [["--scripts", "c1723@0:2", "--holdout", "none"], ["--holdout", "c1723@10:11.5"]],
    ids=["tuning window", "held-out window"],
)
def test_a_tuning_window_shorter_than_the_soft_start_is_one_line(tmp_path, args):
    """A window (or a recording) no longer than the 2 s soft start leaves nothing to score:
    a worker's ValueError came back as a traceback (exit 1). One line naming the
    manoeuvre, exit 2, and no file written."""
    out = tmp_path / "tuned.toml"
    scripts = [] if "--scripts" in args else ["--scripts", "c1723@0:5"]
    code, err = run_process("tune", *scripts, *args, "--budget", "1", "--out", out)
    assert code == 2, err
    one_line(err, "c1723@", "soft start", "longer window")  # (the held-out one: no overlap)
    assert not out.exists()


def test_a_script_whose_initial_conditions_are_missing_is_one_line(tmp_path):
    """JSBSim's exception text ends in a newline, and its logger had said the same thing:
    the error was two lines, the second repeating the first."""
    script = tmp_path / "no_init.xml"
    script.write_text(
        '<?xml version="1.0"?>\n<runscript name="no_init">'
        '<use aircraft="c172x" initialize="no_such_initial_conditions"/>'
        '<run start="0" end="10" dt="0.008333"></run></runscript>\n'
    )
    out = tmp_path / "x.mcap"
    code, err = run_process("fly", script, "--duration", "1", "--out", out)
    assert code == 2, err
    line = one_line(err, "no_such_initial_conditions")
    assert line.count("no_such_initial_conditions") == 1, line
    assert not out.exists()


@pytest.mark.parametrize("dt", ["10", "1e-9"])
def test_a_script_time_step_out_of_the_pipelines_range_names_the_script(tmp_path, dt):
    """fly's pipeline runs at the rate of the script's time step: one the pipeline cannot
    tick at was said as 'pipeline: rate_hz ...', a rate the user never gave."""
    script = tmp_path / "odd_dt.xml"
    script.write_text(
        '<?xml version="1.0"?>\n<runscript name="odd_dt">'
        '<use aircraft="c172x" initialize="reset00"/>'
        f'<run start="0" end="5" dt="{dt}"></run></runscript>\n'
    )
    out = tmp_path / "x.mcap"
    code, err = run_process("fly", script, "--duration", "1", "--out", out)
    assert code == 2, err
    one_line(err, "odd_dt.xml", "<run dt>")
    assert not out.exists()


def test_a_script_that_ends_before_it_starts_is_one_line_not_an_empty_flight(tmp_path, run_cli):
    """Nothing to fly: it was "1 sample, stopped by end of source", a log of the park
    alone and exit status 0."""
    script = tmp_path / "backwards.xml"
    script.write_text(
        '<?xml version="1.0"?>\n<runscript name="backwards">'
        '<use aircraft="c172x" initialize="reset00"/>'
        '<run start="10" end="5" dt="0.008333"></run></runscript>\n'
    )
    out = tmp_path / "x.mcap"
    code, _, err = run_cli("fly", script, "--out", out)
    assert code == 2, err
    one_line(err, "backwards.xml", "<run> end")
    assert not out.exists()


@pytest.mark.parametrize(
    "output", ['unit = "deg"\ngear_ratio = 1e300', 'unit = "counts"\ncounts_per_rev = 1e300']
)
def test_a_drive_mapping_past_whole_numbers_is_refused_and_sends_nothing(tmp_path, output):
    """A gear ratio or counts per revolution of 1e300 (a typo for 1e3, say) was taken: the
    wiring check sent frames of 300-digit numbers, float rounding noise past their 16th
    digit, to the drive, and exited 0. Refused before anything is sent."""
    from motionbase.config import preset_path

    path = tmp_path / "geared.toml"
    path.write_text(preset_path("rus6", "ceart").read_text() + f"\n[output]\n{output}\n")
    sock = udp_listener()
    port = sock.getsockname()[1]
    try:
        code, err = run_process(
            "output", "--test", f"udp:127.0.0.1:{port}", "--platform", path, "--range-deg", "1"
        )
        frames = received(sock)
    finally:
        sock.close()
    assert code == 2, err
    one_line(err, "geared.toml", "[output]", "2^53")
    assert frames == []


_HUGE = 10**400  # a TOML (or JSON) integer has no bound; a float stops near 1.8e308


@pytest.mark.parametrize(
    "kind, preset, edit, args, needle",
    [
        ("washout", "default", ("tilt", "wn"), ["fly", "c1723", "--params"], "tilt.wn"),
        (
            "mpc",
            "tuned_ceart",
            ("horizon", "step_s"),
            ["fly", "--cueing", "mpc", "--params"],
            "step_s",
        ),
        ("rus6", "ceart", (None, "rb"), ["workspace", "--platform"], "'rb'"),
        ("stewart6", "seat", (None, "length_min"), ["workspace", "--platform"], "length_min"),
        ("rrr3", "udesc", (None, "crank"), ["workspace", "--planar", "--platform"], "crank"),
        (
            "rus6",
            "ceart",
            ("output", "range_hi"),
            ["output", "--test", "udp:127.0.0.1:9", "--platform"],
            "range_hi",
        ),
    ],
    ids=["washout", "mpc", "rus6", "stewart6", "rrr3", "output"],
)
def test_a_whole_number_too_large_for_a_float_is_one_line(
    tmp_path, kind, preset, edit, args, needle
):
    """``float()`` of a 400-digit TOML integer raises OverflowError: every configuration file
    answered it with a traceback (exit 1)."""
    import tomllib

    import tomli_w

    from motionbase.config import preset_path

    with open(preset_path(kind, preset), "rb") as fh:
        data = tomllib.load(fh)
    section, key = edit
    if section == "output":
        data["output"] = {"unit": "range", "range_lo": 0}
    (data[section] if section else data)[key] = _HUGE
    path = tmp_path / f"huge_{kind}.toml"
    path.write_bytes(tomli_w.dumps(data).encode())
    out = ["--out", tmp_path / "x.mcap"] if args[0] == "fly" else []
    duration = ["--duration", "1"] if args[0] == "fly" else []
    code, err = run_process(*args, path, *duration, *out)
    assert code == 2, err
    one_line(err, f"huge_{kind}.toml", needle)
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("args", [["workspace", "--planar"], ["workspace"]])
def test_a_reader_gone_before_the_result_is_printed_is_no_traceback(args):
    """``motionbase workspace --planar | head -1`` printed a BrokenPipeError traceback: the
    reader had gone when the table came. The work is done by then; the result is a display,
    so the command ends as it would have, exit 0, with nothing on stderr."""
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-m", "motionbase", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    proc.stdout.close()  # the reader goes before anything is printed
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == 0, err
    assert "Traceback" not in err and "Error" not in err, err


@pytest.mark.parametrize("reader", [False, True], ids=["no reader", "a reader"])
def test_out_on_a_fifo_is_one_line_and_exit_2(tmp_path, reader):
    """``--out`` naming a FIFO: the log's writer seeks back into its file to finish each
    chunk, which a FIFO cannot do. Without a reader, opening it waited for one forever
    (the run never started, and ignored Ctrl-C); with one, the SDK's error came as two
    lines. Now: one line naming the path, exit 2, before the run starts."""
    import subprocess
    import sys
    import threading

    import motionbase

    fifo = tmp_path / "log.mcap"
    os.mkfifo(fifo)
    drained = threading.Thread(target=lambda: Path(fifo).read_bytes(), daemon=True)
    if reader:
        drained.start()
    here = str(Path(motionbase.__file__).parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([here, os.environ.get("PYTHONPATH", "")])}
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "motionbase.cli", "fly", "c1723", "--duration", "1"]
            + ["--out", str(fifo)],
            cwd=tmp_path,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,  # (it used to wait here forever)
        )
    finally:
        if reader and drained.is_alive():  # release a reader the run never opened for
            with open(fifo, "wb"):
                pass
    assert proc.returncode == 2, proc.stderr
    one_line(proc.stderr, str(fifo), "FIFO")


@pytest.mark.parametrize("spelling", ["drive.toml", "@drive.toml"])
def test_out_may_not_overwrite_an_output_format_file(tmp_path, run_cli, spelling, monkeypatch):
    """``--output 'udp:...?format=drive.toml' --out drive.toml``: the drive's frame format
    was read from the file, then the log was written over it. Refused with one line, the
    file untouched, nothing sent."""
    import socket

    monkeypatch.chdir(tmp_path)
    victim = tmp_path / "drive.toml"
    victim.write_text('text = "A{1}B{2}C{3}D{4}E{5}F{6}\\n"\nrate_hz = 50.0\n')
    before = victim.read_bytes()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as drive:
        drive.bind(("127.0.0.1", 0))
        drive.settimeout(0.5)
        url = f"udp:127.0.0.1:{drive.getsockname()[1]}?format={spelling}"
        code, _, err = run_cli("fly", "c1723", "--duration", "1", "--output", url, "--out", victim)
        assert code == 2, err
        one_line(err, "--out", "--output format", "destroy")
        assert victim.read_bytes() == before
        with pytest.raises(TimeoutError):
            drive.recv(100)  # the drive heard nothing


def test_a_geometry_file_saved_with_a_byte_order_mark_loads(run_cli, tmp_path):
    """Notepad's UTF-8 starts with a BOM: 'not valid TOML: Invalid statement (at line 1,
    column 1)' for a file that looks right in any editor."""
    src = Path(cli.__file__).parent / "presets" / "rus6_ceart.toml"
    path = tmp_path / "mine.toml"
    path.write_bytes(b"\xef\xbb\xbf" + src.read_bytes())
    code, out, err = run_cli("workspace", "--platform", path)
    assert code == 0, err
    assert "roll" in out


def test_a_geometry_file_not_in_utf8_says_where(run_cli, tmp_path):
    path = tmp_path / "latin1.toml"
    path.write_bytes(b'kind = "rus6"\nname = "caf\xe9"\n')
    code, _, err = run_cli("workspace", "--platform", path)
    assert code == 2
    one_line(err, f"{path}: not a text TOML file", "line 2", "save it as UTF-8")


# --------------------------------------------------------------------------- review: cli

#: A process's address space in the tests that read endless files: old code read them until
#: the memory ran out (a MemoryError traceback here; the machine's memory without a limit).
_AS_LIMIT = "import resource\nresource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30))"


@pytest.mark.parametrize(
    "args",
    [
        ["workspace", "--platform", "/dev/zero"],
        ["workspace", "--planar", "--platform", "/dev/urandom"],
        ["teleop", "--input", "file:CSV", "--calibration", "/dev/zero"],
    ],
    ids=["geometry", "3-RRR geometry", "calibration"],
)
def test_a_toml_path_that_never_ends_is_one_line(tmp_path, args):
    """``--platform /dev/zero`` (or /dev/urandom, any device that never ends): the file was
    read whole, until the memory ran out. One line naming the file, exit 2."""
    csv = tmp_path / "cursor.csv"
    csv.write_text("t,x,y\n0,100,100\n0.5,120,110\n")
    args = [a.replace("CSV", str(csv)) for a in args]
    code, err = run_process(*args, setup=_AS_LIMIT, cwd=tmp_path)
    assert code == 2, err
    one_line(err, f"{args[-1]}: larger than", "not a configuration file")


def test_a_geometry_given_through_a_pipe_is_read_once(tmp_path):
    """``--platform <(cat rig.toml)`` (a shell's process substitution: a pipe that can be
    read once) was read again for each use of the file, and the second read found it empty:
    "missing field 'rb'", of a complete geometry. It is read once and kept: the same reach
    as from the file itself."""
    import subprocess
    import sys

    import motionbase

    text = resources.files("motionbase.presets").joinpath("rus6_ceart.toml").read_bytes()
    plain = tmp_path / "rig.toml"
    plain.write_bytes(text)
    here = str(Path(motionbase.__file__).parents[1])  # the motionbase under test
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([here, os.environ.get("PYTHONPATH", "")])}

    def workspace(platform: str, fds: tuple[int, ...] = ()) -> str:
        out = subprocess.run(
            [sys.executable, "-m", "motionbase", "workspace", "--platform", platform],
            capture_output=True, text=True, pass_fds=fds, env=env, timeout=300,
        )  # fmt: skip
        assert out.returncode == 0, out.stderr
        return out.stdout.replace(platform, "RIG")

    r, w = os.pipe()
    try:
        os.write(w, text)  # (a few kB: within the pipe's buffer)
        os.close(w)
        piped = workspace(f"/dev/fd/{r}", (r,))
    finally:
        os.close(r)
    assert piped == workspace(str(plain))


@pytest.mark.parametrize(
    "args, needles",
    [
        (["stream", "--signing-key", "/dev/urandom"], ("signing key /dev/urandom", "32 raw bytes")),
        (["teleop", "--input", "file:/dev/zero"], ("/dev/zero: line 1", "t,x,y")),
    ],
    ids=["signing key", "cursor CSV"],
)
def test_a_key_or_cursor_file_that_never_ends_is_one_line(tmp_path, args, needles):
    """``--signing-key /dev/urandom`` (the README makes a key with ``head -c 32
    /dev/urandom``) and ``--input file:/dev/zero`` were read until the memory ran out."""
    link = ["--mavlink", f"udpin:127.0.0.1:{_closed_port()}"] if args[0] == "stream" else []
    out = tmp_path / "x.mcap"
    code, err = run_process(
        *args, *link, "--duration", "1", "--out", out, setup=_AS_LIMIT, cwd=tmp_path
    )
    assert code == 2, err
    one_line(err, *needles)
    assert not out.exists()


@pytest.mark.parametrize(
    "args, needles",
    [
        # a traceback (OverflowError: cannot convert float infinity to integer) ...
        (["--speed-deg-s", "1e-320"], ("deg/s", "more than an hour", "--speed-deg-s")),
        (["--platform", "stewart6", "--speed-mm-s", "1e-320"], ("mm/s", "--speed-mm-s")),
        # ... or a sweep of years, its whole table of commands made before the first frame
        (["--speed-deg-s", "0.0001"], ("0.0001 deg/s", "more than an hour", "--speed-deg-s")),
        # "+-57.2958 deg about neutral leaves the crank limits (choose a smaller --range-deg)"
        (["--platform", "stewart6", "--range-mm", "1000"], ("+-1000 mm", "--range-mm")),
    ],
    ids=["tiny speed", "tiny linear speed", "slow speed", "linear range"],
)
def test_an_output_test_sweep_out_of_reach_is_one_line_in_the_units_given(args, needles):
    sock = udp_listener()
    try:
        url = f"udp:127.0.0.1:{sock.getsockname()[1]}"
        code, err = run_process("output", "--test", url, *args, setup=_AS_LIMIT)
        frames = received(sock)
    finally:
        sock.close()
    assert code == 2, err
    line = one_line(err, *needles)
    assert ("deg" in line) == ("deg" in " ".join(args)), line
    assert frames == []


@pytest.mark.parametrize("scale", ["1e-12", "1e-300"])
def test_an_omct_scale_too_small_to_measure_is_one_line(tmp_path, run_cli, scale):
    """``omct --scale 1e-300``: minutes of tests, then a traceback from the plots; ``1e-12``:
    a table whose heave column was rounding noise, marked as a limit acting (exit 0)."""
    out = tmp_path / "omct"
    code, _, err = run_cli("omct", "--scale", scale, "--out", out)
    assert code == 2, err
    one_line(err, f"--scale {float(scale):g}", "is below 1e-06")
    assert not out.exists()


@pytest.mark.parametrize(
    "args",
    [["output", "--test", "URL", "--platform", "rrr3"], ["fly", "--planar", "--output", "URL"]],
)
def test_the_3rrr_drives_through_an_output_url_without_a_format(tmp_path, args):
    """The README's ``output --test URL --platform rrr3`` (and ``fly --planar --output URL``)
    was refused for a format the user never gave: "text format 'A{1}B{2}C{3}D{4}E{5}F{6}\\n':
    placeholder {4}: the motor number must be 1..3". The default names the robot's motors."""
    sock = udp_listener()
    url = f"udp:127.0.0.1:{sock.getsockname()[1]}"
    out = ["--duration", "1", "--out", tmp_path / "x.mcap"] if args[0] == "fly" else []
    try:
        code, err = run_process(*[url if a == "URL" else a for a in args], *out)
        frames = received(sock)
    finally:
        sock.close()
    assert code == 0, err
    assert frames and all(re.fullmatch(rb"A-?\d+B-?\d+C-?\d+\n", f) for f in frames), frames[:3]


def test_tune_out_may_not_overwrite_the_platform_file(tmp_path, run_cli):
    """``tune --platform rig.toml --out rig.toml``: the tuning read the geometry, then wrote
    the tuned washout over it (exit 0): the user's geometry was gone."""
    rig = tmp_path / "rig.toml"
    rig.write_bytes((Path(cli.__file__).parent / "presets" / "rus6_ceart.toml").read_bytes())
    before = rig.read_bytes()
    args = ["--scripts", "c1723@0:5", "--holdout", "none", "--budget", "1"]
    code, _, err = run_cli("tune", "--platform", rig, *args, "--out", rig)
    assert code == 2, err
    one_line(err, "--out", "--platform", "destroy")
    assert rig.read_bytes() == before


@pytest.mark.parametrize("suffix", [".tlog", ".bin"])
def test_a_log_without_states_leaves_an_existing_out_file_untouched(tmp_path, run_cli, suffix):
    """``stream --mavlink notes.tlog --fast --out flight.mcap``, the .tlog holding no
    MAVLink message of the states: refused, but only at the run's first tick, after the
    log had been opened over flight.mcap (the user's earlier recording, now a log of one
    park tick). Refused when the log is opened, before anything is written."""
    garbage = tmp_path / f"garbage{suffix}"
    garbage.write_bytes(np.random.default_rng(3).bytes(5_000))
    out = tmp_path / "flight.mcap"
    out.write_bytes(b"an earlier recording")
    code, _, err = run_cli("stream", "--mavlink", garbage, "--fast", "--out", out)
    assert code == 2, err
    one_line(err, f"garbage{suffix}", "no ", "messages")
    assert out.read_bytes() == b"an earlier recording"


@pytest.mark.parametrize(
    "edit, needles",
    [
        # numpy's overflow warning (two lines of it) came before the error
        ({"base_radius": 1e300, "neutral_height": 0.6}, ("'neutral_height'", "inf m long")),
        # blamed on neutral_height, a field the file did not have
        ({"neutral_length": 1e300}, ("'neutral_length'", "1e+300 m")),
    ],
    ids=["radius", "neutral length"],
)
def test_a_stewart_geometry_of_astronomical_size_is_one_line(tmp_path, edit, needles):
    import tomllib

    import tomli_w

    from motionbase.config import preset_path

    with open(preset_path("stewart6", "seat"), "rb") as fh:
        geometry = tomllib.load(fh)
    if "neutral_height" in edit:
        del geometry["neutral_length"]
    geometry.update(edit)
    path = tmp_path / "huge_seat.toml"
    path.write_bytes(tomli_w.dumps(geometry).encode())
    code, err = run_process("workspace", "--platform", path)
    assert code == 2, err
    line = one_line(err, "huge_seat.toml", *needles)
    assert "neutral_height" not in line or "neutral_height" in edit, line


def test_an_output_frame_rate_too_slow_to_stop_is_one_line(tmp_path, run_cli):
    """``--output 'udp:...?rate=1e-320'``: the sender thread's wait for its second frame
    overflowed (a traceback from the thread), one frame was sent, and the run exited 0."""
    rec = write_recording(tmp_path / "rec.mcap", ceart_config())
    sock = udp_listener()
    url = f"udp:127.0.0.1:{sock.getsockname()[1]}?rate=1e-320"
    out = tmp_path / "out.mcap"
    try:
        code, _, err = run_cli("replay", rec, "--platform", "ceart", "--output", url, "--out", out)
        frames = received(sock)
    finally:
        sock.close()
    assert code == 2, err
    one_line(err, "rate must be in [1, 10000] Hz", "1e-320")
    assert frames == [] and not out.exists()


def test_a_baud_rate_past_a_c_long_is_one_line(tmp_path, run_cli):
    """``serial:/dev/ttyUSB0?baud=99999999999999999999`` (a pseudo-terminal here): pyserial's
    OverflowError came out as a traceback."""
    import pty

    master, slave = pty.openpty()
    try:
        url = f"serial:{os.ttyname(slave)}?baud=99999999999999999999"
        code, _, err = run_cli("output", "--test", url)
    finally:
        os.close(master)
        os.close(slave)
    assert code == 2, err
    one_line(err, "cannot open serial port", "too large")


@pytest.mark.parametrize("limit", ["angle_min_deg", "angle_max_deg"])
def test_a_neutral_angle_on_a_crank_limit_names_neutral_angle_deg(tmp_path, run_cli, limit):
    """``neutral_angle_deg = 0`` with ``angle_min_deg = 0``: the crank angle the neutral height
    gives back is -0.00 deg, a rounding below the limit, and the error named
    'neutral_height', a field the file did not have (with ``angle_max_deg = 0`` the rounding
    fell the other way and the file was taken). Refused alike, naming the field given."""
    src = (Path(cli.__file__).parent / "presets" / "rus6_ceart.toml").read_text()
    lines = [ln for ln in src.splitlines() if not ln.startswith((limit, "park_angle_deg"))]
    path = tmp_path / "on_limit.toml"
    path.write_text(f"{limit} = 0.0\n" + "\n".join(lines) + "\n")
    code, _, err = run_cli("workspace", "--platform", path)
    assert code == 2, err
    line = one_line(err, "on_limit.toml", "'neutral_angle_deg'", "0 deg is on one of")
    assert "neutral_height" not in line


@pytest.mark.parametrize("how", ["copy", "hard link"])
def test_a_held_out_recording_that_is_a_tuned_one_under_another_name_is_refused(
    tmp_path, run_cli, how
):
    """The README: "the same recording is refused" as a held-out manoeuvre. A symlink was
    caught; a hard link or a copy of the tuning recording was scored as held out (exit 0),
    the overfitting check then comparing the tuning set with itself."""
    rec = tmp_path / "flight.mcap"
    code, _, err = run_cli("fly", "--duration", "5", "--out", rec)
    assert code == 0, err
    other = tmp_path / "held_out.mcap"
    if how == "copy":
        other.write_bytes(rec.read_bytes())
    else:
        os.link(rec, other)
    out = tmp_path / "tuned.toml"
    code, _, err = run_cli(
        "tune", "--recordings", rec, "--holdout", other, "--budget", "1", "--out", out
    )
    assert code == 2, err
    one_line(err, "--holdout held_out.mcap is also in the tuning set", "flight.mcap")
    assert not out.exists()


def test_too_many_workers_says_how_many_are_taken(run_cli, tmp_path):
    """``--workers 9`` on two processors said "give at most 2 (the default)", while up to
    four per processor (8) are taken, as the README says."""
    from motionbase.io.executors import MAX_WORKERS_PER_PROCESSOR, default_workers

    most = MAX_WORKERS_PER_PROCESSOR * default_workers()
    out = tmp_path / "tuned.toml"
    args = ["--scripts", "c1723@0:5", "--holdout", "none", "--budget", "1", "--out", out]
    code, _, err = run_cli("tune", "--workers", most + 1, *args)
    assert code == 2, err
    one_line(err, f"--workers {most + 1}", f"give at most {most} ")
    assert not out.exists()


def test_tune_workers_and_a_scheduler_are_refused_together(run_cli, tmp_path):
    """``--workers 2 --scheduler tcp://...``: the README gives them as alternatives; the
    workers were silently ignored (and the error, after a 10 s wait, was the scheduler's)."""
    out = tmp_path / "tuned.toml"
    args = ["--scripts", "c1723@0:5", "--holdout", "none", "--budget", "1", "--out", out]
    code, _, err = run_cli(
        "tune", "--workers", "2", "--scheduler", f"tcp://127.0.0.1:{_closed_port()}", *args
    )
    assert code == 2, err
    one_line(err, "--workers 2 and --scheduler", "give one of them")
    assert not out.exists()


def _with_field(src: Path, dst: Path, topic: str, key: str, value: object) -> Path:
    """A copy of the recording ``src`` whose 10th ``topic`` message has ``key`` = ``value``."""
    from mcap.reader import make_reader

    with open(src, "rb") as fh:
        reader = make_reader(fh)
        metadata = list(reader.iter_metadata())
        messages = list(reader.iter_messages())
    with open(dst, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        for m in metadata:
            writer.add_metadata(m.name, m.metadata)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        seen = 0
        for schema, channel, msg in messages:
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id]
                )
            data = msg.data
            if channel.topic == topic:
                seen += 1
                if seen == 10:
                    data = json.dumps({**json.loads(data), key: value}).encode()
            writer.add_message(channels[channel.id], msg.log_time, data, msg.publish_time)
        writer.finish()
    return dst


@pytest.mark.parametrize(
    "topic, key, value, needle",
    [
        ("/platform/pose", "pose", 5, "field 'pose' is 5"),
        ("/platform/pose", "pose", ["a", 0, 0, 0, 0, 0], "holds 'a', not a number"),
        ("/platform/actuators", "angles", True, "field 'angles' is True"),
        ("/aircraft/state", "specific_force", [[1.0], 0.0, 0.0], "holds [1.0], not a number"),
    ],
    ids=["number", "string in the list", "bool", "list in the list"],
)
def test_report_of_a_recording_with_a_malformed_field_is_one_line(
    tmp_path, run_cli, topic, key, value, needle
):
    """A recording whose message held a number, a bool or a string where a list of numbers
    goes: ``report`` answered with a TypeError or ValueError traceback. The line names the
    recording too (it named only the topic)."""
    rec = tmp_path / "flight.mcap"
    code, _, err = run_cli("fly", "--duration", "3", "--out", rec)
    assert code == 0, err
    bad = _with_field(rec, tmp_path / "bad.mcap", topic, key, value)
    out = tmp_path / "report"
    code, _, err = run_cli("report", bad, "--out", out)
    assert code == 2, err
    one_line(err, f"bad.mcap: {topic}: message 10", needle)
    assert not out.exists()


def test_tune_scripts_and_holdout_given_twice_take_both(tmp_path, run_cli):
    """``--scripts c1723@0:5 --scripts c1723@10:15``: the second replaced the first, which
    was silently not tuned on (``--recordings`` given twice takes both)."""
    out = tmp_path / "tuned.toml"
    code, _, err = run_cli(
        "tune", "--scripts", "c1723@0:5", "--scripts", "c1723@10:15",
        "--holdout", "c1723@20:25", "--holdout", "c1723@30:35", "--budget", "1", "--out", out,
    )  # fmt: skip
    assert code == 0, err
    header = out.read_text().split("\n[", 1)[0]
    for window in ("c1723@0:5", "c1723@10:15", "c1723@20:25", "c1723@30:35"):
        assert window in header, (window, header)


_UNREADABLE = "/proc/self/mem"  # a file that opens and fails its first read (EIO), as root too


@pytest.mark.skipif(not os.path.exists(_UNREADABLE), reason="needs Linux's /proc/self/mem")
@pytest.mark.parametrize(
    "args, needle",
    [
        (["fly", _UNREADABLE, "--duration", "1"], "cannot read the JSBSim script"),
        (["tune", "--scripts", _UNREADABLE, "--holdout", "none"], "cannot read the JSBSim script"),
        (["replay", _UNREADABLE], "cannot read"),
        (["report", _UNREADABLE], "cannot read"),
        (["workspace", "--platform", _UNREADABLE], "cannot read"),
    ],
    ids=["fly", "tune", "replay", "report", "geometry"],
)
def test_a_file_that_cannot_be_read_is_one_line(tmp_path, run_cli, args, needle):
    """A file that opens but whose read fails (EIO from a failing disk or stick; a script
    without read permission fails the same way for a user who is not root) was an OSError
    traceback for a JSBSim script, a recording and a TOML file."""
    out = ["--out", tmp_path / ("x.toml" if args[0] == "tune" else "x.mcap")]
    code, _, err = run_cli(*args, *(out if args[0] in ("fly", "tune", "replay") else []))
    assert code == 2, err
    one_line(err, "/mem: " + needle)
    assert not (tmp_path / "x.mcap").exists() and not (tmp_path / "x.toml").exists()


@pytest.mark.parametrize(
    "args, needle",
    [
        (["tune", "--scripts", "c1723@0:5", "--holdout", "none", "--out", "LONG.toml"], "too long"),
        (["omct", "--out", "LONG"], "too long"),
        (["fly", "LONG.xml"], "not found"),
        (["tune", "--scripts", "LONG", "--holdout", "none", "--out", "x.toml"], "unknown"),
        (["stream", "--mavlink", "LONG.tlog", "--fast"], "no such file"),
        (["fly", "--params", "LONG"], "unknown washout preset"),
        (["fly", "--platform", "LONG"], "unknown rus6 preset"),
        (["stream", "--signing-key", "LONG", "--mavlink", "udpin:127.0.0.1:14599"], "too long"),
    ],
    ids=["tune --out", "omct --out", "script", "tune --scripts", "log", "params", "platform",
         "signing key"],
)  # fmt: skip
def test_a_file_name_too_long_is_one_line(tmp_path, run_cli, monkeypatch, args, needle):
    """A name longer than the file system takes (300 characters): pathlib's ``is_file()``,
    ``is_dir()`` and ``exists()`` raise for it where ``os.path``'s say False, and those
    tests were OSError tracebacks (ENAMETOOLONG) for a script, a log, a preset name, and
    tune's and omct's --out."""
    monkeypatch.chdir(tmp_path)
    long = "a" * 300
    out = [] if "--out" in args else ["--out", tmp_path / "x.mcap"]
    duration = ["--duration", "1"] if args[0] in ("fly", "stream") else []
    code, _, err = run_cli(*[a.replace("LONG", long) for a in args], *duration, *out)
    assert code == 2, err
    one_line(err, needle)
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("field", ["rb", "crank"])
def test_a_rus6_geometry_of_astronomical_size_is_one_line(tmp_path, run_cli, field):
    """``rb = 1e300`` with a ``neutral_height`` (as in a recording's stored settings too):
    numpy's overflow warning (two lines) came before the error; ``crank = 1e300`` printed
    the rod length it needs with 300 digits."""
    import tomllib

    import tomli_w

    from motionbase.config import preset_path

    with open(preset_path("rus6", "ceart"), "rb") as fh:
        geometry = tomllib.load(fh)
    del geometry["neutral_angle_deg"]
    geometry.update({field: 1e300, "neutral_height": 0.65})
    path = tmp_path / "huge_ceart.toml"
    path.write_bytes(tomli_w.dumps(geometry).encode())
    code, err = run_process("workspace", "--platform", path)
    assert code == 2, err
    line = one_line(err, "huge_ceart.toml", "field 'rod'", "needs >=")
    assert len(line) < 300, line


@pytest.mark.parametrize("second", ["udp:127.0.0.1:{port}?rate=50", "serial:{link}"])
def test_one_drive_given_twice_as_an_output_is_refused(tmp_path, run_cli, second):
    """``--output`` twice to the same drive (another rate, or a serial port by a symlink
    such as /dev/serial/by-id/...) opened two senders on one link: each ramps from the frames
    it sent, so the drive got two interleaved command streams. Refused before the run."""
    first = "udp:127.0.0.1:{port}" if second.startswith("udp") else "serial:/dev/null"
    (tmp_path / "port").symlink_to("/dev/null")
    urls = [u.format(port=49999, link=tmp_path / "port") for u in (first, second)]
    out = tmp_path / "x.mcap"
    out.write_bytes(b"kept")
    args = ["fly", "c1723", "--duration", "1", "--out", out]
    code, _, err = run_cli(*args, "--output", urls[0], "--output", urls[1])
    assert code == 2, err
    one_line(err, "both send to", "give each drive once")
    assert out.read_bytes() == b"kept"
