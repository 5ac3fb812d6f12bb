"""McapSource and read_messages: replays, truncated files, files that are not MCAP."""

from __future__ import annotations

import json
import logging
import math
import re
from pathlib import Path

import numpy as np
import pytest
from mcap.opcode import Opcode
from mcap.writer import Writer

from motionbase.errors import LogFormatError, SourceError
from motionbase.io.mcap_log import MCAP_MAGIC, McapLogger
from motionbase.io.mcap_source import McapSource, read_messages, read_metadata
from motionbase.state import AircraftState

RATE = 120.0


def _states(n: int, seed: int = 3) -> list[AircraftState]:
    rng = np.random.default_rng(seed)
    return [
        AircraftState(
            t=k / RATE,
            specific_force=rng.normal(size=3) + [0, 0, -9.80665],
            angular_velocity=rng.normal(size=3) * 0.1,
            attitude=rng.normal(size=3) * 0.2,
            angular_acceleration=rng.normal(size=3) if k % 2 else None,
        )
        for k in range(1, n + 1)
    ]


def _write(path: Path, states: list[AircraftState], config: dict | None) -> None:
    with McapLogger(path, config if config is not None else {}) as logger:
        for s in states:
            msg = {
                "specific_force": s.specific_force,
                "angular_velocity": s.angular_velocity,
                "attitude": s.attitude,
            }
            if s.angular_acceleration is not None:
                msg["angular_acceleration"] = s.angular_acceleration
            logger.add("/aircraft/state", s.t, msg)
            logger.add("/washout/pose", s.t, {"pose": np.r_[s.attitude, s.attitude] * 0.1})


def _same(a: AircraftState, b: AircraftState) -> bool:
    acc_same = (a.angular_acceleration is None and b.angular_acceleration is None) or (
        a.angular_acceleration is not None
        and b.angular_acceleration is not None
        and np.array_equal(a.angular_acceleration, b.angular_acceleration)
    )
    return (
        a.t == b.t
        and np.array_equal(a.specific_force, b.specific_force)
        and np.array_equal(a.angular_velocity, b.angular_velocity)
        and np.array_equal(a.attitude, b.attitude)
        and acc_same
    )


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> tuple[Path, list[AircraftState]]:
    path = tmp_path_factory.mktemp("rec") / "rec.mcap"
    states = _states(600)  # 5 s
    _write(path, states, {"rate_hz": RATE, "source": {"kind": "jsbsim", "script": "c1723"}})
    return path, states


def test_replays_the_recorded_states_exactly(recording) -> None:
    path, states = recording
    with McapSource(path) as source:
        assert source.rate_hz == RATE
        assert source.count == len(states)
        assert source.duration_s == pytest.approx(states[-1].t - states[0].t, abs=1e-9)
        assert source.truncated is False
        assert source.metadata["source"] == {"kind": "jsbsim", "script": "c1723"}
        back = list(source)
    assert len(back) == len(states)
    assert all(_same(a, b) for a, b in zip(states, back, strict=True))
    desc = source.describe()
    assert desc["kind"] == "mcap" and desc["count"] == 600 and json.dumps(desc)
    assert read_metadata(path)["rate_hz"] == RATE


def test_rate_from_message_spacing_without_config(tmp_path: Path) -> None:
    path = tmp_path / "noconf.mcap"
    rate = 50.0
    states = [
        AircraftState(t=k / rate, specific_force=[0, 0, -9.8], angular_velocity=[0, 0, 0])
        for k in range(1, 201)
    ]
    _write(path, states, None)
    source = McapSource(path)
    assert source.metadata == {}
    assert source.rate_hz == pytest.approx(rate, rel=1e-6)


