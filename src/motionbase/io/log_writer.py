"""The MCAP log's writer process: the Foxglove SDK's writer, off the pipeline's process.

:class:`~motionbase.io.mcap_log.McapLogger` starts this file as a script of its own
(``python -P log_writer.py DATA_FD REPLY_FD``; it imports the standard library, ``orjson``,
``foxglove``, :mod:`motionbase.quaternions`, :mod:`motionbase.scene_update` and
:mod:`motionbase.tick_record` only, so it starts in about 40 ms) and sends it messages
through a pipe; this process logs them with the SDK and, with a live view, serves them to
Foxglove.

Why a process: the SDK's ``Channel.log`` compresses and writes on the thread that calls
it, holding the interpreter lock (a 64 KiB lz4 block costs about 80 us, a chunk's write
waits for the disk), so a thread would not take that work off the real-time loop; a
process does, on the other core. The pipeline's tick packs its numbers into one record
(:mod:`motionbase.tick_record`) and writes it to the pipe; this process makes the tick's
messages from it and encodes them. Other messages come as one JSON array a call, which
this process splits.

Protocol (one machine, one version: this file and ``mcap_log.py`` change together):

* front -> writer, on the data pipe: records of a :data:`HEADER` (op, payload length, log
  time in ns) and a payload. The first is :data:`OP_START` with the configuration as JSON;
  then :data:`OP_BATCH` (a JSON array of ``[topic index, flags, message]``, the index in
  the configuration's ``topics``, all of the header's log time: each message is
  encoded again on its own, orjson both ways, so its numbers are the very same; with
  :data:`FLAG_POSE` the message is a platform pose ``[x, y, z, roll, pitch, yaw]`` (m,
  rad) that this process logs as ``foxglove.FrameTransform`` messages, :meth:`Writer.log_pose`;
  with :data:`FLAG_SCENE` it is the arguments of
  :func:`motionbase.scene_update.scene_message`, the ``/platform/scene`` message it builds),
  :data:`OP_TICK` (one pipeline tick packed by :func:`motionbase.tick_record.pack`, whose
  messages and platform transform this process makes with
  :func:`motionbase.tick_record.messages`), :data:`OP_FLUSH` and :data:`OP_CLOSE`.
* writer -> front, on the reply pipe: one JSON line per answer: ``{"ok": true, ...}`` to
  the start, a flush and the close; ``{"error": "...", "kind": "config" | "sink"}`` when
  something fails. After a failure the writer closes the data pipe (the front's next
  write fails at once and reads the line), finishes what the file has, and exits.
* End of input without :data:`OP_CLOSE` (the front died, even by ``kill -9``): the writer
  finishes the file as a close would. It runs in a session of its own and ignores the
  stop signals: the terminal's Ctrl-C stops the pipeline, whose close ends the log.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import signal
import struct
import sys
import threading
from typing import Any, BinaryIO

import orjson

from motionbase.quaternions import quaternion_from_euler_zyx
from motionbase.scene_update import scene_message, timestamp
from motionbase.tick_record import messages as tick_messages

#: a record's header: op (u8), payload length (u32), log time (u64, ns)
HEADER = struct.Struct("<BIQ")
OP_START, OP_BATCH, OP_FLUSH, OP_CLOSE, OP_TICK = 1, 2, 3, 4, 5
#: a message's flag: it goes live whatever the topic's live grid says
FLAG_ALWAYS_LIVE = 1
#: OP_BATCH flag: the message is a platform pose, to log as transforms (Writer.log_pose)
FLAG_POSE = 2
FLAG_SCENE = 4
_SEC = 1_000_000_000
_WORLD_TO_BASE = (1.0, 0.0, 0.0, 0.0)  # half a turn about x: FRD base in a z-up world
_FIRST = -(2**63)  # the live grid of a topic starts at its first message
_LIVE_SLACK_NS = 1_000  # a tick 1 us before its grid point is on it (rounded tick times)
_STOP_WAIT_S = 1.0  # the server's stop waits for a client that stopped reading: this long


class LogFile:
    """The log's file as the writer sees it; keeps the first write error.

    After an error the file takes no more bytes but keeps counting positions, so
    the SDK's writer goes on as if they were written: it finishes without a cascade
    of errors, the front raises the one error, and the file stays as it was at the
    error, readable up to its last complete chunk.
    """

    def __init__(self, path: str) -> None:
        # O_NONBLOCK: a FIFO with no reader fails at once (ENXIO) instead of waiting for one
        flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NONBLOCK | os.O_CLOEXEC
        fd = os.open(path, flags, 0o666)
        try:
            os.lseek(fd, 0, os.SEEK_CUR)  # the writer seeks back to finish each chunk
            os.set_blocking(fd, True)
        except BaseException:
            os.close(fd)
            raise
        self._fh = open(fd, "wb", buffering=0)  # noqa: SIM115 - closed by close()
        self.error: OSError | None = None
        self._pos = self._end = 0  # positions after an error

    def write(self, data: bytes) -> int:
        if self.error is None:
            try:
                return self._fh.write(data)
            except OSError as exc:  # nothing of `data` was written: count on from here
                self.error = exc
                self._pos = self._fh.tell()
                self._end = self._fh.seek(0, os.SEEK_END)
        self._pos += len(data)
        self._end = max(self._end, self._pos)
        return len(data)

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        if self.error is None:
            return self._fh.seek(offset, whence)
        self._pos = offset + (0, self._pos, self._end)[whence]
        return self._pos

    def flush(self) -> None:
        """Nothing to do: the file is unbuffered (the SDK's writer calls it as it flushes)."""

    def close(self) -> None:
        self._fh.close()  # unbuffered: nothing left to write


class WriterFailed(Exception):
    """What to tell the front: ``kind`` is ``"config"`` (the user's setting) or ``"sink"``."""

    def __init__(self, message: str, kind: str = "sink") -> None:
        super().__init__(message)
        self.kind = kind


def write_failure(path: str, exc: OSError) -> str:
    """The one line for a write error of the file at ``path``."""
    hint = " (disk full?)" if exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT) else ""
    return (
        f"{path}: cannot write the MCAP log: {exc.strerror or exc}{hint}; "
        "the file is readable up to its last complete chunk"
    )


