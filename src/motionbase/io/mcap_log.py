"""MCAP logger: every topic of the pipeline as JSON with a JSON Schema, crash-safe.

File layout (a standard MCAP file, readable by Foxglove and the ``mcap`` library)::

    magic, Header, Metadata "motionbase" {config, version, log_format},
    (Schema, Channel)* as topics first appear, Chunk, MessageIndex*, Chunk, ...,
    DataEnd, summary (schemas, channels, statistics, chunk and metadata indexes),
    Footer, magic

Crash safety
    Messages collect in one chunk in memory. The chunk is compressed, written
    and the file object flushed to the operating system as soon as it spans
    ``flush_interval_s`` of source time (1 s by default) or grows past
    ``chunk_size`` bytes (the writer thread does it within moments), so a
    crash or ``kill -9`` loses at most the chunk in progress (about the last
    second). Schema and channel records are written
    outside the chunks, before the first chunk that uses them. A file cut
    anywhere is read back up to its last complete chunk by
    :class:`~motionbase.io.mcap_source.McapSource`. ``fsync=True`` also survives
    a power cut, at the cost of one ``fsync`` per chunk.

Speed
    The per-message path (:meth:`McapLogger.add`) encodes with orjson when it
    is installed (about 10 times faster), else a prebuilt
    :class:`json.JSONEncoder`, and appends the MCAP message record to the chunk
    buffer with one precompiled :class:`struct.Struct`. The pipeline log's
    per-tick path (:meth:`McapLogger.add_deferred`) appends only the text of the
    tick's numbers (one orjson call) and a template id; the writer thread fills
    the template in. Everything else runs in the writer thread, in as few
    GIL-free calls as it can (each GIL hand-over to a busy pipeline loop costs
    thread switches): template filling, CRC-32 and message indexes (compiled),
    compression, one file write per chunk; the main thread hands its chunk
    buffer over without a copy. Floats are written in their shortest
    round-trip form (Python's ``repr``, orjson's Ryu), so a reader gets back the
    very same doubles.
"""

from __future__ import annotations

import errno
import json
import logging
import math
import os
import queue
import struct
import threading
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from motionbase.errors import ConfigError, SinkError
from motionbase.io._log_kernels import (
    DEFERRED,
    OP_LITERAL,
    chunk_summary,
    crc32_tables,
    expand_records,
)

try:  # optional speed-up: float formatting dominates the cost of a message
    import orjson as _orjson
except ImportError:  # pragma: no cover - depends on the environment
    _orjson = None
from motionbase.io.schemas import TOPIC_SCHEMAS

log = logging.getLogger("motionbase")

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Name of the metadata record that holds the configuration.
METADATA_NAME = "motionbase"
#: Version of the log layout written in the metadata (key ``log_format``).
LOG_FORMAT = "1"

# opcode, record length, channel id, sequence, log_time, publish_time
_MESSAGE_HEADER = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = 2 + 4 + 8 + 8
_COMPRESSIONS = ("zstd", "lz4", "none")
# Chunk record up to its compression name: opcode, length, start, end, size, CRC, name length
_CHUNK_HEADER = struct.Struct("<BQQQQII")
_U64 = struct.Struct("<Q")
_DEFERRED_HEADER = struct.Struct("<BQHQ")
_CRC_TABLES = crc32_tables()
_WARM = False


def _warm_up_kernels() -> None:
    """Load (or compile) the writer's compiled kernels once per process."""
    global _WARM
    if _WARM:
        return
    rec = np.frombuffer(
        _MESSAGE_HEADER.pack(0x05, _MESSAGE_FIXED + 2, 1, 0, 5, 5) + b"{}", np.uint8
    )
    ids, starts, counts = (np.empty(2, np.int64) for _ in range(3))
    chunk_summary(
        rec, _CRC_TABLES, 0, np.empty(64, np.uint8), ids, starts, counts, np.empty(2, np.int64)
    )
    ops = np.zeros((0, 3), np.int64)
    expand_records(
        rec,
        ops,
        np.zeros(2, np.int64),
        np.zeros(0, np.uint8),
        np.zeros(1, np.int64),
        np.empty(64, np.uint8),
    )
    _WARM = True


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple):
        return list(obj)
    raise TypeError(f"cannot write a {type(obj).__name__} to the log")


