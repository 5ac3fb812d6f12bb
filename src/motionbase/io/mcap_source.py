"""Read MCAP recordings back: aircraft states for a replay, every topic for a check.

The reader goes through the file from the start, record by record: it frames
each record itself (opcode, length) and has the ``mcap`` library parse it,
checking each chunk's CRC and those of the data and summary sections. So it
also reads files that were cut short: a run that crashed or was killed leaves
every complete chunk readable, and its file ends inside a record (or lacks its
footer). Such a file yields the messages written before the cut, sets
``truncated`` and logs a warning on the ``motionbase`` logger. Damage is not a
cut: a CRC that does not match, a record that lies wholly in the file but
cannot be read, or a length that runs past the end of a file that ends with the
MCAP magic (as only a finished file does) raises
:class:`~motionbase.errors.LogFormatError`, one line naming the file, the byte
where the damaged record or section starts and what to do. Bytes after the end
of a finished file (something appended to it) are ignored, with a warning: the
recording itself is whole. A file that is not MCAP raises LogFormatError too.
A file that ends, while it is replayed, before the states counted when the source
opened it (cut or overwritten meanwhile) raises :class:`~motionbase.errors.SourceError`
from the iteration: the pipeline parks, and the replay does not end as if the
recording ended there.

A malformed aircraft state (not JSON, not UTF-8, a missing field, a string or a bool
for a number, a list of the wrong length, ``null``, a negative time) never stops a
replay: :class:`McapSource` yields a sample of NaNs in its place, which the pipeline's
validation rejects, counts (``rejected_inputs`` in ``/health``) and replaces by a hold
of the last valid sample. The source counts them (``malformed``) and logs the first
one. Python's ``json`` writes non-finite numbers as bare ``NaN``/``Infinity`` tokens;
those are read (as non-finite numbers, which the validation rejects too).
"""

from __future__ import annotations

import gc
import json
import logging
import math
import os
import re
import zlib
from collections.abc import Callable, Collection, Iterable, Iterator
from io import BytesIO
from pathlib import Path
from types import TracebackType
from typing import IO, Any, NamedTuple

import numpy as np
from mcap.exceptions import UnsupportedCompressionError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, McapRecord, Message, Metadata
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk

from motionbase.errors import LogFormatError, SourceError
from motionbase.io.mcap_log import MCAP_MAGIC, METADATA_NAME
from motionbase.io.schemas import NONFINITE_STRINGS
from motionbase.state import AircraftState

try:  # optional speed-up, same numbers as json.loads
    from orjson import loads as _loads
except ImportError:  # pragma: no cover - depends on the environment
    _loads = json.loads

log = logging.getLogger("motionbase")

_NONFINITE_MARKER = re.compile(rb'"(?:NaN|-?Infinity)"')


def _restore_nonfinite(obj: Any) -> Any:
    if isinstance(obj, str):
        return NONFINITE_STRINGS.get(obj, obj)
    if isinstance(obj, dict):
        return {k: _restore_nonfinite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_restore_nonfinite(v) for v in obj]
    return obj


def decode_message(data: bytes) -> Any:
    """A JSON message as written by the logger, with ``"NaN"`` etc. back as floats.

    Bare ``NaN``/``Infinity`` tokens (Python's ``json`` writes them) are read too.

    Raises
    ------
    ValueError
        The bytes are not UTF-8 JSON (the message says why).
    """
    try:
        msg = _loads(data)
    except ValueError:  # orjson refuses the bare NaN tokens that Python's json writes
        try:
            msg = json.loads(data)
        except RecursionError:
            raise ValueError("not JSON: nested too deeply") from None
        except UnicodeDecodeError:
            raise ValueError("not UTF-8 text") from None
        except ValueError as exc:
            raise ValueError(f"not JSON: {exc}") from None
    if _NONFINITE_MARKER.search(data):
        try:
            msg = _restore_nonfinite(msg)
        except RecursionError:  # (the parser's own depth limit is higher than this walk's)
            raise ValueError("not JSON: nested too deeply") from None
    return msg


def _open(path: Path) -> IO[bytes]:
    try:
        return open(path, "rb")  # noqa: SIM115 - closed by the caller
    except FileNotFoundError:
        raise SourceError(f"{path}: file not found (check the path)") from None
    except IsADirectoryError:
        raise SourceError(f"{path}: is a directory, expected an .mcap file") from None
    except OSError as exc:
        raise SourceError(f"{path}: cannot open: {exc.strerror or exc}") from None