def transform_message(
    ns: int, parent: str, child: str, x: float, y: float, z: float, q: tuple[float, ...]
) -> dict[str, Any]:
    """The ``foxglove.FrameTransform`` message at ``ns`` (a plain dict, fields in logged order)."""
    return {
        "timestamp": timestamp(ns),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": x, "y": y, "z": z},
        "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }


class Writer:
    """The SDK's MCAP writer (and live server) for one log, as configured by the front.

    ``config`` keys: ``path`` (as the user named it, for messages), ``file`` (the same,
    absolute), ``compression`` (``"lz4"``, ``"zstd"``, ``"none"``),
    ``chunk_size`` (bytes), ``flush_interval_ns``, ``metadata_name`` and
    ``metadata`` (the metadata record's name and string fields), ``topics`` (``[topic,
    schema name, JSON Schema]`` in index order), ``live`` (``[host, port]`` or null),
    ``live_period_ns``, and optionally ``platform_origin`` (``[x, y, z]``, m: the platform
    frame's origin in the base frame at the neutral pose; zeros when absent).
    """

    def __init__(self, config: dict[str, Any]) -> None:
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self._foxglove = foxglove
        self.path = config["path"]
        self._flush_interval_ns = int(config["flush_interval_ns"])
        self._chunk_start_ns = -1  # log time of the first message since the last flush
        self._world_ns = -1  # log time of the last world -> base transform
        # the platform frame's origin (the centroid of its joints) in the base frame at the
        # neutral pose, m: a pose is the displacement from there (DESIGN.md)
        self._origin = config.get("platform_origin") or (0.0, 0.0, 0.0)
        self._context = foxglove.Context()  # channels hold only a weak reference to it
        self._server: Any = None
        self._live: list[list] | None = None  # per topic: [live channel or None, due ns, topic]
        self._live_period_ns = int(config["live_period_ns"])
        topics = config["topics"]
        if config["live"] is not None:
            host, port = config["live"]
            self._live_context = foxglove.Context()  # kept alive, as the file's
            self._start_server(host, int(port), self._live_context)  # first: no file left
            self._live = [[None, _FIRST, t] for t in topics]  # advertised at its first message
        try:
            self._file = LogFile(config["file"])
        except OSError as exc:
            self.stop_server()
            if exc.errno in (errno.ENXIO, errno.ESPIPE):  # a FIFO, a socket, a terminal
                raise WriterFailed(
                    f"{self.path}: cannot write the MCAP log there: it is not a file the log "
                    "can seek in (a FIFO, a socket or a terminal); give a file path",
                    "config",
                ) from None
            raise WriterFailed(
                f"{self.path}: cannot create the MCAP log: {exc.strerror or exc} "
                "(check the folder exists and is writable)"
            ) from None
        compression = {"lz4": MCAPCompression.Lz4, "zstd": MCAPCompression.Zstd}
        options = MCAPWriteOptions(
            compression=compression.get(config["compression"]),
            chunk_size=int(config["chunk_size"]),
            compression_level=1 if config["compression"] == "zstd" else 0,
            compression_threads=0,  # this process is the log's worker already
        )
        self._writer = foxglove.open_mcap(self._file, context=self._context, writer_options=options)
        self._writer.write_metadata(config["metadata_name"], config["metadata"])
        self._channels = [self._channel(t, n, s, self._context) for t, n, s in topics]
        self._index = {t: i for i, (t, _, _) in enumerate(topics)}
        self.flush()  # the header and the configuration on disk now

    def _channel(self, topic: str, name: str, schema: Any, context: Any) -> Any:
        """A JSON channel of ``topic`` with its JSON Schema, on ``context``."""
        return self._foxglove.Channel(
            topic,
            schema=self._foxglove.Schema(
                name=name, encoding="jsonschema", data=json.dumps(schema).encode()
            ),
            message_encoding="json",
            context=context,
        )

    def _start_server(self, host: str, port: int, context: Any) -> None:
        try:
            self._server = self._foxglove.start_server(
                name="motionbase", host=host, port=port, context=context
            )
        except RuntimeError as exc:  # the SDK's FoxgloveError: "Failed to bind port: ..."
            reason = str(exc).removeprefix("FoxgloveError: ")
            hint = "check the address"
            if "in use" in reason:
                hint = "another program uses that port: choose another"
            raise WriterFailed(
                f"--live {host}:{port}: cannot serve Foxglove there: {reason} ({hint})", "config"
            ) from None

    @property
    def live_port(self) -> int | None:
        return None if self._server is None else int(self._server.port)

    def stop_server(self) -> None:
        server, self._server = self._server, None
        if server is not None:  # a client that reads nothing holds stop() until it leaves:
            stop = threading.Thread(target=server.stop, daemon=True)  # the exit drops it
            stop.start()
            stop.join(_STOP_WAIT_S)

    def log(self, index: int, data: bytes, ns: int, flags: int) -> None:
        """Log one message; finish the chunk when it spans the flush interval."""
        self._channels[index].log(data, log_time=ns)
        if self._live is not None:
            self._to_live(index, data, ns, bool(flags & FLAG_ALWAYS_LIVE))
        if self._file.error is not None:
            raise WriterFailed(write_failure(self.path, self._file.error))
        if self._chunk_start_ns < 0:
            self._chunk_start_ns = ns
        elif abs(ns - self._chunk_start_ns) >= self._flush_interval_ns:
            self.flush()

    def log_pose(self, index: int, pose: list[float], ns: int) -> None:
        """Log the platform pose ``[x, y, z, roll, pitch, yaw]`` (m, rad, FRD base axes) on
        topic ``index`` as the ``platform`` frame in the ``base`` frame (translation: the
        platform origin at neutral plus the pose's displacement; rotation: the quaternion of
        the Z-Y-X Euler angles), after the transform from Foxglove's z-up
        ``world`` frame to ``base`` (half a turn about x) at the first pose and then once per
        second of log time (each of those goes live)."""
        if self._world_ns < 0 or ns - self._world_ns >= _SEC:
            self._world_ns = ns
            world = transform_message(ns, "world", "base", 0.0, 0.0, 0.0, _WORLD_TO_BASE)
            self.log(index, orjson.dumps(world), ns, FLAG_ALWAYS_LIVE)
        x, y, z, roll, pitch, yaw = pose
        ox, oy, oz = self._origin
        q = quaternion_from_euler_zyx(roll, pitch, yaw)
        tf = transform_message(ns, "base", "platform", ox + x, oy + y, oz + z, q)
        self.log(index, orjson.dumps(tf), ns, 0)

    def log_tick(self, record: bytes, ns: int) -> None:
        """Log one pipeline tick packed by :func:`motionbase.tick_record.pack`: its messages,
        then the platform pose on ``/tf`` (6-DOF robots)."""
        index = self._index
        items, pose = tick_messages(record)
        for topic, message in items:
            self.log(index[topic], orjson.dumps(message), ns, 0)
        if pose is not None:
            self.log_pose(index["/tf"], pose, ns)

    def _to_live(self, index: int, data: bytes, ns: int, always: bool) -> None:
        """Serve ``data`` when its topic is due on its grid (at most one message per
        ``live_period_ns`` of source time) and a client subscribed to it. A topic is
        advertised with its first message, as the file gets its channel: a run advertises
        only the topics it writes (it advertised every topic, a planar run the 6-DOF ones)."""
        entry = self._live[index]
        if entry[0] is None:
            entry[0] = self._channel(*entry[2], self._live_context)
        due = entry[1]
        if always or ns >= due - _LIVE_SLACK_NS:
            channel = entry[0]
            if channel.has_sinks():
                channel.log(data, log_time=ns)
            if not always:
                nxt = due + self._live_period_ns
                entry[1] = nxt if ns < nxt - _LIVE_SLACK_NS else ns + self._live_period_ns

    def flush(self) -> None:
        """Finish the chunk in progress and hand it to the operating system."""
        try:
            self._writer.flush()
        except RuntimeError as exc:  # the SDK's FoxgloveError, with no errno
            if self._file.error is None:
                raise WriterFailed(f"{self.path}: cannot write the MCAP log: {exc}") from None
        if self._file.error is not None:
            raise WriterFailed(write_failure(self.path, self._file.error))
        self._chunk_start_ns = -1

    def close(self) -> str | None:
        """Finish the file (summary, footer) and stop the server; the failure, if any."""
        trouble = None
        try:
            self._writer.close()
        except RuntimeError as exc:  # the SDK's FoxgloveError
            trouble = f"{self.path}: cannot finish the MCAP log: {exc}"
        finally:
            for channel in self._channels:
                channel.close()
            for channel, *_ in self._live or ():
                if channel is not None:
                    channel.close()
            self._file.close()
            self.stop_server()
        if self._file.error is not None:
            return write_failure(self.path, self._file.error)
        return trouble


def _read_record(data: BinaryIO) -> tuple[int, int, bytes] | None:
    """The next record, or None at the end of input (a record cut short counts as the end)."""
    head = data.read(HEADER.size)
    if len(head) < HEADER.size:
        return None
    op, size, ns = HEADER.unpack(head)
    payload = data.read(size) if size else b""
    if len(payload) < size:
        return None
    return op, ns, payload


def serve(data_fd: int, reply_fd: int) -> int:
    """Run one log: the start record, the messages, the close (or the end of input)."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT):
        signal.signal(sig, signal.SIG_IGN)  # the front's close ends the log, not a signal
    os.nice(10)  # the real-time loop first when both want a core (the pipe holds seconds)
    data = os.fdopen(data_fd, "rb", buffering=1 << 20)
    reply = os.fdopen(reply_fd, "wb", buffering=0)

    def answer(**fields: Any) -> None:
        with contextlib.suppress(OSError):  # the front is gone: nobody to tell
            reply.write(json.dumps(fields).encode() + b"\n")

    record = _read_record(data)
    if record is None or record[0] != OP_START:
        return 1
    config = json.loads(record[2])
    try:
        writer = Writer(config)
    except WriterFailed as exc:
        answer(error=str(exc), kind=exc.kind)
        return 1
    except Exception as exc:  # noqa: BLE001 - told to the front, never a traceback
        answer(error=f"{config['path']}: cannot start the MCAP log: {exc}", kind="sink")
        return 1
    answer(ok=True, port=writer.live_port)
    failure = None
    try:
        while (record := _read_record(data)) is not None:
            op, ns, payload = record
            if op == OP_BATCH:  # encoded here, off the pipeline's tick
                for index, flags, message in orjson.loads(payload):
                    if flags & FLAG_POSE:
                        writer.log_pose(index, message, ns)
                    elif flags & FLAG_SCENE:  # the robot drawn from its points
                        writer.log(index, orjson.dumps(scene_message(*message)), ns, 0)
                    else:
                        writer.log(index, orjson.dumps(message), ns, flags)
            elif op == OP_TICK:
                writer.log_tick(payload, ns)
            elif op == OP_FLUSH:
                writer.flush()
                answer(ok=True)
            elif op == OP_CLOSE:
                break
    except WriterFailed as exc:
        failure = str(exc)
    except Exception as exc:  # noqa: BLE001 - told to the front, never a traceback
        failure = f"{writer.path}: cannot write the MCAP log: {exc}"
    if failure is not None:
        answer(error=failure, kind="sink")
        data.close()  # the front's next write fails at once and reads the line above
    trouble = writer.close()
    if failure is None and trouble is None:
        answer(ok=True)
    elif failure is None:
        answer(error=trouble, kind="sink")
    return 0


if __name__ == "__main__":
    sys.exit(serve(int(sys.argv[1]), int(sys.argv[2])))
