"""McapSource and read_messages: replays, truncated files, files that are not MCAP."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from motionbase.errors import LogFormatError, SourceError
from motionbase.io.mcap_log import McapLogger
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