@pytest.mark.parametrize("fraction", [0.02, 0.2, 0.5, 0.77, 0.999])
def test_truncated_file_gives_a_prefix_and_a_warning(
    recording, tmp_path: Path, caplog, fraction: float
) -> None:
    path, states = recording
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    full = read_messages(path)

    with caplog.at_level(logging.WARNING, logger="motionbase"):
        got = read_messages(cut)
    assert any("truncated" in r.getMessage() and str(cut) in r.getMessage() for r in caplog.records)
    for topic, msgs in got.items():
        assert msgs == full[topic][: len(msgs)]
    n = len(got.get("/aircraft/state", []))
    if fraction > 0.5:
        assert n > 0.3 * len(states)

    caplog.clear()
    if n == 0:
        with pytest.raises(LogFormatError, match="no /aircraft/state messages"):
            McapSource(cut)
        return
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        source = McapSource(cut)
    assert source.truncated and source.count == n
    assert any("truncated" in r.getMessage() for r in caplog.records)
    with source:
        back = list(source)
    assert len(back) == n and all(_same(a, b) for a, b in zip(states, back, strict=False))


def test_cut_at_every_record_boundary_region_never_raises(recording, tmp_path: Path) -> None:
    """A cut anywhere (here every 997 bytes) reads as a prefix, never as a crash."""
    path, _ = recording
    data = path.read_bytes()
    full = read_messages(path)["/aircraft/state"]
    cut = tmp_path / "c.mcap"
    previous = 0
    for size in range(8, len(data), 997):
        cut.write_bytes(data[:size])
        got = read_messages(cut).get("/aircraft/state", [])
        assert got == full[: len(got)]
        assert len(got) >= previous  # longer files never give fewer messages
        previous = len(got)


@pytest.mark.parametrize("collecting", [True, False])
def test_reading_leaves_the_garbage_collector_as_it_was(recording, tmp_path, collecting) -> None:
    """read_messages switches the cyclic collector off while it reads, and back to what it
    was after, when the file is whole, cut or not MCAP."""
    import gc

    path, _ = recording
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:1000])
    (tmp_path / "no.mcap").write_bytes(b"not mcap")
    was = gc.isenabled()
    try:
        (gc.enable if collecting else gc.disable)()
        read_messages(path)
        read_messages(cut)
        with pytest.raises(LogFormatError):
            read_messages(tmp_path / "no.mcap")
        assert gc.isenabled() is collecting
    finally:
        (gc.enable if was else gc.disable)()


def test_not_mcap_is_a_one_line_error_naming_the_file(tmp_path: Path) -> None:
    for name, content in [
        ("text.mcap", b"hello, this is a text file, not a recording\n"),
        ("empty.mcap", b""),
        ("short.mcap", b"\x89MC"),
    ]:
        bad = tmp_path / name
        bad.write_bytes(content)
        for reader in (McapSource, read_messages):
            with pytest.raises(LogFormatError) as err:
                reader(bad)
            msg = str(err.value)
            assert str(bad) in msg and "not an MCAP file" in msg and "\n" not in msg


def test_missing_file_is_a_source_error(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="not found"):
        McapSource(tmp_path / "nope.mcap")
    with pytest.raises(SourceError, match="directory"):
        read_messages(tmp_path)


def test_reads_a_file_written_by_the_mcap_library(tmp_path: Path) -> None:
    """Any JSON MCAP recording with the topic replays, not only motionbase's own."""
    path = tmp_path / "other.mcap"
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        sid = writer.register_schema("state", "jsonschema", b"{}")
        cid = writer.register_channel("/aircraft/state", "json", sid)
        for k in range(1, 101):
            t = k / 100
            msg = {
                "t": t,
                "specific_force": [0.0, 0.1, -9.8],
                "angular_velocity": [0.0, 0.0, t],
                "attitude": [0.0, 0.0, 0.0],
            }
            writer.add_message(cid, round(t * 1e9), json.dumps(msg).encode(), round(t * 1e9))
        writer.finish()
    source = McapSource(path)
    assert source.rate_hz == pytest.approx(100.0)
    states = list(source)
    assert [s.t for s in states] == [k / 100 for k in range(1, 101)]
    assert states[-1].angular_velocity[2] == 1.0


