"""MCAP logger: every topic of the pipeline as JSON with a JSON Schema, through the Foxglove SDK.

The file is written by the Foxglove SDK's MCAP writer (``foxglove-sdk``, compiled;
chunks, compression, CRCs, message and summary indexes are its work): a standard
MCAP file that Foxglove and the ``mcap`` library read. It holds the Header, the
metadata record ``"motionbase"`` (``config``, ``version``, ``log_format``), then
chunks (each channel's Schema and Channel records in the chunk of its first
message), and the summary.

The writer runs in a process of its own
    :class:`McapLogger` encodes the messages of one call (orjson, on the caller's thread)
    as one JSON array, or takes a pipeline tick packed as bytes (:meth:`McapLogger.add_tick`),
    and writes it to a pipe; a writer process (:mod:`motionbase.io.log_writer`, started by
    ``start()`` and ended by ``finish()``) splits it, or makes the tick's messages, and logs
    the messages with the SDK. The SDK compresses
    and writes on the thread that calls it, holding the interpreter lock: in the
    pipeline's process that work (about 80 us for each 64 KiB lz4 block, and every
    wait for the disk) fell on the real-time tick, now and then, and set its 99th
    percentile; in a process of its own it runs on the other core. The caller writes
    its records to the pipe once they reach 16 KiB (a few ticks) or span 0.1 s of
    source time, and at ``flush()`` and ``finish()``. A write error, or the writer's
    end, is raised as a :class:`SinkError` by the next call that writes to the pipe (or
    by ``finish()``).

Never waiting for the writer (real-time runs)
    With ``realtime=True`` a call never waits for the writer process: what the pipe does
    not take now (a writer stopped, or held up by a disk that does not answer, once the
    pipe's 1 MiB is full) waits in memory for the next call. A backlog past
    :data:`BACKLOG_BYTES` (8 MiB: tens of seconds of a run) is a :class:`SinkError`, as a
    full disk is (the pipeline parks), and ``finish()`` then waits a few seconds at most
    for the writer, which finishes the file on its own once it runs again. A writer that
    stops before the backlog grows that long (at the end of the run, say) is waited for
    by ``finish()`` as long as it takes more of the log, and a :class:`SinkError` once it
    took nothing for ``_FAILED_WRITER_WAIT_S`` (5 s): the run, parked, then ends (it used
    to wait for it forever). Without it (runs as fast as they go) a call waits for the
    pipe, so the writer's pace sets the run's; a writer that takes nothing for 5 s is
    then a :class:`SinkError` too (a run whose writer stopped waited for it forever, deaf
    to Ctrl-C and SIGTERM). Only the start waits for the writer as long as it takes (the
    writer's own start-up: a Python process and its imports).

Live view
    With ``live=`` (``--live [HOST:]PORT``) the writer process also serves the log's
    topics on a Foxglove WebSocket server, with the same channels on a context of its
    own. Each message is encoded once; the bytes go to the file always and to the
    server at most :data:`LIVE_RATE_HZ` (60) times per second of source time per topic
    (a screen's rate; the file keeps every tick): a topic's message goes live when its
    log time is on or past the topic's 60 Hz grid, so on a 1 kHz run about one tick in
    17, on a 120 Hz run every other tick, and every message of the slower topics
    (``/platform/scene`` at 30 Hz, ``/health``, the ``world -> base`` transform), and
    only to topics a client subscribed to. The file does not depend on the live feed:
    the same input gives the same file, client or not.

Crash safety
    The writer compresses messages into the chunk in progress as they come. It
    finishes the chunk and hands it to the operating system as soon as it spans
    ``flush_interval_s`` of source time (1 s by default), or grows past
    ``chunk_size`` bytes. A crash or ``kill -9`` of the pipeline's process loses only
    the records it had not yet written to the pipe (at most 16 KiB, 0.1 s): the writer
    process reads to the end of its input and finishes the file. A kill of both (or of
    the writer) loses at most the chunk in progress, about the last second. A file cut
    anywhere is read back up to its last complete chunk by
    :class:`~motionbase.io.mcap_source.McapSource` (an unfinished chunk on disk still
    has the writer's placeholder length, which the reader rejects).

Exact numbers
    Messages are encoded here, with orjson: floats in their shortest round-trip
    form, so a reader gets back the very same doubles (the writer process decodes the
    batch and encodes each message again with orjson: the same numbers). JSON has no NaN or
    infinity: a message that holds one (a raw aircraft state that the pipeline
    rejects) writes it as the string ``"NaN"``, ``"Infinity"`` or
    ``"-Infinity"`` (see :mod:`motionbase.io.schemas`).

Compression
    lz4 by default; ``compression="zstd"`` gives files about 1.7 times smaller for
    about three times the writer's work (which is no longer the tick's).
    ``benchmarks/RESULTS.md`` (issue 14) has the figures.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import math
import os
import select
import struct
import subprocess
import sys
import termios
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import orjson
from numpy.typing import ArrayLike

from motionbase.errors import ConfigError, SinkError
from motionbase.io import log_writer
from motionbase.io.log_writer import (
    FLAG_POSE,
    FLAG_SCENE,
    OP_BATCH,
    OP_CLOSE,
    OP_FLUSH,
    OP_START,
    OP_TICK,
)
from motionbase.io.net_address import check_host_port
from motionbase.io.schemas import TOPIC_SCHEMAS
from motionbase.tick_record import json_float

log = logging.getLogger("motionbase")

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Name of the metadata record that holds the configuration.
METADATA_NAME = "motionbase"
#: Version of the message layout written in the metadata (key ``log_format``). "2": ``/tf``
#: places the ``platform`` frame at the platform (its origin at neutral plus the pose);
#: "1" wrote the pose's displacement alone as the translation.
LOG_FORMAT = "2"

_COMPRESSIONS = ("lz4", "zstd", "none")
_HEADER = log_writer.HEADER
#: pending records are written to the writer process once they are this long (a few ticks)
_SEND_BYTES = 16 * 1024
_SEND_NS = 100_000_000  # ... or once they span 0.1 s of source time
_PIPE_BYTES = 1 << 20  # the writer process's pipe: about 3 s of a 1 kHz log with its scene
_MAX_NS = 2**64  # MCAP log times are u64 nanoseconds
#: real-time runs: the most bytes of records the writer process may leave in this process
#: (the pipe full) before the log counts as failed
BACKLOG_BYTES = 8 << 20
#: finish() after such a failure (the writer may be stopped), and the longest any call
#: after the start waits for a writer process that takes nothing more, s
_FAILED_WRITER_WAIT_S = 5.0
_Items = Sequence[tuple[str, Mapping[str, Any]]]  # (topic, message) pairs
#: The most messages per second of source time a live client gets on one topic.
LIVE_RATE_HZ = 60.0


def _json_default(obj: Any) -> Any:
    """What orjson does not write itself: a strided array or an odd numpy scalar."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot write a {type(obj).__name__} to the log")