_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)


def _damaged(path: Path, what: str) -> LogFormatError:
    return LogFormatError(
        f"{path}: the file is damaged, not cut short: {what}; re-record it, or copy it again "
        "from where it was recorded"
    )


def _written_whole(fh: IO[bytes], size: int) -> bool:
    """Whether the file ends as a finished MCAP file does, with the magic after its footer
    (a file cut short ends there by a 1 in 2**64 chance)."""
    if size < 2 * len(MCAP_MAGIC):
        return False
    fh.seek(size - len(MCAP_MAGIC))
    return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC


def _record_name(opcode: int) -> str:
    return Opcode(opcode).name.lower().replace("_", " ")


class _Ending(NamedTuple):
    """How a scanned file ends."""

    truncated: bool  # cut short: the records before the cut were read
    trailing: int = 0  # bytes after the closing magic (something appended to a whole file)


def _scan(
    path: Path,
    on_metadata: Callable[[Metadata], None],
    on_channel: Callable[[Channel], None],
    on_message: Callable[[Message], None],
) -> _Ending:
    """Walk every record of an MCAP file; say whether it was cut short or has bytes after
    its end.

    The walk frames the records itself (opcode, length) so that it knows where each one
    starts and whether it lies wholly in the file: a record that runs past the end of a file
    without its footer is the cut of an interrupted run (the records before it are read); a
    record that lies wholly in the file and cannot be read, a chunk whose CRC does not match,
    or a data section whose CRC does not match, is damage.

    Raises
    ------
    LogFormatError
        The file is not MCAP, or is damaged (the message says where).
    """
    fh = _open(path)
    try:
        size = os.fstat(fh.fileno()).st_size
        magic = fh.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            what = "empty file" if not magic else "wrong magic bytes"
            mavlink = str(path).lower().endswith((".tlog", ".bin"))
            raise LogFormatError(
                f"{path}: not an MCAP file ({what}); expected a recording made by "
                "motionbase or another MCAP writer"
                + ("; a MAVLink log streams with stream --mavlink FILE --fast" if mavlink else "")
            )
        crc = zlib.crc32(magic)  # of the data section, then of the summary section
        summary_start = 0  # where the summary section starts: after the Data End record
        start = len(MCAP_MAGIC)
        while True:
            head = fh.read(9)
            end = start + 9 + int.from_bytes(head[1:], "little") if len(head) == 9 else None
            if end is None or end > size:
                if not _written_whole(fh, size):
                    return _Ending(truncated=True)  # the cut: this record was being written
                raise _damaged(
                    path,
                    f"the record at byte {start} runs past the end of the file, which ends as "
                    "a finished recording does (a damaged length)",
                )
            body = fh.read(end - start - 9)
            rec = _read_record(path, start, head, body) if head[0] in _KNOWN_OPCODES else None
            if isinstance(rec, Message):
                on_message(rec)
            elif isinstance(rec, Channel):
                on_channel(rec)
            elif isinstance(rec, Metadata):
                on_metadata(rec)
            elif isinstance(rec, Chunk):
                for inner in _open_chunk(path, start, rec):
                    if isinstance(inner, Message):
                        on_message(inner)
                    elif isinstance(inner, Channel):
                        on_channel(inner)
            elif isinstance(rec, DataEnd):
                if rec.data_section_crc not in (0, crc):
                    raise _damaged(
                        path, f"the data section (bytes 0 to {start}) fails its CRC check"
                    )
                crc, summary_start, start = 0, end, end
                continue
            elif isinstance(rec, Footer):
                if not summary_start:  # every MCAP writer ends its data with a Data End
                    raise _damaged(path, f"no data end record before the footer at byte {start}")
                # the summary's CRC runs to the footer's summary_offset_start field
                crc = zlib.crc32(body[:16], zlib.crc32(head, crc))
                if rec.summary_crc not in (0, crc):
                    raise _damaged(
                        path,
                        f"the summary section (bytes {summary_start} to {start}) fails its "
                        "CRC check",
                    )
                closing = fh.read(len(MCAP_MAGIC))
                if not MCAP_MAGIC.startswith(closing):  # (a prefix: cut in the magic)
                    raise _damaged(
                        path, f"the footer at byte {start} is not followed by the MCAP magic"
                    )
                return _Ending(truncated=False, trailing=max(0, size - end - len(MCAP_MAGIC)))
            crc = zlib.crc32(body, zlib.crc32(head, crc))
            start = end
    except OSError as exc:  # a read that fails (EIO: a failing disk or stick): a traceback once
        raise SourceError(f"{path}: cannot read: {exc.strerror or exc}") from None
    finally:
        fh.close()