def json_safe(obj: Any) -> Any:
    """Plain JSON data with non-finite floats as ``"NaN"``, ``"Infinity"``, ``"-Infinity"``.

    Numpy arrays and scalars become lists and Python numbers. This is the slow,
    general path; the logger only takes it for messages that hold a non-finite
    number.
    """
    if isinstance(obj, float | np.floating):
        f = float(obj)
        if math.isfinite(f):
            return f
        return "NaN" if f != f else ("Infinity" if f > 0 else "-Infinity")
    if isinstance(obj, bool | str | int) or obj is None:
        return obj
    if isinstance(obj, np.ndarray):
        return [json_safe(v) for v in obj.tolist()]
    if isinstance(obj, np.generic):
        return json_safe(obj.item())
    if isinstance(obj, Mapping):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, Sequence):
        return [json_safe(v) for v in obj]
    raise TypeError(f"cannot write a {type(obj).__name__} to the log")


_FAST_ENCODER = json.JSONEncoder(
    separators=(",", ":"), allow_nan=False, check_circular=False, default=_json_default
)
_SAFE_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False, check_circular=False)


def encode_message_stdlib(message: Mapping[str, Any]) -> bytes:
    """JSON bytes of one message with the standard library (floats exact, non-finite as strings)."""
    try:
        return _FAST_ENCODER.encode(message).encode()
    except ValueError:  # a NaN or an infinity somewhere: the rare, slow path
        return _SAFE_ENCODER.encode(json_safe(message)).encode()


if _orjson is not None:
    _ORJSON_OPTIONS = _orjson.OPT_SERIALIZE_NUMPY

    def encode_message_orjson(message: Mapping[str, Any]) -> bytes:
        """JSON bytes of one message with orjson (about 10 times faster than the stdlib).

        orjson writes floats in their shortest round-trip form, like ``repr``.
        It writes NaN and infinities as ``null``; such messages (and any with
        a literal null or an unusual numpy array) go the stdlib way instead.
        """
        try:
            data = _orjson.dumps(message, default=_json_default, option=_ORJSON_OPTIONS)
        except TypeError:  # orjson.JSONEncodeError: non-contiguous array, odd dtype, ...
            return encode_message_stdlib(message)
        if b"null" in data:
            return encode_message_stdlib(message)
        return data

    encode_message = encode_message_orjson
    JSON_BACKEND = "orjson"
else:  # pragma: no cover - depends on the environment
    encode_message_orjson = None  # type: ignore[assignment]
    encode_message = encode_message_stdlib
    JSON_BACKEND = "json"


def quaternion_from_euler_zyx(roll: float, pitch: float, yaw: float) -> tuple[float, ...]:
    """Unit quaternion ``(x, y, z, w)`` of R = Rz(yaw) Ry(pitch) Rx(roll).

    Parameters
    ----------
    roll, pitch, yaw : float
        Z-Y-X Euler angles, rad.

    Returns
    -------
    tuple of 4 floats
        ``(x, y, z, w)``, the rotation that maps child-frame vectors to the
        parent frame, with ``w >= 0`` for small angles.
    """
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def transform_message(
    sec: Any, nsec: Any, parent: str, child: str, x: Any, y: Any, z: Any, q: Sequence[Any]
) -> dict[str, Any]:
    """The ``foxglove.FrameTransform`` message (a plain dict, fields in the logged order)."""
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": x, "y": y, "z": z},
        "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }


_TRANSFORM_FORMAT = (
    '{"timestamp":{"sec":%d,"nsec":%d},"parent_frame_id":"%s","child_frame_id":"%s",'
    '"translation":{"x":%r,"y":%r,"z":%r},"rotation":{"x":%r,"y":%r,"z":%r,"w":%r}}'
)


