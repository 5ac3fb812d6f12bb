"""Read MCAP recordings back: aircraft states for a replay, every topic for a check.

The reader goes through the file from the start, record by record (the
``mcap`` library's :class:`~mcap.stream_reader.StreamReader`, chunk CRCs
checked), so it also reads files that were cut short: a run that crashed or
was killed leaves every complete chunk readable. Such a file yields the
messages written before the cut, sets ``truncated`` and logs a warning on the
``motionbase`` logger. A file that is not MCAP raises
:class:`~motionbase.errors.LogFormatError` with a one-line message naming it.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
from mcap.records import Channel, Footer, Message, Metadata
from mcap.stream_reader import StreamReader

from motionbase.errors import LogFormatError, SourceError
from motionbase.io.mcap_log import MCAP_MAGIC, METADATA_NAME
from motionbase.io.schemas import NONFINITE_STRINGS
from motionbase.state import AircraftState

try:  # optional speed-up, same numbers as json.loads
    from orjson import loads as _loads
except ImportError:  # pragma: no cover - depends on the environment
    _loads = json.loads

log = logging.getLogger("motionbase")

_NONFINITE_MARKERS = (b'"NaN"', b'"Infinity"', b'"-Infinity"')


def _restore_nonfinite(obj: Any) -> Any:
    if isinstance(obj, str):
        return NONFINITE_STRINGS.get(obj, obj)
    if isinstance(obj, dict):
        return {k: _restore_nonfinite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_restore_nonfinite(v) for v in obj]
    return obj


def decode_message(data: bytes) -> dict[str, Any]:
    """A JSON message as written by the logger, with ``"NaN"`` etc. back as floats."""
    msg = _loads(data)
    if any(m in data for m in _NONFINITE_MARKERS):
        msg = _restore_nonfinite(msg)
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


def _scan(
    path: Path,
    on_metadata: Callable[[Metadata], None],
    on_channel: Callable[[Channel], None],
    on_message: Callable[[Message], None],
) -> bool:
    """Walk every record of an MCAP file; return True when the file was cut short."""
    fh = _open(path)
    try:
        magic = fh.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            what = "empty file" if not magic else "wrong magic bytes"
            raise LogFormatError(
                f"{path}: not an MCAP file ({what}); expected a recording made by "
                "motionbase or another MCAP writer"
            )
        records = StreamReader(fh, skip_magic=True, validate_crcs=True).records
        try:
            for rec in records:
                if isinstance(rec, Message):
                    on_message(rec)
                elif isinstance(rec, Channel):
                    on_channel(rec)
                elif isinstance(rec, Metadata):
                    on_metadata(rec)
                elif isinstance(rec, Footer):
                    return False
        except LogFormatError:
            raise
        except Exception:  # noqa: BLE001 - any failure past the header is a cut
            return True
        return True  # ran out of records before the footer
    finally:
        fh.close()


def _warn_truncated(path: Path, what: str) -> None:
    log.warning(
        "%s: recording is truncated (the run was interrupted); read %s written before the cut",
        path,
        what,
    )


def _decode_config(path: Path, meta: Metadata) -> dict[str, Any]:
    raw = meta.metadata.get("config")
    if raw is None:
        return {}
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        raise LogFormatError(f"{path}: metadata 'config' is not valid JSON") from None
    return _restore_nonfinite(value) if isinstance(value, dict) else {}


def read_messages(path: str | os.PathLike[str]) -> dict[str, list[dict[str, Any]]]:
    """Every JSON message of a recording, by topic, in file order.

    For ``motionbase replay --check``. A truncated file gives the messages
    before the cut and logs a warning.

    Raises
    ------
    SourceError
        The file is missing or unreadable.
    LogFormatError
        The file is not MCAP, or a channel is not JSON-encoded.
    """
    p = Path(path)
    topics: dict[int, str] = {}
    out: dict[str, list[dict[str, Any]]] = {}

    def on_channel(ch: Channel) -> None:
        if ch.message_encoding != "json":
            raise LogFormatError(
                f"{p}: topic {ch.topic!r} is {ch.message_encoding!r}-encoded; "
                "motionbase reads JSON channels only"
            )
        topics[ch.id] = ch.topic
        out.setdefault(ch.topic, [])

    def on_message(msg: Message) -> None:
        topic = topics.get(msg.channel_id)
        if topic is None:
            raise LogFormatError(f"{p}: message on unknown channel {msg.channel_id}")
        out[topic].append(decode_message(msg.data))

    truncated = _scan(p, lambda m: None, on_channel, on_message)
    if truncated:
        _warn_truncated(p, f"{sum(len(v) for v in out.values())} messages")
    return out


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The configuration a recording was made with (``{}`` when it has none)."""
    return McapSource(path, _scan_messages=False).metadata