def test_log_times_beyond_a_signed_64_bit_integer_replay(tmp_path: Path) -> None:
    """MCAP's times are unsigned 64-bit nanoseconds: a writer's times past 2**63 (and a step
    back among them) are read, not an OverflowError."""
    path = tmp_path / "late.mcap"
    base = 2**63 + 5
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        cid = writer.register_channel("/aircraft/state", "json", 0)
        for k in range(1, 101):
            ns = base + k * 10_000_000 if k != 50 else base - 1  # one message logged early
            writer.add_message(cid, ns, json.dumps(_good_message(k / 100)).encode(), ns)
        writer.finish()
    source = McapSource(path)
    assert source.count == 100
    assert source.rate_hz == pytest.approx(100.0)  # 10 ms apart
    assert source.duration_s == pytest.approx(0.99)
    assert [s.t for s in source] == [k / 100 for k in range(1, 101)]


def test_log_times_that_run_backwards_still_give_the_rate(tmp_path: Path) -> None:
    """A recording without a configuration whose log times fall by 20 ms a message (a
    writer that counts down): its rate is their spacing, 50 Hz. It was refused: "fewer than
    two distinct times", of which it has 100."""
    path = tmp_path / "backwards.mcap"
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        cid = writer.register_channel("/aircraft/state", "json", 0)
        for k in range(1, 101):
            ns = (200 - k) * 20_000_000
            writer.add_message(cid, ns, json.dumps(_good_message(k / 50)).encode(), ns)
        writer.finish()
    source = McapSource(path)
    assert source.rate_hz == pytest.approx(50.0)
    assert source.duration_s == pytest.approx(99 * 0.02)  # (it was -1.98 s: a progress bar's)


def test_non_finite_and_null_values_read_back_as_floats(tmp_path: Path) -> None:
    path = tmp_path / "nan.mcap"
    with McapLogger(path, {"rate_hz": 10.0}) as logger:
        logger.add(
            "/aircraft/state",
            0.1,
            {
                "specific_force": [math.nan, math.inf, -9.8],
                "angular_velocity": [0.0, 0.0, 0.0],
                "attitude": [None, 0.0, 0.0],
            },
        )
    (state,) = list(McapSource(path))
    assert math.isnan(state.specific_force[0]) and state.specific_force[1] == math.inf
    assert math.isnan(state.attitude[0])
    assert not state.is_finite()


def test_wrong_topic_lists_the_topics_present(recording) -> None:
    path, _ = recording
    with pytest.raises(LogFormatError, match="/washout/pose"):
        McapSource(path, topic="/nothing")


# --------------------------------------------------------------------------- malformed samples
# Issue 13, item 10: a malformed aircraft state never aborts a replay; it is rejected,
# counted in /health and held like any invalid sample.


def _good_message(t: float) -> dict:
    return {
        "t": t,
        "specific_force": [0.3 * math.sin(t), 0.2, -9.80665],
        "angular_velocity": [0.0, 0.05 * math.cos(t), 0.0],
        "attitude": [0.0, 0.02, 0.1],
    }


_GOOD = json.dumps(_good_message(0.5)).encode()
MALFORMED = {
    "missing field": json.dumps({k: v for k, v in _good_message(0.5).items() if k != "attitude"}),
    "string for a number": _GOOD.decode().replace("0.2,", '"0.2",'),
    "bool for a number": _GOOD.decode().replace("0.2,", "true,"),
    "wrong length": json.dumps({**_good_message(0.5), "angular_velocity": [0.0, 0.1]}),
    "null message": "null",
    "null field": json.dumps({**_good_message(0.5), "specific_force": None}),
    "list message": "[1, 2, 3]",
    "not JSON": '{"t": 0.5, "specific_force": [0, 0',
    "non-UTF-8 bytes": _GOOD.replace(b'"attitude"', b'"att\xff\xfeude"'),
    "negative time": json.dumps(_good_message(-4.0)),
    "huge integer": json.dumps({**_good_message(0.5), "attitude": [10**400, 0, 0]}),
    "fresh not a bool": json.dumps({**_good_message(0.5), "fresh": "yes"}),
}
BAD_INDEX = 60  # 0-based position of the bad message among the states


