"""MCAP logger: every topic of the pipeline as JSON with a JSON Schema, through the Foxglove SDK.

The file is written by the Foxglove SDK's MCAP writer (``foxglove-sdk``, compiled;
chunks, compression, CRCs, message and summary indexes are its work): a standard
MCAP file that Foxglove and the ``mcap`` library read. It holds the Header, the
metadata record ``"motionbase"`` (``config``, ``version``, ``log_format``), then
chunks (each channel's Schema and Channel records in the chunk of its first
message), and the summary. Each logger has its own :class:`foxglove.Context`, so
several logs in one process never mix.

Live view
    With ``live=`` (``--live [HOST:]PORT``) a Foxglove WebSocket server serves the
    log's topics on a second context of its own, with the same channels. Each message
    is encoded once; the bytes go to the file always and to the server at most
    :data:`LIVE_RATE_HZ` (60) times per second of source time per topic (a screen's
    rate; the file keeps every tick): a topic's message goes live when its log time is
    on or past the topic's 60 Hz grid, so on a 1 kHz run about one tick in 17, on a
    120 Hz run every other tick, and every message of the slower topics
    (``/platform/scene`` at 30 Hz, ``/health``, the ``world -> base`` transform).
    The caller's thread only queues the bytes: a thread of the logger hands them to the
    server. (Handing them over on the caller's thread made it wait, now and then, for
    the server's own threads: on a busy machine a 1 kHz loop then overran its tick
    several times as often, see ``benchmarks/RESULTS.md``, issue 17.) The file does
    not depend on the live feed: the same input gives the same file, client or not.

Crash safety
    The writer compresses messages into the chunk in progress as they come. The
    logger finishes the chunk and hands it to the operating system as soon as it
    spans ``flush_interval_s`` of source time (1 s by default); the writer also
    finishes one when it grows past ``chunk_size`` bytes. A crash or ``kill -9``
    therefore loses at most the chunk in progress, about the last second. A file
    cut anywhere is read back up to its last complete chunk by
    :class:`~motionbase.io.mcap_source.McapSource` (an unfinished chunk on disk
    still has the writer's placeholder length, which the reader rejects).
    ``fsync=True`` also survives a power cut, at the cost of one ``fsync`` per
    chunk.

Exact numbers
    Messages are encoded here, with orjson: floats in their shortest round-trip
    form, so a reader gets back the very same doubles. JSON has no NaN or
    infinity: a message that holds one (a raw aircraft state that the pipeline
    rejects) writes it as the string ``"NaN"``, ``"Infinity"`` or
    ``"-Infinity"`` (see :mod:`motionbase.io.schemas`).

Where the time goes
    Everything runs on the caller's thread (but the live hand-over): encoding, the writer's ``log``
    (which holds the interpreter lock, so a writer thread would only add thread
    switches) and its compression, which works a block at a time: the message
    that fills a block (lz4: 64 KiB, zstd: 128 KiB) and the tick that finishes a
    chunk pay for compressing it. lz4 is the default because those stalls are
    about three times shorter than zstd's (about 80 us against 220 us per block
    here), for files about 1.7 times larger. zstd suits runs where the file's
    size matters more than a tick's worst case (``compression="zstd"``).
    ``benchmarks/RESULTS.md`` (issue 14) has the figures.
"""

from __future__ import annotations

import errno
import json
import logging
import math
import os
import queue
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import foxglove
import numpy as np
import orjson
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from motionbase.errors import ConfigError, SinkError
from motionbase.io.net_address import check_host_port
from motionbase.io.schemas import TOPIC_SCHEMAS
from motionbase.physics import quaternion_from_euler_zyx

log = logging.getLogger("motionbase")

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Name of the metadata record that holds the configuration.
METADATA_NAME = "motionbase"
#: Version of the message layout written in the metadata (key ``log_format``).
LOG_FORMAT = "1"

