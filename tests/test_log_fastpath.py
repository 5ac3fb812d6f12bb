"""The pipeline log's fast path writes what its general path writes, byte for byte.

:class:`PipelineLog` encodes a tick's messages from a template (one orjson call for
all the numbers, a compiled fill); ticks with a NaN or an infinity take the general
path (one encoder call per message). Both paths write the same outputs here; the
messages read back (topic, log time, JSON bytes) must be identical. The MCAP
message indexes, now built from the chunk's records in the writer thread, are
checked against the records themselves, and ``AircraftState.from_vector`` against
the constructor.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk, MessageIndex
from mcap.stream_reader import StreamReader

from motionbase.app import load_config
from motionbase.io.pipeline_log import PipelineLog
from motionbase.pipeline import Pipeline
from motionbase.state import AircraftState

G = 9.80665


def _outputs(planar: bool, n: int = 900) -> list:
    """Real pipeline outputs: strong and calm stretches, NaN samples, no angular
    acceleration on some, stale marks, then the park ramp (state None)."""
    rng = np.random.default_rng(3)
    pipeline = Pipeline(load_config(planar=planar, rate_hz=120.0))
    outs = []
    for k in range(1, n):
        s = 2.0 if (k // 150) % 2 else 0.2
        f = rng.normal(size=3) * 20 * s + (0.0, 0.0, -G)
        w = rng.normal(size=3) * 2 * s
        att = rng.uniform(-3, 3, 3)
        if k % 101 == 7:
            f[1] = math.nan  # rejected, logged as text by the general path
        if k % 131 == 9:
            w[2] = math.inf
        acc = None if k % 3 == 0 else rng.normal(size=3)
        state = AircraftState(k / 120.0, f, w, att, angular_acceleration=acc)
        outs.append(pipeline.step(state, fresh=(k // 40) % 9 != 4))
    pipeline.stop()
    while not pipeline.parked and len(outs) < n + 600:
        outs.append(pipeline.step(None))
    return outs


def _write(path: Path, outs: list, fast: bool, planar: bool | None = None) -> None:
    health = {"samples": 0}
    log = PipelineLog(path, {"kind": "test"}, health=lambda: dict(health), planar=planar)
    if not fast:
        log._write_fast = lambda logger, out, t: False
    with log:
        for out in outs:
            health["samples"] += 1
            log.write(out)


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        return [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]


@pytest.mark.parametrize("prepared", [False, True], ids=["lazy", "prepared"])
@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_fast_path_writes_the_general_paths_bytes(tmp_path, planar, prepared):
    # prepared: every kind of tick's template built when the log starts (``planar=``)
    outs = _outputs(planar)
    assert any(o.state is not None and not o.accepted for o in outs)
    _write(tmp_path / "general.mcap", outs, fast=False)
    _write(tmp_path / "fast.mcap", outs, fast=True, planar=planar if prepared else None)
    general = _messages(tmp_path / "general.mcap")
    fast = _messages(tmp_path / "fast.mcap")
    assert len(fast) == len(general)
    for k, (a, b) in enumerate(zip(general, fast, strict=True)):
        assert a == b, (k, a, b)
    topics = {t for t, _, _ in fast}
    if planar:
        assert "/planar/actuators" in topics and "/tf" not in topics
    else:
        assert {"/aircraft/state", "/platform/actuators", "/tf", "/health"} <= topics
    # the NaN samples went the general way: their non-finite values as strings
    texts = [d for t, _, d in fast if t == "/aircraft/state"]
    assert any(b'"NaN"' in d for d in texts) and any(b'"Infinity"' in d for d in texts)


def test_message_indexes_point_at_their_messages(tmp_path):
    outs = _outputs(False, n=400)
    _write(tmp_path / "x.mcap", outs, fast=True)
    with open(tmp_path / "x.mcap", "rb") as fh:
        records = list(StreamReader(fh, skip_magic=False, emit_chunks=True).records)
    chunks = 0
    total = 0
    for i, rec in enumerate(records):
        if not isinstance(rec, Chunk):
            continue
        chunks += 1
        data = zstandard.ZstdDecompressor().decompress(
            rec.data, max_output_size=rec.uncompressed_size
        )
        # the chunk's Message records, parsed here independently: opcode, length, body
        per_channel: dict[int, list[tuple[int, int]]] = {}
        pos = 0
        while pos < len(data):
            opcode, length = struct.unpack_from("<BQ", data, pos)
            assert opcode == 0x05
            channel, _seq, log_time = struct.unpack_from("<HIQ", data, pos + 9)
            per_channel.setdefault(channel, []).append((log_time, pos))
            pos += 9 + length
        # the index records follow their chunk, one per channel present in it
        indexes = []
        for nxt in records[i + 1 :]:
            if not isinstance(nxt, MessageIndex):
                break
            indexes.append(nxt)
        assert [ix.channel_id for ix in indexes] == list(per_channel)
        for ix in indexes:
            assert ix.records == per_channel[ix.channel_id]
            total += len(ix.records)
    assert chunks >= 3
    assert total == len(_messages(tmp_path / "x.mcap"))


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