class McapLogger:
    """Write pipeline topics to an MCAP file, chunk by chunk.

    Lifecycle: ``start()`` -> ``add(...)``/``add_transform(...)`` -> ``finish()``;
    or use it as a context manager (enter starts, exit finishes, also when an
    exception leaves the block)::

        with McapLogger("flight.mcap", config) as logger:
            logger.add("/aircraft/state", t, {"specific_force": f, ...})

    Parameters
    ----------
    path : str or Path
        Output file; an existing file is replaced.
    metadata : Mapping
        The whole run configuration (geometry, washout parameters, source,
        rate, ...), plain data or numpy values. Written as one JSON string under
        key ``config`` of the metadata record ``"motionbase"``, together with
        ``version`` (motionbase's) and ``log_format``.
    chunk_size : int
        Uncompressed size, bytes, past which a chunk is written.
    compression : {"zstd", "lz4", "none"}
        Chunk compression.
    flush_interval_s : float
        Source time, s, after which a chunk is written even if small: the most
        a crash can lose.
    fsync : bool
        Also ``os.fsync`` after every chunk (survives power loss, costs time).
    background : bool
        Compress and write chunks in a writer thread (zstd and file writes
        release the GIL), so ``add`` never waits for the disk. A write error
        in that thread is raised by the next ``add`` or by ``finish``.

    Raises
    ------
    SinkError
        The file cannot be created or written (names the file), a topic is
        unknown, or a time is negative or not finite.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        metadata: Mapping[str, Any] | None = None,
        *,
        chunk_size: int = 512 * 1024,
        compression: str = "zstd",
        flush_interval_s: float = 1.0,
        fsync: bool = False,
        background: bool = True,
    ) -> None:
        self.path = Path(path)
        self.metadata: dict[str, Any] = dict(metadata or {})
        if compression not in _COMPRESSIONS:
            raise ConfigError(
                f"MCAP compression {compression!r} is unknown: choose one of "
                f"{', '.join(_COMPRESSIONS)}"
            )
        if not (isinstance(chunk_size, int) and chunk_size > 0):
            raise ConfigError(f"MCAP chunk_size must be a positive integer, got {chunk_size!r}")
        if not (math.isfinite(flush_interval_s) and flush_interval_s > 0):
            raise ConfigError(f"flush_interval_s must be > 0 s, got {flush_interval_s!r}")
        self.compression = compression
        self.chunk_size = chunk_size
        self.flush_interval_s = float(flush_interval_s)
        self.fsync = fsync
        self._compress = self._make_compressor(compression)
        self._flush_interval_ns = int(round(flush_interval_s * 1e9))
        self.background = bool(background)
        self._fh: IO[bytes] | None = None
        self._state = "new"
        self._queue: queue.SimpleQueue[Any] | None = None
        self._worker: threading.Thread | None = None
        self._failure = ""
        self._failure_reported = True
        self._pos = 0
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._channel_ids: dict[str, int] = {}
        self._metadata_indexes: list[MetadataIndex] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._channel_counts: dict[int, int] = {}
        self._message_count = 0
        self._start_ns = 0
        self._end_ns = 0
        # chunk in progress
        self._buf = bytearray()
        self._chunk_extra = 0  # bytes the deferred ticks of the chunk will grow by
        self._chunk_deferred = 0
        self._template_parts: list[tuple[np.ndarray, np.ndarray, int, int]] = []
        self._template_set: tuple[Any, ...] | None = None
        self._chunk_start_ns = 0
        self._chunk_end_ns = 0
        self._chunk_messages = 0
        self._last_static_ns = -1

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> McapLogger:
        """Create the file and write the header and the configuration metadata."""
        if self._state != "new":
            raise SinkError(f"{self.path}: MCAP logger already started")
        try:
            config_json = json.dumps(json_safe(self.metadata), allow_nan=False)
        except TypeError as exc:
            raise SinkError(f"{self.path}: configuration cannot be logged: {exc}") from None
        try:
            self._fh = open(self.path, "wb")  # noqa: SIM115 - closed in finish()
        except OSError as exc:
            raise SinkError(
                f"{self.path}: cannot create the MCAP log: {exc.strerror or exc} "
                "(check the folder exists and is writable)"
            ) from None
        self._state = "open"
        from motionbase import __version__

        rb = RecordBuilder()
        Header(profile="", library=f"motionbase {__version__}").write(rb)
        self._write(MCAP_MAGIC + rb.end())
        meta = Metadata(
            name=METADATA_NAME,
            metadata={"config": config_json, "version": __version__, "log_format": LOG_FORMAT},
        )
        meta.write(rb)
        data = rb.end()
        self._metadata_indexes.append(
            MetadataIndex(offset=self._pos, length=len(data), name=METADATA_NAME)
        )
        self._write(data)
        self._sync()
        _warm_up_kernels()  # now, not in the middle of the first chunk
        if self.background:
            self._queue = queue.SimpleQueue()
            self._worker = threading.Thread(
                target=self._work, name=f"mcap-writer {self.path.name}", daemon=True
            )
            self._worker.start()
        return self

    def finish(self) -> None:
        """Write the last chunk, the summary and the footer, and close the file.

        Idempotent. After a write error the file is only closed (it stays
        readable up to its last complete chunk) and the error is raised here if
        no earlier call reported it.
        """
        if self._state in ("new", "finished"):
            self._state = "finished"
            return
        if self._state == "open":
            self._flush_chunk()
        self._stop_worker()
        if self._state == "failed":
            self._close()
            self._state = "finished"
            if not self._failure_reported:
                self._failure_reported = True
                raise SinkError(self._failure)
            return
        try:
            rb = RecordBuilder()
            DataEnd(data_section_crc=0).write(rb)
            self._write(rb.end())
            self._write_summary_and_footer()
            self._sync()
        finally:
            self._close()
            self._state = "finished"

    def __enter__(self) -> McapLogger:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.finish()
            return
        try:
            self.finish()
        except SinkError as err:  # do not hide the exception that is propagating
            log.warning("%s", err)

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self._message_count

    # ------------------------------------------------------------------ messages
    def add(self, topic: str, t: float, message: Mapping[str, Any]) -> None:
        """Log one message.

        Parameters
        ----------
        topic : str
            One of :data:`~motionbase.io.schemas.TOPIC_SCHEMAS`.
        t : float
            Time of the sample, s, source clock; ``log_time`` and
            ``publish_time`` are ``round(t * 1e9)`` ns. Must be finite and >= 0.
        message : Mapping
            The message fields (numpy arrays and scalars allowed). ``t`` is
            added when missing.
        """
        if self._state != "open":
            self._not_open()
        cid = self._channel_ids.get(topic)
        if cid is None:
            cid = self._register(topic)
        if "t" not in message:
            message = {"t": t, **message}
        self._append(cid, self._ns(t), encode_message(message))

    def add_many(self, t: float, items: Sequence[tuple[str, Mapping[str, Any]]]) -> None:
        """Log several messages of one time ``t`` (the pipeline's per-tick path).

        The same as calling :meth:`add` for each ``(topic, message)`` pair, with the
        per-call checks done once.
        """
        if self._state != "open":
            self._not_open()
        ns = self._ns(t)
        ids = self._channel_ids
        append = self._append
        for topic, message in items:
            cid = ids.get(topic)
            if cid is None:
                cid = self._register(topic)
            if "t" not in message:
                message = {"t": t, **message}
            append(cid, ns, encode_message(message))

    def add_transform(
        self,
        t: float,
        pose6: Sequence[float] | np.ndarray,
        *,
        parent: str = "base",
        child: str = "platform",
    ) -> None:
        """Log the platform pose as a ``foxglove.FrameTransform`` on ``/tf``.

        The transform is the platform frame (``child``) in the base frame
        (``parent``): translation ``pose6[:3]`` m, rotation the quaternion of the
        Z-Y-X Euler angles ``pose6[3:]`` rad. Both frames are FRD (x forward,
        y right, z down) and Foxglove shows them as they are. So that the 3D
        panel shows the platform upright, a transform from Foxglove's z-up
        ``world`` frame to ``base`` (half a turn about x) is also written at the
        first call and then once per second of source time: pick ``world`` as
        the display frame.

        Parameters
        ----------
        t : float
            Time, s, source clock.
        pose6 : array_like, shape (6,)
            ``[x, y, z, roll, pitch, yaw]``, m and rad, base axes FRD.
        parent, child : str
            Frame names.
        """
        if self._state != "open":
            self._not_open()
        ns = self._ns(t)
        cid = self._channel_ids.get("/tf")
        if cid is None:
            cid = self._register("/tf")
        if self.static_transform_due(ns):
            self._append(
                cid,
                ns,
                self._transform_bytes(ns, "world", "base", 0.0, 0.0, 0.0, (1.0, 0.0, 0.0, 0.0)),
            )
        p = pose6.tolist() if isinstance(pose6, np.ndarray) else [float(v) for v in pose6]
        if len(p) != 6:
            raise SinkError(f"add_transform: pose must have 6 numbers, got {len(p)}")
        q = quaternion_from_euler_zyx(p[3], p[4], p[5])
        self._append(cid, ns, self._transform_bytes(ns, parent, child, p[0], p[1], p[2], q))

    def channel_id(self, topic: str) -> int:
        """The channel id of ``topic`` (registered now if it is new)."""
        cid = self._channel_ids.get(topic)
        return cid if cid is not None else self._register(topic)

    def static_transform_due(self, ns: int) -> bool:
        """True (and noted) when the ``world`` -> ``base`` transform is due at ``ns``."""
        if self._last_static_ns < 0 or ns - self._last_static_ns >= 1_000_000_000:
            self._last_static_ns = ns
            return True
        return False

    def register_template(
        self, ops: np.ndarray, pool: np.ndarray, n_tokens: int, n_messages: int
    ) -> int:
        """Register a tick template for :meth:`add_deferred`; returns its id.

        ``ops`` (rows ``(op, a, b)``, see ``_log_kernels``; channel ids from
        :meth:`channel_id`) and ``pool`` (its literal bytes) describe the Message
        records of one tick with ``n_tokens`` values in ``n_messages`` messages.
        """
        self._template_parts.append((ops, pool, n_tokens, n_messages))
        ops_all, pools, bounds, tokens = [], [], [0], []
        base = 0
        widest = 0
        for o, pl, nt, nm in self._template_parts:
            o = o.copy()
            o[o[:, 0] == OP_LITERAL, 1] += base
            ops_all.append(o)
            pools.append(pl)
            base += len(pl)
            bounds.append(bounds[-1] + len(o))
            tokens.append(nt)
            widest = max(widest, len(pl) + 31 * nm + 40)
        self._template_set = (
            np.ascontiguousarray(np.concatenate(ops_all)),
            np.array(bounds, dtype=np.int64),
            np.ascontiguousarray(np.concatenate(pools)),
            np.array(tokens, dtype=np.int64),
            widest,
        )
        return len(self._template_parts) - 1

    def add_deferred(self, ns: int, template: int, values: bytes, count: int) -> None:
        """Append one tick whose ``count`` records the writer thread fills from a template.

        Parameters
        ----------
        ns : int
            Log time of every record, ns (``>= 0``).
        template : int
            A :meth:`register_template` id.
        values : bytes
            JSON text of the tick's values (no ``null``; as many tokens as the
            template takes): the records are the template with these tokens in.
        count : int
            Messages the template writes.
        """
        if self._state != "open":
            self._not_open()
        buf = self._buf
        buf += _DEFERRED_HEADER.pack(DEFERRED, 10 + len(values), template, ns)
        buf += values
        self._chunk_deferred += 1
        self._chunk_extra += self._template_set[4]
        self._added(ns, count)

    def flush(self) -> None:
        """Write the chunk in progress now (e.g. before a risky operation or on E-stop)."""
        if self._state == "open":
            self._flush_chunk()

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _transform_bytes(
        ns: int, parent: str, child: str, x: float, y: float, z: float, q: Sequence[float]
    ) -> bytes:
        if _orjson is None and math.isfinite(x + y + z + q[0] + q[1] + q[2] + q[3]):
            sec, nsec = divmod(ns, 1_000_000_000)
            return (
                _TRANSFORM_FORMAT % (sec, nsec, parent, child, x, y, z, q[0], q[1], q[2], q[3])
            ).encode()
        sec, nsec = divmod(ns, 1_000_000_000)
        return encode_message(transform_message(sec, nsec, parent, child, x, y, z, q))

    def _ns(self, t: float) -> int:
        t = float(t)
        if not (t >= 0.0 and math.isfinite(t)):
            raise SinkError(f"{self.path}: message time must be finite and >= 0 s, got {t!r}")
        return round(t * 1e9)

    def _not_open(self) -> None:
        if self._state == "new":
            raise SinkError(f"{self.path}: MCAP logger not started: call start() before add()")
        if self._state == "failed":
            self._failure_reported = True
            raise SinkError(self._failure or f"{self.path}: MCAP log stopped after a write error")
        raise SinkError(f"{self.path}: MCAP logger already finished")

    def _register(self, topic: str) -> int:
        try:
            schema_name, schema = TOPIC_SCHEMAS[topic]
        except KeyError:
            raise SinkError(
                f"unknown MCAP topic {topic!r}: known topics are {', '.join(TOPIC_SCHEMAS)}"
            ) from None
        schema_rec = Schema(
            id=len(self._schemas) + 1,
            name=schema_name,
            encoding="jsonschema",
            data=json.dumps(schema).encode(),
        )
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding="json",
            metadata={},
            schema_id=schema_rec.id,
        )
        rb = RecordBuilder()
        schema_rec.write(rb)
        channel.write(rb)
        self._submit(rb.end())
        self._schemas.append(schema_rec)
        self._channels.append(channel)
        self._channel_ids[topic] = channel.id
        self._channel_counts[channel.id] = 0
        return channel.id

    def _append(self, cid: int, ns: int, data: bytes) -> None:
        # the message indexes and counts are built from the records by the writer thread
        buf = self._buf
        buf += _MESSAGE_HEADER.pack(0x05, _MESSAGE_FIXED + len(data), cid, 0, ns, ns)
        buf += data
        self._added(ns, 1)

    def _added(self, ns: int, count: int) -> None:
        """Account ``count`` messages at ``ns`` to the chunk; write it when full or old."""
        if self._chunk_messages:
            if ns < self._chunk_start_ns:
                self._chunk_start_ns = ns
            elif ns > self._chunk_end_ns:
                self._chunk_end_ns = ns
        else:
            self._chunk_start_ns = self._chunk_end_ns = ns
        self._chunk_messages += count
        if (
            len(self._buf) + self._chunk_extra >= self.chunk_size
            or ns - self._chunk_start_ns >= self._flush_interval_ns
        ):
            self._flush_chunk()

    def _flush_chunk(self) -> None:
        if not self._chunk_messages:
            return
        # hand the buffer itself over (no copy): the writer thread owns it from now on
        deferred = (self._template_set, self._chunk_deferred) if self._chunk_deferred else None
        self._submit((self._buf, self._chunk_start_ns, self._chunk_end_ns, deferred))
        if self._message_count:
            self._start_ns = min(self._start_ns, self._chunk_start_ns)
            self._end_ns = max(self._end_ns, self._chunk_end_ns)
        else:
            self._start_ns, self._end_ns = self._chunk_start_ns, self._chunk_end_ns
        self._message_count += self._chunk_messages
        self._buf = bytearray()
        self._chunk_messages = 0
        self._chunk_deferred = 0
        self._chunk_extra = 0

    # Everything below `_submit` runs in the writer thread (or inline when
    # background=False): compression, file writes, flushes.
    def _submit(self, item: bytes | tuple[bytearray, int, int, Any]) -> None:
        if self._queue is not None:
            self._queue.put(item)
        else:
            self._do(item)

    def _work(self) -> None:
        assert self._queue is not None
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                self._do(item)
            except SinkError as err:  # reported by the next add() or by finish()
                self._failure_reported = False
                log.debug("MCAP writer thread stopped: %s", err)
                return

    def _stop_worker(self) -> None:
        if self._queue is not None and self._worker is not None:
            self._queue.put(None)
            self._worker.join()
        self._queue = None
        self._worker = None

    def _do(self, item: bytes | tuple[bytearray, int, int, Any]) -> None:
        if isinstance(item, bytes):
            self._write(item)
        else:
            self._write_chunk(*item)

    def _write_chunk(
        self, records: bytearray, start_ns: int, end_ns: int, deferred: Any = None
    ) -> None:
        # Runs in the writer thread beside the busy pipeline loop: every GIL hand-over
        # costs both threads two switches, so the work is a few GIL-free calls
        # (deferred ticks filled in; compression; CRC and message indexes, compiled;
        # one file write) with little Python between them.
        rec = np.frombuffer(records, np.uint8)
        if deferred is not None:
            (ops, bounds, pool, tokens, widest), count = deferred
            # tokens may be used twice (the /tf translation): 2x the values text
            out = np.empty(2 * len(rec) + widest * count, np.uint8)
            n = expand_records(rec, ops, bounds, pool, tokens, out)
            if n < 0:  # a bug, not a disk problem: say where
                self._failure = (
                    f"{self.path}: deferred tick at byte {-1 - n} of a chunk does not fit "
                    "its template (motionbase bug); the file is readable up to here"
                )
                self._failure_reported = True
                self._state = "failed"
                raise SinkError(self._failure)
            rec = out[:n]
            records = rec
        compressed = self._compress(records)
        compression = "" if self.compression == "none" else self.compression
        name = compression.encode()
        # Chunk record: opcode, length, start and end time, uncompressed size and CRC,
        # compression (string), records (u64-prefixed bytes); the CRC is filled below
        head_len = 8 + 8 + 8 + 4 + 4 + len(name) + 8
        chunk_len = 9 + head_len + len(compressed)
        chunk_start = self._pos
        index_start = chunk_start + chunk_len
        room = len(self._channels) + 1
        out = np.empty(len(records) + 15 * room, np.uint8)
        ids = np.empty(room, np.int64)
        starts = np.empty(room, np.int64)
        counts = np.empty(room, np.int64)
        nch, length, _, crc = chunk_summary(
            rec, _CRC_TABLES, index_start, out, ids, starts, counts, np.empty(2, np.int64)
        )
        head = _CHUNK_HEADER.pack(
            Opcode.CHUNK,
            head_len + len(compressed),
            start_ns,
            end_ns,
            len(records),
            crc,
            len(name),
        )
        data = b"".join((head, name, _U64.pack(len(compressed)), compressed, out[:length]))
        offsets = dict(zip(ids[:nch].tolist(), starts[:nch].tolist(), strict=True))
        for cid, count in zip(ids[:nch].tolist(), counts[:nch].tolist(), strict=True):
            self._channel_counts[cid] += count
        self._write(data)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=start_ns,
                message_end_time=end_ns,
                chunk_start_offset=chunk_start,
                chunk_length=chunk_len,
                message_index_offsets=offsets,
                message_index_length=length,
                compression=compression,
                compressed_size=len(compressed),
                uncompressed_size=len(records),
            )
        )
        self._sync()

    def _write_summary_and_footer(self) -> None:
        summary_start = self._pos
        sb = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records: Sequence[Any]) -> None:
            if not records:
                return
            start = sb.count
            for rec in records:
                rec.write(sb)
            offsets.append(
                SummaryOffset(
                    group_opcode=opcode,
                    group_start=summary_start + start,
                    group_length=sb.count - start,
                )
            )

        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        stats = Statistics(
            attachment_count=0,
            channel_count=len(self._channels),
            channel_message_counts=dict(self._channel_counts),
            chunk_count=len(self._chunk_indexes),
            message_count=self._message_count,
            message_end_time=self._end_ns,
            message_start_time=self._start_ns,
            metadata_count=len(self._metadata_indexes),
            schema_count=len(self._schemas),
        )
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + sb.count
        for off in offsets:
            off.write(sb)
        summary = sb.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(
            struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc
        )
        rb = RecordBuilder()
        Footer(
            summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc
        ).write(rb)
        self._write(summary + rb.end() + MCAP_MAGIC)

    def _write(self, data: bytes) -> None:
        assert self._fh is not None
        try:
            self._fh.write(data)
        except OSError as exc:
            self._fail(exc)
        self._pos += len(data)

    def _sync(self) -> None:
        assert self._fh is not None
        try:
            self._fh.flush()
            if self.fsync:
                os.fsync(self._fh.fileno())
        except OSError as exc:
            self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        hint = " (disk full?)" if getattr(exc, "errno", None) in (errno.ENOSPC, errno.EFBIG) else ""
        self._failure = (
            f"{self.path}: cannot write the MCAP log: {exc.strerror or exc}{hint}; "
            "the file is readable up to its last complete chunk"
        )
        self._failure_reported = True
        self._state = "failed"
        raise SinkError(self._failure) from None

    def _close(self) -> None:
        fh, self._fh = self._fh, None
        if fh is None:
            return
        try:
            fh.close()
        except OSError:  # buffered bytes that cannot be written: already reported
            pass

    @staticmethod
    def _make_compressor(name: str) -> Any:
        if name == "zstd":
            import zstandard

            # level 1: about twice as fast as 3 and, on these JSON chunks, no larger
            return zstandard.ZstdCompressor(level=1).compress
        if name == "lz4":
            try:
                import lz4.frame
            except ImportError:
                raise ConfigError(
                    "MCAP compression 'lz4' needs the lz4 package (pip install lz4) "
                    "or choose 'zstd'"
                ) from None
            return lz4.frame.compress
        return bytes


__all__ = [
    "JSON_BACKEND",
    "McapLogger",
    "encode_message",
    "encode_message_stdlib",
    "json_safe",
    "quaternion_from_euler_zyx",
]