_COMPRESSIONS = {"lz4": MCAPCompression.Lz4, "zstd": MCAPCompression.Zstd, "none": None}
_MAX_NS = 2**64  # MCAP log times are u64 nanoseconds
_SEC = 1_000_000_000
_WORLD_TO_BASE = (1.0, 0.0, 0.0, 0.0)  # half a turn about x: FRD base in a z-up world
#: The most messages per second of source time a live client gets on one topic.
LIVE_RATE_HZ = 60.0
_LIVE_SLACK_NS = 1_000  # a tick 1 us before its grid point is on it (rounded tick times)
_FIRST = -(2**63)  # the live grid of a topic starts at its first message


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
    general path; :func:`encode_message` only takes it for messages that hold a
    non-finite number.
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


_SAFE_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False, check_circular=False)
_ORJSON_OPTIONS = orjson.OPT_SERIALIZE_NUMPY


def encode_message(message: Mapping[str, Any]) -> bytes:
    """JSON bytes of one message (floats exact, non-finite numbers as strings).

    orjson writes floats in their shortest round-trip form, like ``repr``. It
    writes NaN and infinities as ``null``; such messages (and any with a literal
    null or a numpy array orjson does not take, e.g. a strided one) go through
    :func:`json_safe` and the standard library instead.

    Raises
    ------
    TypeError
        A value JSON cannot hold (names its type).
    """
    try:
        data = orjson.dumps(message, default=_json_default, option=_ORJSON_OPTIONS)
    except TypeError:  # orjson.JSONEncodeError: non-contiguous array, odd dtype, ...
        data = b"null"
    if b"null" in data:
        return _SAFE_ENCODER.encode(json_safe(message)).encode()
    return data