def _state_from_message(msg: dict[str, Any]) -> AircraftState:
    acc = msg.get("angular_acceleration")
    # a pipeline log keeps the source's own time (even a bad one) in `source_t`
    t = msg.get("source_t", msg["t"])
    return AircraftState(
        t=math.nan if t is None else t,
        specific_force=msg["specific_force"],
        angular_velocity=msg["angular_velocity"],
        attitude=msg["attitude"],
        angular_acceleration=acc,
    )


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
        Time from the first to the last state, s.
    metadata : dict
        The recorded configuration (``{}`` when there is none).
    truncated : bool
        The file was cut short; the states before the cut are read.
    count : int
        Number of states.

    Raises
    ------
    SourceError
        The file is missing or unreadable.
    LogFormatError
        The file is not MCAP, or holds no message on ``topic``.
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
        self.truncated = False
        self.count = 0
        self.fresh = True  # the last yielded sample's freshness, as recorded
        self.rate_hz = float("nan")
        self.duration_s: float | None = None
        self._channel_ids: set[int] = set()
        self._topics: set[str] = set()
        times: list[int] = []

        def on_metadata(meta: Metadata) -> None:
            if meta.name == METADATA_NAME and not self.metadata:
                self.metadata = _decode_config(self.path, meta)
                self.version = meta.metadata.get("version")

        def on_channel(ch: Channel) -> None:
            self._topics.add(ch.topic)
            if ch.topic == topic:
                if ch.message_encoding != "json":
                    raise LogFormatError(
                        f"{self.path}: topic {topic!r} is {ch.message_encoding!r}-encoded; "
                        "motionbase reads JSON channels only"
                    )
                self._channel_ids.add(ch.id)

        def on_message(msg: Message) -> None:
            if msg.channel_id in self._channel_ids:
                times.append(msg.log_time)

        if not _scan_messages:
            self.truncated = _scan_metadata_only(self.path, on_metadata)
            return
        self.truncated = _scan(self.path, on_metadata, on_channel, on_message)
        if not times:
            present = ", ".join(sorted(self._topics)) or "none"
            raise LogFormatError(
                f"{self.path}: no {topic} messages in the recording (topics present: {present})"
            )
        self.count = len(times)
        self.duration_s = (times[-1] - times[0]) / 1e9
        self.rate_hz = self._find_rate(np.asarray(times, dtype=np.int64))
        if self.truncated:
            _warn_truncated(self.path, f"{self.count} aircraft states")
        self._open = False

    def _find_rate(self, times_ns: np.ndarray) -> float:
        for table in (self.metadata, self.metadata.get("pipeline"), self.metadata.get("source")):
            if isinstance(table, dict):
                rate = table.get("rate_hz")
                if isinstance(rate, int | float) and not isinstance(rate, bool) and rate > 0:
                    return float(rate)
        steps = np.diff(times_ns)
        steps = steps[steps > 0]
        if steps.size == 0:
            raise LogFormatError(
                f"{self.path}: cannot tell the sample rate: fewer than two distinct times on "
                f"{self.topic} and no rate_hz in the recorded configuration"
            )
        return 1e9 / float(np.median(steps))

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

    def __iter__(self) -> Iterator[AircraftState]:
        """The recorded states in file order (the order they were logged)."""
        fh = _open(self.path)
        try:
            fh.seek(len(MCAP_MAGIC))
            records = StreamReader(fh, skip_magic=True, validate_crcs=True).records
            ids: set[int] = set()
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    return
                except Exception:  # noqa: BLE001 - the cut, already reported
                    return
                if isinstance(rec, Message):
                    if rec.channel_id in ids:
                        msg = decode_message(rec.data)
                        # whether the live source had a fresh sample (watchdog replays)
                        self.fresh = bool(msg.get("fresh", True))
                        yield _state_from_message(msg)
                elif isinstance(rec, Channel):
                    if rec.topic == self.topic:
                        ids.add(rec.id)
                elif isinstance(rec, Footer):
                    return
        finally:
            fh.close()

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
    return _scan(path, on_metadata, lambda c: None, lambda m: None)


__all__ = ["McapSource", "decode_message", "read_messages", "read_metadata"]