def json_safe(obj: Any) -> Any:
    """Plain JSON data with non-finite floats as ``"NaN"``, ``"Infinity"``, ``"-Infinity"``.

    Numpy arrays and scalars become lists and Python numbers. This is the slow,
    general path; :func:`encode_message` only takes it for messages that hold a
    non-finite number.
    """
    if isinstance(obj, float | np.floating):
        return json_float(float(obj))
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


def encode_message(message: Any) -> bytes:
    """JSON bytes of one message, or of a list of them (floats exact, non-finite numbers as
    strings).

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
        data = orjson.dumps(message, default=_json_default, option=orjson.OPT_SERIALIZE_NUMPY)
    except TypeError:  # orjson.JSONEncodeError: non-contiguous array, odd dtype, ...
        data = b"null"
    if b"null" in data:
        return _SAFE_ENCODER.encode(json_safe(message)).encode()
    return data


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
        return cls(*check_host_port(f"--live {text!r}", host, port, free_port=True))

    def url(self, port: int | None = None) -> str:
        """``ws://host:port`` for Foxglove's "Open connection" dialog."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port if port is None else port}"

    def banner(self, port: int | None = None) -> str:
        """The line a job prints when its server is up: where to point Foxglove."""
        return f"live view: {self.url(port)} (Foxglove: Open connection > Foxglove WebSocket)"


