"""The interfaces every I/O adapter implements, and what the pipeline's loop reads of them.

A *source* is a context manager and an iterator of
:class:`~motionbase.state.AircraftState` at a nominal fixed rate::

    with source:
        for state in source:
            ...

:func:`motionbase.pipeline.run` takes an entered :class:`Source` (or any iterable of
states; the command pipeline's sources, a cursor or the wiring check's sweep, yield
:class:`motionbase.commanding.Command` instead). Besides the states it reads three
optional capabilities, each its own protocol so that a source declares it by having the
attributes:

* :class:`StaleMarkingSource`: ``fresh``, False while the state just yielded is a stale
  hold (the pipeline's watchdog then fades the cue to level flight). A source without it
  is always fresh.
* :class:`SelfPacedSource`: ``paces_itself``, true when the source hands its states over
  in real time by itself (a live link, whose samples arrive on the sender's clock: the
  loop then does not pace the ticks; a JSBSim flight or a log never waits, the loop paces
  it), and ``due_time``, when the state just yielded was due (s on
  :func:`time.monotonic`), from which the loop counts late commands.
* :class:`EndingSource`: ``ended``, why its states ran out (``"duration"`` when
  ``duration_s`` cut it short), said in the run's summary instead of "end of source".

The live links (MAVLink, FlightGear, X-Plane) have both: :class:`LiveSource`.

A *sink* (:class:`Sink`) is a context manager with ``write(output)`` taking one
:class:`~motionbase.state.PipelineOutput` per tick. It never waits (only the pipeline's
loop keeps time), and what it returns is ignored by the loop.

These are :func:`typing.runtime_checkable` protocols: ``isinstance(x, Source)`` checks
that ``x`` has every member (not their types).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Protocol, Self, runtime_checkable

from motionbase.state import AircraftState, PipelineOutput

__all__ = [
    "EndingSource",
    "LiveSource",
    "SelfPacedSource",
    "Sink",
    "Source",
    "StaleMarkingSource",
]


@runtime_checkable
class Source(Protocol):
    """A source of aircraft states.

    Attributes
    ----------
    rate_hz : float
        Nominal sample rate, Hz. The pipeline runs at this rate by default.
    duration_s : float or None
        Expected length of the run in the source's time, s, when known (for
        progress bars); None for live sources.
    """

    rate_hz: float
    duration_s: float | None

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc: object) -> None: ...

    def __iter__(self) -> Iterator[AircraftState]: ...

    def describe(self) -> dict[str, Any]:
        """Plain-data description of the source for the log's metadata."""
        ...


@runtime_checkable
class StaleMarkingSource(Source, Protocol):
    """A source that marks stale holds (read by the pipeline's loop after each state).

    Attributes
    ----------
    fresh : bool
        False when the state just yielded is a hold older than the source's stale
        timeout (or, for a recording, was recorded so).
    """

    fresh: bool


@runtime_checkable
class EndingSource(Source, Protocol):
    """A source that says why it ended (read by the pipeline's loop at the end of input).

    Attributes
    ----------
    ended : str
        Set when the source's states run out: ``"duration"`` when its ``duration_s``
        cut it short, ``"end of input"`` when its input ended; empty when it has nothing
        to add (the run's summary then says "end of source").
    """

    ended: str


@runtime_checkable
class SelfPacedSource(Source, Protocol):
    """A source that may hand its states over in real time by itself.

    Attributes
    ----------
    paces_itself : bool
        True when it does (the pipeline's loop then does not pace the ticks).
    due_time : float or None
        When the state just yielded was due, s on :func:`time.monotonic` (None when
        not paced); the loop counts a command as late from it.
    """

    paces_itself: bool
    due_time: float | None


@runtime_checkable
class LiveSource(StaleMarkingSource, SelfPacedSource, Protocol):
    """A live link: marks stale holds and paces itself (MAVLink, FlightGear, X-Plane)."""


@runtime_checkable
class Sink(Protocol):
    """A consumer of pipeline outputs (MCAP log, motor drives, servo serial link)."""

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc: object) -> None: ...

    def write(self, output: PipelineOutput) -> object:
        """Take one tick's output; never waits. The return value is ignored by the loop."""
        ...