def _read_record(path: Path, start: int, head: bytes, body: bytes) -> McapRecord:
    """The record framed at byte ``start``, which lies wholly in the file."""
    try:
        return next(StreamReader(BytesIO(head + body), skip_magic=True, emit_chunks=True).records)
    except Exception as exc:  # noqa: BLE001 - whatever the parser trips on, it is damage
        raise _damaged(
            path,
            f"the {_record_name(head[0])} record at byte {start} cannot be read "
            f"({_short_reason(exc) or type(exc).__name__})",
        ) from None


def _open_chunk(path: Path, start: int, chunk: Chunk) -> list[McapRecord]:
    """The records in the chunk at byte ``start``, its CRC checked."""
    try:
        return breakup_chunk(chunk, validate_crc=True)
    except UnsupportedCompressionError:
        raise LogFormatError(
            f"{path}: its chunks are {chunk.compression}-compressed, which this Python cannot "
            f"read (install the {'zstandard' if chunk.compression == 'zstd' else 'lz4'} package)"
        ) from None
    except CRCValidationError:
        raise _damaged(path, f"the chunk at byte {start} fails its CRC check") from None
    except Exception as exc:  # noqa: BLE001 - a decompressor's or the parser's error
        raise _damaged(
            path,
            f"the chunk at byte {start} cannot be read "
            f"({_short_reason(exc) or type(exc).__name__})",
        ) from None


def _warn_ending(path: Path, ending: _Ending, what: str) -> None:
    """Warn of a file cut short (``what`` was read before the cut) or with bytes after it."""
    if ending.truncated:
        log.warning(
            "%s: recording is truncated (the run was interrupted); read %s written before the cut",
            path,
            what,
        )
    if ending.trailing:
        log.warning(
            "%s: %d bytes follow the end of the recording (its footer and closing magic); "
            "ignored, the recording itself is whole",
            path,
            ending.trailing,
        )


def _decode_config(path: Path, meta: Metadata) -> dict[str, Any]:
    raw = meta.metadata.get("config")
    if raw is None:
        return {}
    try:
        value = json.loads(raw)
        if isinstance(value, dict):
            value = _restore_nonfinite(value)
    except json.JSONDecodeError:
        raise LogFormatError(f"{path}: metadata 'config' is not valid JSON") from None
    except RecursionError:
        raise LogFormatError(
            f"{path}: metadata 'config' is nested too deeply to be a motionbase configuration"
        ) from None
    if not isinstance(value, dict):
        kinds = {list: "a JSON array", str: "a JSON string", bool: "a JSON boolean"}
        kind = "JSON null" if value is None else kinds.get(type(value), "a JSON number")
        raise LogFormatError(
            f"{path}: metadata 'config' is {kind}, not an object (motionbase records its "
            "configuration as one; re-record the file)"
        )
    return value


def _no_messages(path: Path, topic: str, present: Iterable[str], truncated: bool) -> LogFormatError:
    """The error for a recording without a message on ``topic`` (cut short before one?)."""
    listed = ", ".join(sorted(present)) or "none"
    if truncated:
        return LogFormatError(
            f"{path}: no {topic} messages: the recording was cut short before the first one "
            f"(the run was interrupted; topics present: {listed})"
        )
    return LogFormatError(
        f"{path}: no {topic} messages in the recording (topics present: {listed})"
    )