class McapLogger:
    """Write pipeline topics to an MCAP file through the Foxglove SDK's writer, which runs
    in a process of its own (see the module's notes).

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
        Chunk compression: lz4 (the least work for the writer process), or
        zstd at level 1 (files about 1.7 times smaller, as small as zstd's default
        level on these JSON chunks, and faster).
    flush_interval_s : float
        Source time, s, after which a chunk is finished and handed to the
        operating system even if small: the most a crash can lose.
    live : LiveAddress, optional
        Also serve every topic live to Foxglove: a WebSocket server (the Foxglove SDK's)
        in the writer process, on a context of its own, started by ``start()`` before the
        file is created and stopped by ``finish()`` after the file is finished. A message
        is encoded once; it goes to the file, and to the clients subscribed to its topic at most
        ``live_rate_hz`` times per second of source time.
    live_rate_hz : float
        The live feed's most messages per second of source time per topic (default
        :data:`LIVE_RATE_HZ`, 60).
    realtime : bool
        A real-time run: no call waits for the writer process (see the module's notes);
        a backlog past :data:`BACKLOG_BYTES` is a :class:`SinkError`. Default False: a call
        waits while the pipe is full.
    topics : Mapping, optional
        More topics than :data:`~motionbase.io.schemas.TOPIC_SCHEMAS`: topic ->
        (schema name, JSON Schema of its messages), e.g. a cueing plug-in's
        diagnostics (:attr:`motionbase.washout.cueing.Cueing.diagnostics_schema`).
        A topic of ``TOPIC_SCHEMAS`` keeps its own schema, unless given one of the same
        name (a robot plug-in's platform topics, sized to it:
        :func:`~motionbase.io.schemas.platform_topics`).
    platform_origin : array_like, shape (3,), optional
        The platform frame's origin (the centroid of the platform joints) in the base frame
        at the neutral pose, m (the robot geometry's ``platform_origin``): ``/tf`` places
        the ``platform`` frame there plus the pose's displacement. Default zeros.

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
        live: LiveAddress | None = None,
        live_rate_hz: float = LIVE_RATE_HZ,
        realtime: bool = False,
        topics: Mapping[str, tuple[str, Mapping[str, Any]]] | None = None,
        platform_origin: ArrayLike | None = None,
    ) -> None:
        self.path = Path(path)
        self.live = live
        self.realtime = bool(realtime)
        origin = np.zeros(3) if platform_origin is None else np.asarray(platform_origin, float)
        if origin.shape != (3,) or not np.isfinite(origin).all():
            raise ConfigError(f"platform_origin must be 3 finite numbers (m), got {origin}")
        #: the platform frame's origin in the base frame at the neutral pose, m (``/tf``)
        self.platform_origin = tuple(float(v) for v in origin)
        self.topics = {**(topics or {}), **TOPIC_SCHEMAS}
        for topic, entry in (topics or {}).items():  # topic -> (schema name, JSON Schema)
            ok = isinstance(topic, str) and topic.startswith("/") and isinstance(entry, tuple)
            ok = ok and len(entry) == 2 and isinstance(entry[0], str) and entry[0] != ""
            ok = ok and isinstance(entry[1], Mapping) and entry[1].get("type") == "object"
            if not ok:
                raise ConfigError(
                    f"MCAP topic {topic!r}: expected '/name' -> (schema name, JSON Schema of an "
                    f"object), got {entry!r:.80}"
                )
            if topic in TOPIC_SCHEMAS and entry[0] == TOPIC_SCHEMAS[topic][0]:
                self.topics[topic] = entry  # the same message, sized to a robot
        self._index = {topic: i for i, topic in enumerate(self.topics)}
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
        self._process: subprocess.Popen | None = None
        self._data_fd = -1  # the pipe to the writer process
        self._reply: Any = None  # its answers, one JSON line each
        self._port: int | None = None
        self._state = "new"
        self._failure = ""
        self._pending = bytearray()  # records not yet written to the writer process
        self._pending_ns = -1  # log time of the first of them
        #: how long a wait on the writer process may go without progress, s (None: as long
        #: as it takes, until it answered the start)
        self._patience: float | None = None
        self._stalled = False  # the writer took nothing within the patience

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> McapLogger:
        """Start the writer process: it creates the file and writes the header and the
        configuration metadata (on disk when this returns)."""
        if self._state != "new":
            raise SinkError(f"{self.path}: MCAP logger already started")
        from motionbase import __version__

        try:
            config_json = json.dumps(json_safe(self.metadata), allow_nan=False)
        except TypeError as exc:
            raise SinkError(f"{self.path}: configuration cannot be logged: {exc}") from None
        config = {
            "path": str(self.path),
            "file": os.path.abspath(self.path),
            "compression": self.compression,
            "chunk_size": self.chunk_size,
            "flush_interval_ns": round(self.flush_interval_s * 1e9),
            "metadata_name": METADATA_NAME,
            "metadata": {"config": config_json, "version": __version__, "log_format": LOG_FORMAT},
            "topics": [[topic, name, schema] for topic, (name, schema) in self.topics.items()],
            "live": None if self.live is None else [self.live.host, self.live.port],
            "live_period_ns": self._live_period_ns,
            "platform_origin": list(self.platform_origin),
        }
        self._spawn()
        self._state = "open"
        try:
            self._port = self._request(OP_START, json.dumps(config).encode()).get("port")
            self._patience = _FAILED_WRITER_WAIT_S  # from now on, never wait forever
        except BaseException:
            self._state = "failed"  # reported by this exception, not again by finish()
            self.finish()
            raise
        return self

    def _spawn(self) -> None:
        """Start the writer process, its data and reply pipes (the front keeps one end each)."""
        data_r, data_w = os.pipe()
        reply_r, reply_w = os.pipe()
        with contextlib.suppress(OSError):  # room for a few seconds of a 1 kHz log
            fcntl.fcntl(data_w, fcntl.F_SETPIPE_SZ, _PIPE_BYTES)
        try:
            self._process = subprocess.Popen(
                [sys.executable, "-P", log_writer.__file__, str(data_r), str(reply_w)],
                pass_fds=(data_r, reply_w),
                stdin=subprocess.DEVNULL,
                start_new_session=True,  # the terminal's signals go to the pipeline only
            )
        except OSError as exc:
            os.close(data_w)
            os.close(reply_r)
            raise SinkError(
                f"{self.path}: cannot start the MCAP log's writer process: {exc.strerror or exc}"
            ) from None
        finally:
            os.close(data_r)
            os.close(reply_w)
        os.set_blocking(data_w, False)  # _send waits for it only when it must
        self._data_fd = data_w
        self._reply = os.fdopen(reply_r, "rb")

    def finish(self) -> None:
        """Finish the last chunk, write the summary and the footer, and close the file.

        Idempotent. After a write error the file keeps what it had (readable up
        to its last complete chunk); the error was raised by the call that met it.
        """
        if self._state in ("new", "finished"):
            self._state = "finished"
            return
        try:
            if self._state != "failed":
                self._request(OP_CLOSE)
        finally:  # (open or failed: start() made the writer process and its pipes)
            failed, self._state = self._state == "failed", "finished"
            os.close(self._data_fd)  # the writer ends at the end of its input
            self._data_fd = -1
            # a writer stopped or stuck (after a failure) finishes the file on its own
            wait = 0.0 if self._stalled else _FAILED_WRITER_WAIT_S if failed else None
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._process.wait(timeout=wait)
            self._reply.close()

    def __enter__(self) -> McapLogger:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        try:
            self.finish()
        except SinkError as err:
            if exc_type is None:
                raise
            log.warning("%s", err)  # do not hide the exception that is propagating

    @property
    def live_port(self) -> int | None:
        """The port the live server listens on (None without ``live``, or once finished)."""
        return self._port if self._state == "open" else None

    @property
    def writer_pid(self) -> int | None:
        """The process id of the writer process (None before ``start()``)."""
        return None if self._process is None else self._process.pid

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

    def add_many(self, t: float, items: _Items, transform: ArrayLike | None = None) -> None:
        """Log several messages of one time ``t`` (the pipeline's per-tick path), and the
        platform pose ``transform`` on ``/tf`` when given.

        The same as calling :meth:`add` for each ``(topic, message)`` pair and
        :meth:`add_transform`, with the per-call checks done once and one encoding: the
        messages go to the writer process as one JSON array, which it splits.
        """
        batch = []  # (topic index, flags, message)
        for topic, message in items:
            i = self._index.get(topic)
            if i is None:
                self._unknown(topic)
            batch.append((i, 0, message if "t" in message else {"t": t, **message}))
        if transform is not None:  # the writer process makes the FrameTransforms
            p = np.asarray(transform, dtype=float).tolist()
            if len(p) != 6 or not math.isfinite(sum(p)):
                raise SinkError(f"add_transform: pose must be 6 finite numbers, got {p}")
            batch.append((self._index["/tf"], FLAG_POSE, p))
        self._queue_batch(t, batch)

    def add_scene(self, t: float, parts: list[Any]) -> None:
        """Log the ``/platform/scene`` message made of ``parts``
        (:meth:`motionbase.io.scene.SceneBuilder.parts`): the writer process builds it
        (:func:`motionbase.scene_update.scene_message`) and encodes it, off the caller's
        thread; otherwise as :meth:`add`."""
        self._queue_batch(t, [(self._index["/platform/scene"], FLAG_SCENE, parts)])

    def add_tick(self, t: float, record: bytes) -> None:
        """Log one pipeline tick packed by :func:`motionbase.tick_record.pack`: the writer
        process makes its messages (:func:`motionbase.tick_record.messages`) and the
        platform's ``/tf``, off the caller's thread; otherwise as :meth:`add_many`."""
        self._queue(OP_TICK, self._ns(t), record)

    def _queue_batch(self, t: float, batch: list[tuple[int, int, Any]]) -> None:
        """Queue one batch record (``[topic index, flags, message]`` entries of time ``t``,
        s) for the writer process."""
        self._queue(OP_BATCH, self._ns(t), encode_message(batch))

    def _queue(self, op: int, ns: int, data: bytes) -> None:
        """Queue one record for the writer process."""
        self._pending += _HEADER.pack(op, len(data), ns)
        self._pending += data
        # written to the writer process once they reach 16 KiB or span 0.1 s of source time
        if self._pending_ns < 0:
            self._pending_ns = ns
        if len(self._pending) >= _SEND_BYTES or abs(ns - self._pending_ns) >= _SEND_NS:
            self._send()

    def _unknown(self, topic: str) -> None:
        raise SinkError(f"unknown MCAP topic {topic!r}: known topics are {', '.join(self.topics)}")

    def add_transform(self, t: float, pose6: Sequence[float] | np.ndarray) -> None:
        """Log the platform pose as a ``foxglove.FrameTransform`` on ``/tf``.

        The transform is the ``platform`` frame in the ``base`` frame: translation
        ``platform_origin + pose6[:3]`` m (the pose is the displacement from the neutral pose,
        whose platform frame origin, the centroid of the platform joints, is
        ``platform_origin``: ``(0, 0, -neutral_height)`` on the 6-DOF robots), rotation the
        quaternion of the Z-Y-X Euler angles ``pose6[3:]`` rad. Both frames are FRD (x
        forward, y right, z down) and Foxglove shows them as they are. So that the 3D panel
        shows the platform upright, a transform from Foxglove's z-up ``world`` frame to
        ``base`` (half a turn about x) is also written at the first call and then once per
        second of source time: pick ``world`` as the
        display frame. (The writer process builds these messages from the pose.)

        Parameters
        ----------
        t : float
            Time, s, source clock.
        pose6 : array_like, shape (6,)
            ``[x, y, z, roll, pitch, yaw]``, m and rad, base axes FRD; finite.

        Raises
        ------
        SinkError
            Not six finite numbers (or a time :meth:`add` refuses).
        """
        self.add_many(t, (), pose6)

    def flush(self) -> None:
        """Finish the chunk in progress and hand it to the OS now (e.g. before a risky
        step); returns when the writer process has."""
        if self._state == "open":
            self._request(OP_FLUSH)

    # ------------------------------------------------------------------ internals
    def _ns(self, t: float) -> int:
        """Log time of ``t`` s, ns; checks the logger is open and the time fits MCAP."""
        if self._state != "open":
            if self._state == "new":
                raise SinkError(f"{self.path}: MCAP logger not started: call start() before add()")
            if self._state == "failed":
                raise SinkError(self._failure)
            raise SinkError(f"{self.path}: MCAP logger already finished")
        x = float(t) * 1e9
        if not 0.0 <= x < _MAX_NS:  # also NaN; a double below 2**64 rounds below it
            raise SinkError(
                f"{self.path}: message time must be finite and >= 0 s and below "
                f"{_MAX_NS / 1e9:.4g} s (MCAP log times are u64 ns), got {t!r}"
            )
        return round(x)

    def _request(self, op: int, payload: bytes = b"") -> dict[str, Any]:
        """Send a control record (after the records pending); the writer process's answer."""
        self._pending += _HEADER.pack(op, len(payload), 0) + payload
        self._send(wait=True)
        return self._answer()

    def _send(self, wait: bool = False) -> None:
        """Write the pending records to the writer process: all of them (a signal can cut a
        write short), or in a real-time run, unless ``wait``, what the pipe takes now (the
        rest stays pending; past :data:`BACKLOG_BYTES` the log fails)."""
        wait = wait or not self.realtime
        self._pending_ns = -1
        sent, stalled = 0, False
        try:
            with memoryview(self._pending) as view:
                while sent < len(view):
                    try:
                        sent += os.write(self._data_fd, view[sent:])
                    except BlockingIOError:  # the pipe is full
                        if not wait:
                            break
                        if not select.select((), (self._data_fd,), (), self._patience)[1]:
                            stalled = True  # (cleared once the view is released)
                            break
        except BrokenPipeError:  # the writer failed and closed its end: its answer says why
            self._pending.clear()
            self._answer()
            raise SinkError(f"{self.path}: the MCAP log's writer process stopped") from None
        if stalled:
            self._pending.clear()
            self._writer_stalled()
        del self._pending[:sent]
        if len(self._pending) > BACKLOG_BYTES:
            self._pending.clear()
            self._failed(
                SinkError,
                f"{self.path}: the MCAP log's writer process does not keep up with the run "
                f"(its pipe full and {BACKLOG_BYTES / 2**20:g} MiB more of the log waiting: "
                "the process is stopped, or its disk does not answer); the log ends there",
            )

    def _answer(self) -> dict[str, Any]:
        """The writer process's next answer; a failure it reports raises, as does its end."""
        if self._patience is not None:
            self._await_answer(self._patience)
        line = self._reply.readline()
        if not line:
            status = self._process.wait()
            self._failed(
                SinkError,
                f"{self.path}: the MCAP log's writer process ended unexpectedly (status "
                f"{status}); the file is readable up to its last complete chunk",
            )
        answer = json.loads(line)
        if "error" in answer:
            self._failed(ConfigError if answer["kind"] == "config" else SinkError, answer["error"])
        return answer

    def _await_answer(self, patience: float) -> None:
        """Wait for the writer process's answer while it takes records from its pipe (a
        writer at a lower priority on a busy machine may take seconds to empty it); raise
        once it took nothing for ``patience`` s."""
        left, since = self._in_pipe(), time.monotonic()
        while not select.select((self._reply,), (), (), 0.1)[0]:
            now = self._in_pipe()
            if now < left:
                left, since = now, time.monotonic()
            elif time.monotonic() - since > patience:
                self._writer_stalled()

    def _in_pipe(self) -> int:
        """Bytes the writer process has not yet read from its pipe."""
        return struct.unpack("i", fcntl.ioctl(self._data_fd, termios.FIONREAD, b"\0\0\0\0"))[0]

    def _writer_stalled(self) -> None:
        self._stalled = True
        self._failed(
            SinkError,
            f"{self.path}: the MCAP log's writer process took nothing more for "
            f"{self._patience:g} s (it is stopped, or its disk does not answer); the file is "
            "readable up to its last complete chunk (the writer finishes it if it runs again)",
        )

    def _failed(self, kind: type[Exception], message: str) -> None:
        self._failure = message
        self._state = "failed"
        raise kind(message) from None


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
]