def _write_raw(path: Path, payloads: list[bytes], rate: float = 100.0) -> None:
    """A recording made with the mcap library, the message data written as raw bytes."""
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        writer.add_metadata("motionbase", {"config": json.dumps({"rate_hz": rate})})
        sid = writer.register_schema("state", "jsonschema", b"{}")
        cid = writer.register_channel("/aircraft/state", "json", sid)
        for k, data in enumerate(payloads):
            ns = round((k + 1) / rate * 1e9)
            writer.add_message(cid, ns, data, ns)
        writer.finish()


def _recording_with(path: Path, bad: bytes | str, n: int = 240) -> list[bytes]:
    payloads = [json.dumps(_good_message((k + 1) / 100)).encode() for k in range(n)]
    payloads[BAD_INDEX] = bad.encode() if isinstance(bad, str) else bad
    _write_raw(path, payloads)
    return payloads


@pytest.mark.parametrize("kind", sorted(MALFORMED))
def test_a_malformed_state_becomes_a_sample_the_validation_rejects(tmp_path, caplog, kind):
    path = tmp_path / "bad.mcap"
    _recording_with(path, MALFORMED[kind])
    with caplog.at_level(logging.WARNING, logger="motionbase"), McapSource(path) as source:
        states = list(source)
    assert len(states) == 240
    assert source.malformed == 1
    bad = states[BAD_INDEX]
    assert not bad.is_finite()  # the pipeline rejects it (tests below)
    for k, s in enumerate(states):
        if k != BAD_INDEX:
            assert s.t == pytest.approx((k + 1) / 100, abs=1e-12) and s.is_finite()
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and str(path) in warnings[0]
    assert f"message {BAD_INDEX + 1}" in warnings[0] and "\n" not in warnings[0]
    # read_messages (replay --check, report) reads the rest of the file
    got = read_messages(path)["/aircraft/state"]
    assert len(got) in (239, 240)


def test_python_json_nan_tokens_are_read_as_non_finite_numbers(tmp_path):
    """``json.dumps(float("nan"))`` writes a bare NaN: a non-finite value, not a crash."""
    path = tmp_path / "nan.mcap"
    bad = json.dumps({**_good_message(0.5), "specific_force": [math.nan, 0.0, -math.inf]})
    assert "NaN" in bad and "-Infinity" in bad
    _recording_with(path, bad)
    with McapSource(path) as source:
        states = list(source)
    assert source.malformed == 0  # well-formed, only not finite: the validation's business
    assert math.isnan(states[BAD_INDEX].specific_force[0])
    assert states[BAD_INDEX].specific_force[2] == -math.inf
    assert read_messages(path)["/aircraft/state"][BAD_INDEX]["specific_force"][2] == -math.inf


def _health(path: Path) -> dict:
    return read_messages(path)["/health"][-1]