def read_messages(
    path: str | os.PathLike[str],
    *,
    require: str | None = None,
    skip: Collection[str] = (),
    json_only: bool = True,
) -> dict[str, list[dict[str, Any]]]:
    """Every JSON message of a recording, by topic, in file order.

    For ``motionbase replay --check`` and ``report``. A truncated file gives the
    messages before the cut and logs a warning.

    Parameters
    ----------
    path : str or Path
        The recording.
    require : str, optional
        A topic the caller cannot do without: a recording with no message on it
        raises, before any warning (a file with nothing usable gives one line).
    skip : collection of str
        Topics not decoded and left out of the result (``report`` skips the robot's
        drawing, ``/platform/scene``: about 75 kB a message decoded, 30 a second, most of
        a recording's memory once read).
    json_only : bool
        A channel that is not JSON-encoded raises (``replay --check``, which would not
        compare it). When False its messages are left out with the warning that counts
        messages that are not JSON (``report``, which reads its own topics: a recording merged
        with another tool's camera, say); on ``require``, it still raises.

    Raises
    ------
    SourceError
        The file is missing or unreadable.
    LogFormatError
        The file is not MCAP, is damaged (not cut short), a channel is not JSON-encoded,
        or there is no message on ``require``.
    """
    p = Path(path)
    topics: dict[int, str] = {}
    out: dict[str, list[dict[str, Any]]] = {}

    foreign: dict[int, str] = {}  # channel id -> its encoding, not JSON (left out)

    def on_channel(ch: Channel) -> None:
        if ch.message_encoding != "json":
            if json_only or ch.topic == require:
                raise LogFormatError(
                    f"{p}: topic {ch.topic!r} is {ch.message_encoding!r}-encoded; "
                    "motionbase reads JSON channels only"
                )
            foreign[ch.id] = ch.message_encoding
        topics[ch.id] = ch.topic
        if ch.topic not in skip and ch.id not in foreign:
            out.setdefault(ch.topic, [])

    skipped: list[str] = []
    skipped_topics: set[str] = set()  # (on ``skip``: present, not read)
    # the first message on a channel never defined: refused after the walk, so that damage
    # (which may have taken the channel's record) is reported as such
    orphans: list[int] = []

    def on_message(msg: Message) -> None:
        topic = topics.get(msg.channel_id)
        if topic is None:
            if not orphans:
                orphans.append(msg.channel_id)
            return
        if topic in skip or msg.channel_id in foreign:
            skipped_topics.add(topic)
            if msg.channel_id in foreign:
                skipped.append(f"{topic}: {foreign[msg.channel_id]!r}-encoded")
            return
        try:
            out[topic].append(decode_message(msg.data))
        except ValueError as exc:
            skipped.append(f"{topic}: {_short_reason(exc)}")

    # The messages are trees of dicts and lists, never cycles; with the cyclic collector on,
    # each of its passes walks every message read so far (12 s instead of 5 s for a
    # recording of 330,000 messages).
    collecting = gc.isenabled()
    gc.disable()
    try:
        ending = _scan(p, lambda m: None, on_channel, on_message)
    finally:
        if collecting:
            gc.enable()
    if orphans:
        raise LogFormatError(f"{p}: message on unknown channel {orphans[0]}")
    if require is not None and not out.get(require):
        present = {t for t, msgs in out.items() if msgs} | skipped_topics
        raise _no_messages(p, require, present, ending.truncated)
    _warn_ending(p, ending, f"{sum(len(v) for v in out.values())} messages")
    if skipped:
        log.warning(
            "%s: skipped %d messages that are not JSON (first: %s)", p, len(skipped), skipped[0]
        )
    return out


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The configuration a recording was made with (``{}`` when it has none)."""
    return McapSource(path, _scan_messages=False).metadata


class _Malformed(ValueError):
    """An aircraft-state message that cannot be read as one (the reason is the message)."""


def _short_reason(exc: BaseException, limit: int = 120) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _show(value: Any, limit: int = 40) -> str:
    """A value as JSON writes it, cut short (``null``, ``"0"``, ``[0, 1]``)."""
    try:
        text = json.dumps(value)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _number(key: str, value: Any) -> float:
    # null stands for a non-finite number (the logger's own convention): NaN, rejected later
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _Malformed(f"{key!r} holds {_show(value)}, not a number")
    try:
        return float(value)
    except OverflowError:  # an integer beyond any float
        raise _Malformed(f"{key!r} holds an integer too large for a number") from None


def _vector(msg: dict[str, Any], key: str, *, optional: bool = False) -> list[float] | None:
    if key not in msg:
        if optional:
            return None
        raise _Malformed(f"no {key!r} field")
    value = msg[key]
    if value is None and optional:
        return None
    if not isinstance(value, list) or len(value) != 3:
        raise _Malformed(f"{key!r} is {_show(value)}, not a list of 3 numbers")
    return [_number(key, v) for v in value]


#: The reason a replay gives for the stop it reproduces (:meth:`McapSource.reproduce_stop`).
RECORDED_STOP = "the stop in the recording"
_POSES = frozenset({"/platform/pose", "/planar/pose"})
_STOPPING = re.compile(rb'"phase"\s*:\s*"stopping"')

_NAN3 = (math.nan, math.nan, math.nan)
_MALFORMED_STATE = AircraftState(t=math.nan, specific_force=_NAN3, angular_velocity=_NAN3)


def _state_from_message(msg: Any) -> AircraftState:
    """The state in one decoded message; :class:`_Malformed` when it holds none."""
    if not isinstance(msg, dict):
        raise _Malformed(f"the message is {_show(msg)}, not a JSON object")
    # a pipeline log keeps the source's own time (even a bad one) in `source_t`
    key = "source_t" if "source_t" in msg else "t"
    if key not in msg:
        raise _Malformed("no 't' field")
    t = _number(key, msg[key])
    if t < 0.0:
        raise _Malformed(f"time {t:g} s is negative (a recording's times start at 0 s)")
    on_ground = msg.get("on_ground")
    if on_ground is not None and not isinstance(on_ground, bool):
        raise _Malformed(f"'on_ground' is {_show(on_ground)}, not true, false or null")
    return AircraftState(
        t=t,
        specific_force=_vector(msg, "specific_force"),
        angular_velocity=_vector(msg, "angular_velocity"),
        attitude=_vector(msg, "attitude"),
        angular_acceleration=_vector(msg, "angular_acceleration", optional=True),
        on_ground=on_ground,
    )


def _unusable(data: bytes, limits: Any) -> str:
    """Why a state message cannot be used (malformed, non-finite, rejected by the input
    validation with ``limits``: a time no log holds, a value beyond its bound); ``""`` when
    it can."""
    from motionbase.safety import input_problem

    try:
        state = _state_from_message(decode_message(data))
    except ValueError as exc:
        return _short_reason(exc)
    if not state.is_finite():
        return "a number in it is not finite"
    f, w, att = state.specific_force, state.angular_velocity, state.attitude
    return input_problem(state.t, f, w, att, None, limits) or ""


class McapSource:
    """Aircraft states from an MCAP recording, for replays.

    The file is scanned when the source is created (metadata, message count,
    rate, duration, truncation) and read again, message by message, while
    iterating, so memory does not grow with the recording's length.

    Parameters
    ----------
    path : str or Path
        The recording.
    topic : str
        Topic of the :class:`~motionbase.state.AircraftState` messages.

    Attributes
    ----------
    rate_hz : float
        The recording's pipeline rate, Hz: ``rate_hz`` from the recorded
        configuration (top level, then ``pipeline``, then ``source``), else the
        median spacing of the messages.
    duration_s : float
        Time from the first to the last state, s (by their log times).
    metadata : dict
        The recorded configuration (``{}`` when there is none).
    truncated : bool
        The file was cut short; the states before the cut are read.
    count : int
        Number of states.
    recorded_stop : int or None
        The recorded run was stopped (a stop signal, a failure) while its source still
        gave states: the 1-based number of the state whose tick was the first one
        stopping (its ``/platform/pose`` or ``/planar/pose`` phase). None when the run
        went on to the end of its source. :meth:`reproduce_stop` asks a replay to stop
        at the same state.
    malformed : int
        States read so far that were malformed (each yielded as a sample of NaNs, which
        the pipeline rejects and holds); ``first_malformed`` says what was wrong with the
        first one.

    Raises
    ------
    SourceError
        The file is missing or unreadable.
    LogFormatError
        The file is not MCAP, is damaged (not cut short), or holds no message on ``topic``.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        topic: str = "/aircraft/state",
        _scan_messages: bool = True,
    ) -> None:
        self.path = Path(path)
        self.topic = topic
        self.metadata: dict[str, Any] = {}
        self.version: str | None = None
        #: the log's message layout (``LOG_FORMAT`` of :mod:`motionbase.io.mcap_log`; None
        #: when the file does not say)
        self.log_format: str | None = None
        self.truncated = False
        self.count = 0
        self.malformed = 0
        self.first_malformed = ""
        self.fresh = True  # the last yielded sample's freshness, as recorded
        self.rate_hz = float("nan")
        self.rate_from = ""  # where rate_hz came from, for messages
        self.duration_s: float | None = None
        self.recorded_stop: int | None = None
        self._stop_request: Any = None
        self._channel_ids: set[int] = set()
        self._topics: dict[int, str] = {}  # channel id -> topic
        with_messages: set[int] = set()  # the channels that have messages
        times: list[int] = []

        def on_metadata(meta: Metadata) -> None:
            if meta.name == METADATA_NAME and not self.metadata:
                self.metadata = _decode_config(self.path, meta)
                self.version = meta.metadata.get("version")
                self.log_format = meta.metadata.get("log_format")

        def on_channel(ch: Channel) -> None:
            self._topics[ch.id] = ch.topic
            if ch.topic == topic:
                if ch.message_encoding != "json":
                    raise LogFormatError(
                        f"{self.path}: topic {topic!r} is {ch.message_encoding!r}-encoded; "
                        "motionbase reads JSON channels only"
                    )
                self._channel_ids.add(ch.id)

        first: list[bytes] = []
        # a tick logs its state (when it has one) before its poses
        state_in_tick = [False]

        def on_message(msg: Message) -> None:
            with_messages.add(msg.channel_id)
            if msg.channel_id in self._channel_ids:
                times.append(msg.log_time)
                state_in_tick[0] = True
                if not first:
                    first.append(msg.data)
            elif self.recorded_stop is None and self._topics.get(msg.channel_id) in _POSES:
                if state_in_tick[0] and _STOPPING.search(msg.data):
                    self.recorded_stop = len(times)
                state_in_tick[0] = False

        if not _scan_messages:
            self.truncated = _scan_metadata_only(self.path, on_metadata)
            return
        ending = _scan(self.path, on_metadata, on_channel, on_message)
        self.truncated = ending.truncated
        if not times:
            present = {self._topics[i] for i in with_messages if i in self._topics}
            raise _no_messages(self.path, topic, present, ending.truncated)
        self._check_clock(first[0])
        self.count = len(times)
        self.duration_s = abs(times[-1] - times[0]) / 1e9  # (log times may run backwards)
        self.rate_hz = self._find_rate(np.asarray(times, dtype=np.uint64))
        _warn_ending(self.path, ending, f"{self.count} aircraft states")
        self._open = False

    def reproduce_stop(self, stop: Any) -> None:
        """Set ``stop`` (a :class:`~motionbase.stopping.StopRequest`) when the iteration
        hands over the state at which the recorded run was stopped (:attr:`recorded_stop`),
        so that a replay stops where the recording did, with :data:`RECORDED_STOP` as the
        reason (the pipeline's loop reads the request before it steps that state)."""
        self._stop_request = stop

    def _check_clock(self, data: bytes) -> None:
        """Refuse a recording whose clock starts before 0 s, naming the file: each of its
        samples would be rejected (an isolated negative time later on is rejected and held)."""
        try:
            msg = decode_message(data)
        except ValueError:
            return  # a malformed first state: rejected and held like any other
        t = msg.get("source_t", msg.get("t")) if isinstance(msg, dict) else None
        if isinstance(t, int | float) and not isinstance(t, bool) and t < 0:
            raise LogFormatError(
                f"{self.path}: the first {self.topic} message is at {t:g} s; a recording's "
                "times start at 0 s (shift its clock so the first sample is at 0 s or later)"
            )

    def _find_rate(self, times_ns: np.ndarray) -> float:
        for name in ("", "pipeline", "source"):
            table = self.metadata.get(name) if name else self.metadata
            if isinstance(table, dict):
                rate = table.get("rate_hz")
                if (
                    isinstance(rate, int | float)
                    and not isinstance(rate, bool)
                    and 0 < rate < math.inf
                ):
                    where = f"{name}." if name else ""
                    self.rate_from = f"its recorded configuration ({where}rate_hz)"
                    return float(rate)
        # (MCAP's times are unsigned 64-bit: the steps modulo 2**64, back ones negative; a
        # writer's log times that run backwards are spaced as well as forward ones)
        steps = np.abs(np.diff(times_ns).view(np.int64))
        steps = steps[steps > 0]
        if steps.size == 0:
            raise LogFormatError(
                f"{self.path}: cannot tell the sample rate: fewer than two distinct times on "
                f"{self.topic} and no rate_hz in the recorded configuration"
            )
        median = float(np.median(steps))
        self.rate_from = (
            f"the spacing of its {self.topic} log times (median {median:g} ns; no rate_hz in "
            "its recorded configuration)"
        )
        return 1e9 / median

    # lifecycle -------------------------------------------------------------
    def __enter__(self) -> McapSource:
        self._open = True
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._open = False

    def unusable_with(self, limits: Any) -> str:
        """Why no state of the recording can be used by a run with the input ``limits``
        (:class:`~motionbase.safety.InputLimits`): the first one's reason (malformed, not
        finite, beyond the limits), ``""`` when one can. The states are read until one is
        usable (the first, in a usable recording)."""
        first = ""
        for _, data in self._messages():
            why = _unusable(data, limits)
            if not why:
                return ""
            first = first or f"message 1: {why}"
        return first

    def __iter__(self) -> Iterator[AircraftState]:
        """The recorded states in file order (the order they were logged)."""
        self.malformed, self.fresh = 0, True  # (as a fresh source: a replay after a preview)
        for index, data in self._messages():
            state = self._read_state(data, index)
            if index == self.recorded_stop and self._stop_request is not None:
                self._stop_request.set(RECORDED_STOP)
            yield state

    def _messages(self) -> Iterator[tuple[int, bytes]]:
        """The state messages' payloads in file order, numbered from 1."""
        fh = _open(self.path)
        index = 0
        try:
            fh.seek(len(MCAP_MAGIC))
            records = StreamReader(fh, skip_magic=True, validate_crcs=True).records
            ids: set[int] = set()
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    break
                except Exception as exc:  # noqa: BLE001 - the cut, already reported
                    self._check_whole(index, exc)
                    return
                if isinstance(rec, Message):
                    if rec.channel_id in ids:
                        index += 1
                        yield index, rec.data
                elif isinstance(rec, Channel):
                    if rec.topic == self.topic:
                        ids.add(rec.id)
                elif isinstance(rec, Footer):
                    break
            self._check_whole(index, None)
        finally:
            fh.close()

    def _check_whole(self, read: int, exc: BaseException | None) -> None:
        """Raise when the file ended before the states counted when it was opened: it was
        cut, overwritten or damaged during the replay (a replay that ended there as if the
        recording ended would say nothing of it)."""
        if read >= self.count:
            return
        why = f" ({_short_reason(exc) or type(exc).__name__})" if exc is not None else ""
        raise SourceError(
            f"{self.path}: the recording changed while it was replayed: it ends after "
            f"{read} of the {self.count} aircraft states it held when the replay began{why}; "
            "replay a copy that nothing writes to"
        )

    def _read_state(self, data: bytes, index: int) -> AircraftState:
        """The state in message ``index`` (1-based), or a sample of NaNs when malformed."""
        try:
            msg = decode_message(data)
            state = _state_from_message(msg)
            fresh = msg.get("fresh", True)
            if not isinstance(fresh, bool):
                raise _Malformed(f"'fresh' holds {_show(fresh)}, not true or false")
        except ValueError as exc:  # _Malformed, or bytes that are not UTF-8 JSON
            self.malformed += 1
            if not self.first_malformed:  # (said once: a preview read the states before)
                self.first_malformed = f"message {index}: {_short_reason(exc)}"
                log.warning(
                    "%s: message %d on %s is malformed (%s); rejected and held like any "
                    "invalid sample",
                    self.path,
                    index,
                    self.topic,
                    _short_reason(exc),
                )
            return _MALFORMED_STATE  # its freshness stays that of the last valid one
        # whether the live source had a fresh sample (watchdog replays)
        self.fresh = fresh
        return state

    def describe(self) -> dict[str, Any]:
        """Plain-data description of the source for the log's metadata."""
        return {
            "kind": "mcap",
            "path": str(self.path),
            "topic": self.topic,
            "rate_hz": self.rate_hz,
            "duration_s": self.duration_s,
            "count": self.count,
            "truncated": self.truncated,
            "recorded_with": self.version,
            "recorded_source": self.metadata.get("source"),
        }


def _scan_metadata_only(path: Path, on_metadata: Callable[[Metadata], None]) -> bool:
    return _scan(path, on_metadata, lambda c: None, lambda m: None).truncated


__all__ = ["RECORDED_STOP", "McapSource", "decode_message", "read_messages", "read_metadata"]
