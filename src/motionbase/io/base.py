"""The two small interfaces every I/O adapter implements.

A *source* is a context manager and an iterator of
:class:`~motionbase.state.AircraftState` at a nominal fixed rate::

    with source:
        for state in source:
            ...

A *sink* is a context manager with ``write(output)`` taking one
:class:`~motionbase.pipeline.PipelineOutput`-like record per pipeline tick.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Protocol, runtime_checkable

from motionbase.state import AircraftState


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

    def __enter__(self) -> Source: ...

    def __exit__(self, *exc: object) -> None: ...

    def __iter__(self) -> Iterator[AircraftState]: ...

    def describe(self) -> dict[str, Any]:
        """Plain-data description of the source for the log's metadata."""
        ...


@runtime_checkable
class Sink(Protocol):
    """A consumer of pipeline outputs (MCAP log, serial link, UDP output)."""

    def __enter__(self) -> Sink: ...

    def __exit__(self, *exc: object) -> None: ...

    def write(self, output: Any) -> None: ...