@pytest.mark.parametrize("kind", ["string for a number", "non-UTF-8 bytes", "null message"])
def test_replay_and_check_of_a_malformed_recording_through_the_cli(
    tmp_path, capsys, fresh_logger, kind
):
    from motionbase import cli

    src = tmp_path / "bad.mcap"
    payloads = _recording_with(src, MALFORMED[kind])
    out = tmp_path / "out.mcap"
    code = cli.main(["replay", str(src), "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "Traceback" not in captured.err
    assert "malformed" in captured.out and "rejected inputs 1;" in captured.out
    assert _health(out)["rejected_inputs"] == 1  # counted in /health
    states = read_messages(out)["/aircraft/state"]
    assert [m["accepted"] for m in states].count(False) == 1
    assert states[BAD_INDEX]["accepted"] is False
    # held: the washout saw the previous sample again, so its pose moved on smoothly
    poses = np.array([m["angles"] for m in read_messages(out)["/platform/actuators"]])
    assert np.isfinite(poses).all()

    # --check of the malformed recording itself runs and reports (it has no outputs: differs)
    code = cli.main(["replay", str(src), "--check"])
    captured = capsys.readouterr()
    assert code == 1 and "Traceback" not in captured.err
    assert "check: DIFFERS" in captured.out

    # the replay's own log replays bit for bit, the rejection included
    code = cli.main(["replay", str(out), "--check"])
    captured = capsys.readouterr()
    assert code == 0, captured.out + captured.err
    assert "check: identical to the recording" in captured.out

    # the same recording with the good sample in its place: no rejection at all
    payloads[BAD_INDEX] = json.dumps(_good_message((BAD_INDEX + 1) / 100)).encode()
    _write_raw(src, payloads)
    assert cli.main(["replay", str(src), "--out", str(out)]) == 0
    capsys.readouterr()
    assert _health(out)["rejected_inputs"] == 0


def test_replaying_a_truncated_recording_warns_once(tmp_path, capsys, fresh_logger):
    """The shipped recording cut at a third: the replay runs on what was written before the
    cut and says so once, on stderr (the source's warning, which report and tune share)."""
    from motionbase import cli

    shipped = Path(__file__).parents[1] / "recordings" / "c1723_30s.mcap"
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(shipped.read_bytes()[: shipped.stat().st_size // 3])
    code = cli.main(["replay", str(cut), "--out", str(tmp_path / "out.mcap")])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    said = (captured.out + captured.err).count("is truncated")  # (the folder says it too)
    assert said == 1 and "is truncated" in captured.err, captured.out + captured.err


def test_rate_from_metadata_must_be_finite(tmp_path):
    path = tmp_path / "inf.mcap"
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        writer.add_metadata("motionbase", {"config": '{"rate_hz": Infinity}'})
        sid = writer.register_schema("state", "jsonschema", b"{}")
        cid = writer.register_channel("/aircraft/state", "json", sid)
        for k in range(1, 51):
            ns = k * 20_000_000
            writer.add_message(cid, ns, json.dumps(_good_message(k / 50)).encode(), ns)
        writer.finish()
    assert McapSource(path).rate_hz == pytest.approx(50.0)  # from the spacing, not inf


# --------------------------------------------------------------------------- damaged files
# A file cut short (a crash while writing) is read up to the cut, with a warning; damage
# inside a file (a CRC that does not match, a record that cannot be read) is an error.

RECORDING = Path(__file__).parents[1] / "recordings" / "c1723_30s.mcap"


def _damage(data: bytes, offset: int, junk: bytes = b"\xde\xad\xbe\xef\x01\x02\x03\x04") -> bytes:
    damaged = bytearray(data)
    damaged[offset : offset + len(junk)] = junk
    assert damaged != data
    return bytes(damaged)


def _assert_damaged(path: Path, chunk_at: int | None = None) -> None:
    """Every reader refuses ``path`` in one line naming it, the damage, where (the chunk
    holding byte ``chunk_at`` when given) and what to do."""
    for reader in (McapSource, read_messages, read_metadata):
        with pytest.raises(LogFormatError) as err:
            reader(path)
        msg = str(err.value)
        assert str(path) in msg and "\n" not in msg, msg
        assert "damaged, not cut short" in msg and "re-record it, or copy it again" in msg
        where = re.search(r"at byte (\d+)|bytes (\d+) to (\d+)", msg)
        assert where is not None, msg
        if chunk_at is not None:
            assert "the chunk at byte" in msg, msg
            assert chunk_at - 200_000 < int(where.group(1)) <= chunk_at, msg


def test_a_damaged_recording_is_an_error_not_a_truncated_file(tmp_path, capsys, fresh_logger):
    """The audit's case: 8 bytes overwritten at byte 1,000,000 of a real recording were read
    as a cut (a quarter of the data, exit 0)."""
    from motionbase import cli

    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(_damage(RECORDING.read_bytes(), 1_000_000))
    _assert_damaged(bad, chunk_at=1_000_000)
    for args in (["replay", str(bad)], ["report", str(bad), "--out", str(tmp_path / "rep")]):
        assert cli.main(args) == 2
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and "damaged, not cut short" in lines[0], captured.err
        assert "truncated" not in captured.err and "Traceback" not in captured.err
    assert not (tmp_path / "rep").exists()


@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.5, 0.7, 0.9, 0.97, 0.995, 0.9995])
def test_damage_anywhere_in_a_finished_file_is_an_error(recording, tmp_path, fraction) -> None:
    """Chunks, message indexes, the summary and the footer: each is covered by a CRC or
    framed so that the damage shows."""
    path, _ = recording
    data = path.read_bytes()
    bad = tmp_path / "bad.mcap"
    offset = int(len(data) * fraction)
    bad.write_bytes(_damage(data, offset))
    _assert_damaged(bad)


@pytest.mark.parametrize(
    ("where", "junk"),
    [
        ("length of a chunk", b"\x7f"),  # a length of terabytes, past the end
        ("kind of a chunk", b"\x7f"),  # a record kind readers skip
        ("kind of the data end", b"\x7f"),
        ("closing magic", b"\x00"),
    ],
)
def test_damaged_framing_of_a_finished_file_is_not_a_cut(recording, tmp_path, where, junk):
    """Damage to what frames the records, in a file that ends with the MCAP magic (a
    finished file, which a cut never is)."""
    path, _ = recording
    data = path.read_bytes()
    starts = {}  # the first record of each kind: opcode -> byte
    at = len(MCAP_MAGIC)
    while at < len(data) - len(MCAP_MAGIC):
        starts.setdefault(data[at], at)
        at += 9 + int.from_bytes(data[at + 1 : at + 9], "little")
    offset = {
        "length of a chunk": starts[Opcode.CHUNK] + 5,
        "kind of a chunk": starts[Opcode.CHUNK],
        "kind of the data end": starts[Opcode.DATA_END],
        "closing magic": len(data) - 3,
    }[where]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(_damage(data, offset, junk))
    _assert_damaged(bad)


def test_damage_before_a_cut_is_still_damage(recording, tmp_path) -> None:
    path, _ = recording
    data = path.read_bytes()
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(_damage(data, len(data) // 4)[: int(len(data) * 0.8)])
    _assert_damaged(bad, chunk_at=len(data) // 4)


def test_bytes_after_the_end_of_a_finished_file_are_a_warning(
    recording, tmp_path, caplog, capsys, fresh_logger
):
    """They used to be ignored without a word; the recording itself is whole, so it is read."""
    from motionbase import cli

    path, states = recording
    appended = tmp_path / "appended.mcap"
    junk = b"garbage after the footer\n" * 4
    appended.write_bytes(path.read_bytes() + junk)
    said = f"{appended}: {len(junk)} bytes follow the end of the recording"
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        assert read_messages(appended) == read_messages(path)
        source = McapSource(appended)
    assert not source.truncated and source.count == len(states)
    assert [r.getMessage().startswith(said) for r in caplog.records] == [True, True]

    assert cli.main(["replay", str(appended)]) == 0
    captured = capsys.readouterr()
    assert [ln for ln in captured.err.splitlines() if "WARNING" in ln] == [
        f"motionbase: WARNING: {said} (its footer and closing magic); ignored, the recording "
        "itself is whole"
    ]
    assert "truncated" not in captured.err + captured.out


@pytest.mark.parametrize(
    ("config", "needle"),
    [
        ("[1, 2, 3]", "is a JSON array, not an object"),
        ('"ceart"', "is a JSON string, not an object"),
        ("42", "is a JSON number, not an object"),
        ("null", "is JSON null, not an object"),
        ("{not json", "is not valid JSON"),  # refused before; the others were read as none
    ],
)
def test_a_config_that_is_not_a_json_object_is_refused(
    tmp_path, capsys, fresh_logger, config, needle
):
    from motionbase import cli

    path = tmp_path / "bad_config.mcap"
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        writer.add_metadata("motionbase", {"config": config})
        sid = writer.register_schema("state", "jsonschema", b"{}")
        cid = writer.register_channel("/aircraft/state", "json", sid)
        for k in range(1, 121):
            ns = round(k / RATE * 1e9)
            writer.add_message(cid, ns, json.dumps(_good_message(k / RATE)).encode(), ns)
        writer.finish()
    for reader in (McapSource, read_metadata):
        with pytest.raises(LogFormatError, match=needle) as err:
            reader(path)
        assert str(path) in str(err.value) and "metadata 'config'" in str(err.value)
    assert cli.main(["replay", str(path)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and str(path) in lines[0], captured.err
    assert "no recorded configuration" not in captured.out


def test_check_of_a_cut_recording_says_the_message_counts_differ(tmp_path, capsys, fresh_logger):
    """``replay --check`` of a cut file said "DIFF ... largest difference 0" for topics whose
    counts differ: the count is the difference, and the line now says so."""
    from motionbase import cli
    from motionbase.app import CheckReport

    data = (RECORDING.parent / "c1723_planar_15s.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.4)])
    assert cli.main(["replay", str(cut), "--check"]) == 1
    lines = capsys.readouterr().out.splitlines()
    rows = [ln.split() for ln in lines[lines.index("check: DIFFERS from the recording") + 1 :]]
    counted = [r for r in rows if "recorded," in r]
    assert counted and all(r[0] == "DIFF" for r in counted)
    for r in counted:  # DIFF TOPIC N messages recorded, M replayed; the first N are identical
        recorded, replayed = int(r[2]), int(r[5])
        assert recorded != replayed and "difference" not in r
        assert r[7:] == ["the", "first", str(min(recorded, replayed)), "are", "identical"], r
    assert ["ok", "/aircraft/state"] == rows[0][:2]  # the cut's states are replayed as recorded

    report = CheckReport({"/a": (3, 5, 0.25), "/b": (0, 4, 0.0), "/c": (2, 2, 0.0)})
    assert report.lines()[1:] == [
        f"  DIFF {'/a':<22} 3 messages recorded, 5 replayed; the first 3 differ by up to 0.25",
        f"  DIFF {'/b':<22} 0 messages recorded, 4 replayed",
        f"  ok   {'/c':<22} messages 2 vs 2, largest difference 0",
    ]


def _with_camera(path: Path, states: bool = True) -> Path:
    """Aircraft states (JSON) and a camera's frames (protobuf), as a recording merged with
    another tool's is (made with the mcap library)."""
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        cid = writer.register_channel("/aircraft/state", "json", 0)
        image = writer.register_schema("foxglove.CompressedImage", "protobuf", b"\x0a\x00")
        camera = writer.register_channel("/camera", "protobuf", image)
        for k in range(1, 101):
            ns = k * 10_000_000
            if states:
                writer.add_message(cid, ns, json.dumps(_good_message(k / 100)).encode(), ns)
            if k % 10 == 0:
                writer.add_message(camera, ns, b"\x0a\x04jpeg", ns)
        writer.finish()
    return path


def test_a_report_leaves_out_another_tools_topic_that_is_not_json(tmp_path, caplog):
    """``report`` reads its own topics: a recording merged with a camera's protobuf frames
    was refused whole ("topic '/camera' is 'protobuf'-encoded"), and a file of the camera
    alone was refused for its encoding, not for having no aircraft state."""
    path = _with_camera(tmp_path / "merged.mcap")
    with pytest.raises(LogFormatError, match="'/camera' is 'protobuf'-encoded"):
        read_messages(path)  # replay --check: a topic it would not compare is refused
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        msgs = read_messages(path, require="/aircraft/state", json_only=False)
    assert set(msgs) == {"/aircraft/state"} and len(msgs["/aircraft/state"]) == 100
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "skipped 10 messages that are not JSON" in warned[0]
    assert "/camera: 'protobuf'-encoded" in warned[0]
    with pytest.raises(LogFormatError, match=r"no /aircraft/state messages.*present: /camera\)"):
        read_messages(
            _with_camera(tmp_path / "camera.mcap", states=False),
            require="/aircraft/state",
            json_only=False,
        )
    with pytest.raises(LogFormatError, match="'/camera' is 'protobuf'-encoded"):
        read_messages(path, require="/camera", json_only=False)  # the topic needed