def transform_message(
    ns: int, parent: str, child: str, x: float, y: float, z: float, q: Sequence[float]
) -> dict[str, Any]:
    """The ``foxglove.FrameTransform`` message at ``ns`` (a plain dict, fields in logged order)."""
    return {
        "timestamp": {"sec": ns // _SEC, "nsec": ns % _SEC},
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": x, "y": y, "z": z},
        "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }


#: Where ``--live`` listens when given a port only: this machine only.
LIVE_DEFAULT_HOST = "127.0.0.1"


@dataclass(frozen=True)
class LiveAddress:
    """Where the live Foxglove WebSocket server listens (``--live [HOST:]PORT``)."""

    host: str
    port: int

    @classmethod
    def parse(cls, text: str) -> LiveAddress:
        """``PORT`` or ``HOST:PORT`` (``[::1]:PORT`` for an IPv6 literal); host 127.0.0.1 by
        default, ``0.0.0.0`` to be watched from another PC; port 0 picks a free one.

        Raises
        ------
        ConfigError
            One line naming what is wrong (port not a number or out of range, a host
            that does not resolve).
        """
        host, sep, port = str(text).rpartition(":")
        if not sep:
            host = LIVE_DEFAULT_HOST
        host = host.removeprefix("[").removesuffix("]")
        return cls(*check_host_port(f"--live {text!r}", host, port, bind=True))

    def url(self, port: int | None = None) -> str:
        """``ws://host:port`` for Foxglove's "Open connection" dialog."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port if port is None else port}"

    def banner(self, port: int | None = None) -> str:
        """The line a job prints when its server is up: where to point Foxglove."""
        return f"live view: {self.url(port)} (Foxglove: Open connection > Foxglove WebSocket)"


def _serve_live(jobs: queue.SimpleQueue) -> None:
    """The live feed's thread: log each queued ``(channel, data, log_time)`` until ``None``."""
    while (job := jobs.get()) is not None:
        channel, data, ns = job
        try:
            channel.log(data, log_time=ns)
        except Exception as exc:  # noqa: BLE001 - the live view never stops the run
            log.warning("live view: %s", exc)


def _checked_topics(
    topics: Mapping[str, tuple[str, Mapping[str, Any]]],
) -> dict[str, tuple[str, Mapping[str, Any]]]:
    """``topics`` (topic -> (schema name, JSON Schema)) when each entry is one, else a
    ConfigError naming the entry."""
    for topic, entry in topics.items():
        ok = isinstance(topic, str) and topic.startswith("/") and isinstance(entry, tuple)
        ok = ok and len(entry) == 2 and isinstance(entry[0], str) and entry[0] != ""
        ok = ok and isinstance(entry[1], Mapping) and entry[1].get("type") == "object"
        if not ok:
            raise ConfigError(
                f"MCAP topic {topic!r}: expected '/name' -> (schema name, JSON Schema of an "
                f"object), got {entry!r:.80}"
            )
    return dict(topics)


def _channel(topic: str, name: str, schema: Any, context: foxglove.Context) -> foxglove.Channel:
    """A JSON channel of ``topic`` with its JSON Schema, on ``context``."""
    return foxglove.Channel(
        topic,
        schema=foxglove.Schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode()),
        message_encoding="json",
        context=context,
    )


class _LogFile:
    """The log's file as the writer sees it; keeps the first write error for the logger.

    After an error the file takes no more bytes but keeps counting positions, so
    the writer goes on as if they were written: it finishes without a cascade of
    errors (each of which it would print), the logger raises the one
    :class:`SinkError`, and the file stays as it was at the error, readable up to
    its last complete chunk.
    """

    def __init__(self, path: Path, fsync: bool) -> None:
        self._fh = open(path, "wb", buffering=0)  # noqa: SIM115 - closed by close()
        self._fsync = fsync
        self.error: OSError | None = None
        self._pos = self._end = 0  # positions after an error

    def write(self, data: bytes) -> int:
        if self.error is None:
            try:
                return self._fh.write(data)
            except OSError as exc:  # nothing of `data` was written
                self._failed(exc)
        self._pos += len(data)
        self._end = max(self._end, self._pos)
        return len(data)

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        if self.error is None:
            return self._fh.seek(offset, whence)
        self._pos = offset + (0, self._pos, self._end)[whence]
        return self._pos

    def flush(self) -> None:
        if self._fsync and self.error is None:
            try:
                os.fsync(self._fh.fileno())
            except OSError as exc:
                self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        self.error = exc
        self._pos = self._fh.tell()
        self._end = self._fh.seek(0, os.SEEK_END)

    def close(self) -> None:
        self._fh.close()  # unbuffered: nothing left to write


class McapLogger:
    """Write pipeline topics to an MCAP file through the Foxglove SDK's writer.

    Lifecycle: ``start()`` -> ``add(...)``/``add_many(...)``/``add_transform(...)``
    -> ``finish()``; or use it as a context manager (enter starts, exit finishes,
    also when an exception leaves the block)::

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
        Uncompressed size, bytes, past which the writer finishes a chunk.
    compression : {"lz4", "zstd", "none"}
        Chunk compression: lz4 (the shortest stalls, see the module's notes), or
        zstd at level 1 (files about 1.7 times smaller, as small as zstd's default
        level on these JSON chunks, and faster).
    flush_interval_s : float
        Source time, s, after which a chunk is finished and handed to the
        operating system even if small: the most a crash can lose.
    fsync : bool
        Also ``os.fsync`` after every chunk (survives power loss, costs time).
    live : LiveAddress, optional
        Also serve every topic live to Foxglove: a WebSocket server (the Foxglove SDK's)
        on a context of its own, started by ``start()`` before the file is created and
        stopped by ``finish()`` after the file is finished. A message is encoded once; it
        goes to the file, and to the clients subscribed to its topic at most
        ``live_rate_hz`` times per second of source time.
    live_rate_hz : float
        The live feed's most messages per second of source time per topic (default
        :data:`LIVE_RATE_HZ`, 60).
    topics : Mapping, optional
        More topics than :data:`~motionbase.io.schemas.TOPIC_SCHEMAS`: topic ->
        (schema name, JSON Schema of its messages), e.g. a cueing plug-in's
        diagnostics (:attr:`motionbase.washout.cueing.Cueing.diagnostics_schema`).
        A topic of ``TOPIC_SCHEMAS`` keeps its own schema.

    Raises
    ------
    SinkError
        The file cannot be created or written (names the file), a topic is
        unknown, or a time is negative, not finite or beyond MCAP's range.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        metadata: Mapping[str, Any] | None = None,
        *,
        chunk_size: int = 512 * 1024,
        compression: str = "lz4",
        flush_interval_s: float = 1.0,
        fsync: bool = False,
        live: LiveAddress | None = None,
        live_rate_hz: float = LIVE_RATE_HZ,
        topics: Mapping[str, tuple[str, Mapping[str, Any]]] | None = None,
    ) -> None:
        self.path = Path(path)
        self.live = live
        self.topics = {**_checked_topics(topics or {}), **TOPIC_SCHEMAS}
        self._server: Any = None
        if not (math.isfinite(live_rate_hz) and live_rate_hz > 0):
            raise ConfigError(f"live_rate_hz must be > 0, got {live_rate_hz!r}")
        self._live_period_ns = round(1e9 / live_rate_hz)
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
        self._flush_interval_ns = round(flush_interval_s * 1e9)
        self._file: _LogFile | None = None
        self._context: foxglove.Context | None = None
        self._writer: Any = None
        self._channels: dict[str, foxglove.Channel] = {}
        self._live_context: foxglove.Context | None = None
        # topic -> [live channel, log time (ns) from which its next message goes live]
        self._live: dict[str, list] | None = None
        self._live_queue: queue.SimpleQueue | None = None
        self._live_thread: threading.Thread | None = None
        self._state = "new"
        self._failure = ""
        self._message_count = 0
        self._chunk_start_ns = -1  # log time of the first message since the last flush
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
        # the channels only hold a weak reference to their context: keep it alive
        self._context = foxglove.Context()
        if self.live is not None:
            self._live_context = foxglove.Context()
            self._start_server(self.live)  # first: a port in use leaves no file behind
        try:
            self._file = _LogFile(self.path, self.fsync)
        except OSError as exc:
            self._stop_server()
            raise SinkError(
                f"{self.path}: cannot create the MCAP log: {exc.strerror or exc} "
                "(check the folder exists and is writable)"
            ) from None
        self._state = "open"
        try:
            self._open_writer(config_json)
        except BaseException:
            self._state = "failed"  # reported by this exception, not again by finish()
            self.finish()
            raise
        return self

    def _open_writer(self, config_json: str) -> None:
        from motionbase import __version__

        context = self._context
        options = MCAPWriteOptions(
            compression=_COMPRESSIONS[self.compression],
            chunk_size=self.chunk_size,
            compression_level=1 if self.compression == "zstd" else 0,
            # zstd's worker threads get a chunk's data only at its end (their jobs
            # are larger than a chunk) and the tick waits for them: a longer stall
            compression_threads=0,
        )
        self._writer = foxglove.open_mcap(self._file, context=context, writer_options=options)
        self._writer.write_metadata(
            METADATA_NAME,
            {"config": config_json, "version": __version__, "log_format": LOG_FORMAT},
        )
        for topic, (name, schema) in self.topics.items():
            self._channels[topic] = _channel(topic, name, schema, context)
        if self._live_context is not None:
            self._live = {
                topic: [_channel(topic, name, schema, self._live_context), _FIRST]
                for topic, (name, schema) in self.topics.items()
            }
            self._live_queue = queue.SimpleQueue()
            self._live_thread = threading.Thread(
                target=_serve_live, args=(self._live_queue,), name="motionbase-live", daemon=True
            )
            self._live_thread.start()
        self._flush()  # the header and the configuration on disk now

    def finish(self) -> None:
        """Finish the last chunk, write the summary and the footer, and close the file.

        Idempotent. After a write error the file keeps what it had (readable up
        to its last complete chunk); the error was raised by the call that met it.
        """
        if self._state in ("new", "finished"):
            self._state = "finished"
            return
        failed = self._state == "failed"
        writer, self._writer = self._writer, None
        file = self._file
        assert file is not None
        trouble = None
        try:
            if writer is not None:
                writer.close()
        except RuntimeError as exc:  # the SDK's FoxgloveError
            trouble = exc
        finally:
            for channel in self._channels.values():
                channel.close()
            if self._live_thread is not None:  # the queued messages go out first
                self._live_queue.put(None)
                self._live_thread.join()
                self._live_thread = None
            for channel, _ in (self._live or {}).values():
                channel.close()
            file.close()
            self._state = "finished"
            self._stop_server()
        if failed:
            return
        if file.error is not None:
            raise SinkError(self._failure_message(file.error))
        if trouble is not None:
            raise SinkError(f"{self.path}: cannot finish the MCAP log: {trouble}")

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

    def _start_server(self, live: LiveAddress) -> None:
        try:
            self._server = foxglove.start_server(
                name="motionbase", host=live.host, port=live.port, context=self._live_context
            )
        except RuntimeError as exc:  # the SDK's FoxgloveError: "Failed to bind port: ..."
            reason = str(exc).removeprefix("FoxgloveError: ")
            hint = (
                "another program uses that port: choose another"
                if "in use" in reason
                else "check the address"
            )
            raise ConfigError(
                f"--live {live.host}:{live.port}: cannot serve Foxglove there: {reason} ({hint})"
            ) from None

    def _stop_server(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.stop()

    @property
    def live_port(self) -> int | None:
        """The port the live server listens on (None without ``live``, or once finished)."""
        return None if self._server is None else int(self._server.port)

    @property
    def message_count(self) -> int:
        """Messages logged so far."""
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
            ``publish_time`` are ``round(t * 1e9)`` ns. Must be finite, >= 0
            and below 2**64 ns (about 584 years).
        message : Mapping
            The message fields (numpy arrays and scalars allowed). ``t`` is
            added when missing.
        """
        self.add_many(t, ((topic, message),))

    def add_many(self, t: float, items: Sequence[tuple[str, Mapping[str, Any]]]) -> None:
        """Log several messages of one time ``t`` (the pipeline's per-tick path).

        The same as calling :meth:`add` for each ``(topic, message)`` pair, with the
        per-call checks done once.
        """
        ns = self._ns(t)
        channels = self._channels
        live = self._live
        for topic, message in items:
            channel = channels.get(topic)
            if channel is None:
                self._unknown(topic)
            if "t" not in message:
                message = {"t": t, **message}
            data = encode_message(message)
            channel.log(data, log_time=ns)
            if live is not None:
                self._to_live(topic, data, ns)
        self._logged(ns, len(items))

    def add_encoded(self, topic: str, t: float, data: bytes) -> None:
        """Log one message already encoded (its JSON bytes, e.g.
        :meth:`motionbase.io.scene.SceneBuilder.encode`); otherwise as :meth:`add`."""
        ns = self._ns(t)
        channel = self._channels.get(topic)
        if channel is None:
            self._unknown(topic)
        channel.log(data, log_time=ns)
        if self._live is not None:
            self._to_live(topic, data, ns)
        self._logged(ns, 1)

    def _to_live(self, topic: str, data: bytes, ns: int, always: bool = False) -> None:
        """Hand ``data`` to the live server when ``topic`` is due (its 60 Hz grid)."""
        entry = self._live[topic]
        due = entry[1]
        if always or ns >= due - _LIVE_SLACK_NS:
            channel = entry[0]
            if channel.has_sinks():  # a client subscribed to the topic
                self._live_queue.put((channel, data, ns))
            if not always:
                nxt = due + self._live_period_ns
                entry[1] = nxt if ns < nxt - _LIVE_SLACK_NS else ns + self._live_period_ns

    def _unknown(self, topic: str) -> None:
        raise SinkError(f"unknown MCAP topic {topic!r}: known topics are {', '.join(self.topics)}")

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
        ns = self._ns(t)
        p = pose6.tolist() if isinstance(pose6, np.ndarray) else [float(v) for v in pose6]
        if len(p) != 6:
            raise SinkError(f"add_transform: pose must have 6 numbers, got {len(p)}")
        tf = self._channels["/tf"]
        count = 1
        if self._last_static_ns < 0 or ns - self._last_static_ns >= _SEC:
            self._last_static_ns = ns
            world = transform_message(ns, "world", "base", 0.0, 0.0, 0.0, _WORLD_TO_BASE)
            data = encode_message(world)
            tf.log(data, log_time=ns)
            if self._live is not None:  # once a second: every one goes live
                self._to_live("/tf", data, ns, always=True)
            count = 2
        q = quaternion_from_euler_zyx(p[3], p[4], p[5])
        msg = transform_message(ns, parent, child, p[0], p[1], p[2], q)
        data = encode_message(msg)
        tf.log(data, log_time=ns)
        if self._live is not None:
            self._to_live("/tf", data, ns)
        self._logged(ns, count)

    def flush(self) -> None:
        """Finish the chunk in progress and hand it to the OS now (e.g. before a risky step)."""
        if self._state == "open":
            self._flush()

    # ------------------------------------------------------------------ internals
    def _ns(self, t: float) -> int:
        """Log time of ``t`` s, ns; checks the logger is open and the time fits MCAP."""
        if self._state != "open":
            self._not_open()
        x = float(t) * 1e9
        if not 0.0 <= x < _MAX_NS:  # also NaN; a double below 2**64 rounds below it
            raise SinkError(
                f"{self.path}: message time must be finite and >= 0 s and below "
                f"{_MAX_NS / 1e9:.4g} s (MCAP log times are u64 ns), got {t!r}"
            )
        return round(x)

    def _not_open(self) -> None:
        if self._state == "new":
            raise SinkError(f"{self.path}: MCAP logger not started: call start() before add()")
        if self._state == "failed":
            raise SinkError(self._failure)
        raise SinkError(f"{self.path}: MCAP logger already finished")

    def _logged(self, ns: int, count: int) -> None:
        """Account ``count`` messages at ``ns``; finish the chunk when it spans the interval."""
        self._message_count += count
        if self._file.error is not None:
            self._fail(self._file.error)
        if self._chunk_start_ns < 0:
            self._chunk_start_ns = ns
        elif abs(ns - self._chunk_start_ns) >= self._flush_interval_ns:
            self._flush()

    def _flush(self) -> None:
        try:
            self._writer.flush()
        except RuntimeError as exc:  # the SDK's FoxgloveError, with no errno
            if self._file.error is None:
                self._failure = f"{self.path}: cannot write the MCAP log: {exc}"
                self._state = "failed"
                raise SinkError(self._failure) from None
        if self._file.error is not None:
            self._fail(self._file.error)
        self._chunk_start_ns = -1

    def _fail(self, exc: OSError) -> None:
        self._failure = self._failure_message(exc)
        self._state = "failed"
        raise SinkError(self._failure) from None

    def _failure_message(self, exc: OSError) -> str:
        hint = " (disk full?)" if exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT) else ""
        return (
            f"{self.path}: cannot write the MCAP log: {exc.strerror or exc}{hint}; "
            "the file is readable up to its last complete chunk"
        )


__all__ = [
    "LIVE_DEFAULT_HOST",
    "LIVE_RATE_HZ",
    "LOG_FORMAT",
    "LiveAddress",
    "MCAP_MAGIC",
    "METADATA_NAME",
    "McapLogger",
    "encode_message",
    "json_safe",
    "quaternion_from_euler_zyx",
    "transform_message",
]
