"""The shared loop of the live UDP sources: fixed-rate ticks holding the latest sample.

:class:`UdpLiveSource` is the part that the FlightGear native-FDM source
(:mod:`motionbase.io.fgnative_source`) and the X-Plane source
(:mod:`motionbase.io.xplane_source`) have in common; a subclass only binds its
address and decodes its packets.

* One UDP socket, non-blocking, bound at :meth:`UdpLiveSource.open`.
* Ticks at ``rate_hz`` on the wall clock (:func:`time.monotonic`), tick ``k``
  due at ``start + k / rate_hz``. Between ticks the datagrams that arrive are
  read (see Draining below) and handed to the subclass, which stores the values
  it accepts in nine slots (specific force, body rates, attitude) with their
  arrival time. Each tick yields the latest value of every slot, never
  extrapolated (a hold), with ``t = k / rate_hz``.
* Stale watchdog: a tick is *fresh* when the oldest slot is at most
  ``stale_timeout_s`` old. Before any sample the held state is the neutral one,
  ``f = (0, 0, -g)``. Stale ticks keep coming at the pipeline rate, marked
  ``fresh`` False, so the pipeline fades the platform to neutral.
* A tick that starts more than one period late is counted (``late_ticks``); after
  a stall of more than 0.25 s the schedule is re-anchored (no burst of catch-up
  ticks).
* Pacing: :func:`motionbase.pacing.wait_until` polls the socket every 0.1 ms when
  busy-waiting, otherwise the loop sleeps in :func:`select.select` until a
  datagram or the tick is due.
* Draining: between ticks the link is read as datagrams arrive. Reading never
  goes on past the tick's due time plus ``drain_budget_s`` (a tenth of a period
  by default), whatever arrives: a flood of datagrams (anyone who can reach the
  port can send one) cannot hold a tick back. What is still queued then waits
  in the socket for the next tick (or the kernel drops it when the socket's
  buffer is full). Each pass reads :data:`MIN_READS` datagrams (messages), when
  there are that many, whatever the clock says, so a late tick reads something.

The ticking, the held sample, the watchdog and the counters are
:class:`SampleHoldSource`, which :class:`~motionbase.io.mavlink_source.MavlinkSource`
shares: it reads through pymavlink rather than a socket of its own, so it
supplies its own reader (pymavlink's ``recv_msg`` instead of ``recvfrom``).
"""

from __future__ import annotations

import logging
import math
import select
import socket
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Self

from motionbase.errors import ConfigError, SourceError
from motionbase.io.net_address import bind_fix, check_port
from motionbase.pacing import wait_until
from motionbase.physics import STANDARD_GRAVITY
from motionbase.state import AircraftState

__all__ = [
    "DRAIN_BUDGET_PERIODS",
    "MIN_READS",
    "LiveStats",
    "LiveTick",
    "SampleHoldSource",
    "TickStats",
    "UdpLiveSource",
    "attitude_ok",
    "finite_within",
    "is_loopback",
    "positive_number",
    "split_host_port",
    "wrap_pi",
]

_log = logging.getLogger("motionbase")

_ANGLE_TOL = 1e-3  # rad, on the limits of roll, pitch and yaw

_POLL_S = 1e-4  # busy-wait: how often the socket is polled between ticks, s
#: Datagrams (MAVLink: messages) a pass over the link reads before it looks at the clock:
#: a tick that starts late still reads this many, however late it is. Few: at 1 kHz four
#: MAVLink messages (about 0.1 ms each) already take a good part of a period.
MIN_READS = 4
#: How long a tick may go on reading past its due time, in periods (``drain_budget_s``).
DRAIN_BUDGET_PERIODS = 0.1
_RECV_BYTES = 65536

#: slot order of the held sample: specific force (3), body rates (3), attitude (3)
N_SLOTS = 9
F_SLOTS = slice(0, 3)
W_SLOTS = slice(3, 6)
ATT_SLOTS = slice(6, 9)


@dataclass(frozen=True)
class LiveTick:
    """What the pipeline needs to know about the state just yielded.

    Attributes
    ----------
    fresh : bool
        True when every part of the state (specific force, body rates,
        attitude) is at most ``stale_timeout_s`` old.
    sample_age_s : float
        Age of the oldest part of the state, s, in the source clock (wall clock
        for a live link, log time for a log); inf before any sample.
    new_sample : bool
        True when a value entered the state since the previous tick.
    arrival_s : float
        When the newest value in the state arrived, s: ``time.monotonic()`` for
        a live link, log time for a log; nan before any sample.
    """

    fresh: bool
    sample_age_s: float
    new_sample: bool
    arrival_s: float


_NOT_STARTED = LiveTick(fresh=False, sample_age_s=math.inf, new_sample=False, arrival_s=math.nan)


@dataclass(frozen=True)
class TickStats:
    """The counters every live source keeps (see :attr:`UdpLiveSource.stats`).

    Attributes
    ----------
    received : int
        Datagrams (MAVLink: decoded messages) read from the link.
    accepted : int
        Datagrams (messages) that passed the source's checks of origin and
        protocol.
    rejected_invalid : int
        Datagrams (FlightGear), values (X-Plane) or messages (MAVLink) that
        were NaN, infinite or physically absurd; none of them reached the state.
    bad_data : int
        Datagrams (chunks of bytes) that are not the protocol.
    bad_bytes : int
        Bytes in those.
    ticks, stale_ticks : int
        Ticks yielded, and how many of them were stale.
    gaps : int
        Fresh-to-stale transitions (each logged as a warning).
    late_ticks : int
        Live ticks that started more than one period late.
    last_sample_age_s : float
        Age of the oldest part of the last yielded state, s, in the source
        clock; inf before any.
    message_rate_hz : float
        Accepted datagrams (messages) per second over the last complete second
        of source time.
    """

    received: int = 0
    accepted: int = 0
    rejected_invalid: int = 0
    bad_data: int = 0
    bad_bytes: int = 0
    ticks: int = 0
    stale_ticks: int = 0
    gaps: int = 0
    late_ticks: int = 0
    last_sample_age_s: float = math.inf
    message_rate_hz: float = 0.0


@dataclass(frozen=True)
class LiveStats(TickStats):
    """A snapshot of a UDP live source's counters (see :attr:`UdpLiveSource.stats`).

    Attributes
    ----------
    extra : Mapping[str, Any]
        Source-specific figures (protocol version, subscription state, ...).

    The counters are those of :class:`TickStats`: ``accepted`` counts the
    datagrams whose values entered the state (in whole or in part), ``bad_data``
    those with a wrong header, size or version.
    """

    extra: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def rejected(self) -> int:
        """Everything refused: invalid values and datagrams that are not the protocol."""
        return self.rejected_invalid + self.bad_data


def split_host_port(
    text: str, what: str, example: str, *, free_port: bool = True
) -> tuple[str, int]:
    """``HOST:PORT`` (or ``[IPv6]:PORT``) as (host, port), or a one-line ConfigError.

    Parameters
    ----------
    text : str
        The address, e.g. ``0.0.0.0:5500``.
    what : str
        Name of the thing in the error message, e.g. ``"fgnative URL"``.
    example : str
        A correct example for the error message.
    free_port : bool
        Port 0 (listen on any free port) is allowed; False refuses it (see
        :func:`~motionbase.io.net_address.check_host_port`).
    """
    host, sep, port_s = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not sep or not host:
        raise ConfigError(f"{what}: expected HOST:PORT, got {text!r} ({example})")
    return host, check_port(what, port_s, free_port=free_port, example=example)


def finite_within(values: Any, limit: float) -> bool:
    """True when every value is a finite number in [-limit, limit] (False for NaN)."""
    for v in values:
        if not (-limit <= v <= limit):
            return False
    return True


def attitude_ok(roll: float, pitch: float, yaw: float) -> bool:
    """True for Euler angles inside roll [-pi, pi], pitch [-pi/2, pi/2], yaw [-2 pi, 2 pi], rad."""
    return (
        -math.pi - _ANGLE_TOL <= roll <= math.pi + _ANGLE_TOL
        and -0.5 * math.pi - _ANGLE_TOL <= pitch <= 0.5 * math.pi + _ANGLE_TOL
        and -2.0 * math.pi - _ANGLE_TOL <= yaw <= 2.0 * math.pi + _ANGLE_TOL
    )


def wrap_pi(a: float) -> float:
    """An angle wrapped to [-pi, pi), rad."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def is_loopback(host: str) -> bool:
    """True for a loopback host name or address (``localhost``, ``::1``, ``127.x.x.x``)."""
    return host in ("localhost", "::1") or host.startswith("127.")


def positive_number(kind: str, name: str, value: Any, unit: str, *, zero_ok: bool = False) -> float:
    """``value`` as a float when it is a finite number > 0 (>= 0 with ``zero_ok``), else a
    one-line ConfigError.

    Parameters
    ----------
    kind, name : str
        The source and the parameter, for the message (``"mavlink"``, ``"rate_hz"``).
    value : Any
        What was given.
    unit : str
        Its unit, for the message (``"Hz"``, ``"s"``).
    zero_ok : bool
        0 is allowed too.
    """
    if not (
        isinstance(value, int | float)
        and math.isfinite(value)
        and (value >= 0 if zero_ok else value > 0)
    ):
        bound = ">= 0" if zero_ok else "> 0"
        raise ConfigError(f"{kind} {name}: must be a finite number {bound} {unit}, got {value!r}")
    return float(value)


class SampleHoldSource:
    """Fixed-rate ticks holding the latest sample, with a stale watchdog and counters.

    The part every live source shares (the UDP simulator sources and MAVLink):
    the nine held slots (specific force, body rates, attitude) with their arrival
    times, the live tick loop on the wall clock, the freshness of each tick and
    the message rate. A subclass opens its link, reads it (:meth:`_reader`) and
    stores the values it accepts with :meth:`_store`.

    Parameters
    ----------
    url : str
        The source URL (kept for messages and descriptions).
    rate_hz : float
        Tick rate, Hz (> 0): the pipeline rate.
    duration_s : float, optional
        Stop after this long, s; None runs until the consumer stops.
    busy_wait : bool
        Wait for the next tick by polling the link (one processor at 100 %)
        instead of sleeping in ``select`` (see :mod:`motionbase.pacing`).
    stale_timeout_s : float
        A tick is stale when its oldest part is older than this, s (> 0).
    drain_budget_s : float, optional
        How long a tick may go on reading the link past its due time, s (>= 0);
        None: :data:`DRAIN_BUDGET_PERIODS` of a period. Whatever is still queued
        then waits for the next tick (see :meth:`_pump_until`).

    Notes
    -----
    Subclasses set :attr:`kind` (messages) and :attr:`label` (log lines),
    extend :attr:`_COUNTERS`, and implement :meth:`_reader`; they may override
    :meth:`_service` and :meth:`_peer`. The constructor does not reset the
    state: a subclass calls :meth:`_reset_state` once its own fields are set.
    """

    kind = "live"
    label = "live source"
    #: counters of :attr:`_c` (subclasses add theirs in front)
    _COUNTERS: tuple[str, ...] = ("accepted", "ticks", "stale_ticks", "gaps", "late_ticks")

    def __init__(
        self,
        url: str,
        *,
        rate_hz: float = 100.0,
        duration_s: float | None = None,
        busy_wait: bool = False,
        stale_timeout_s: float = 0.5,
        drain_budget_s: float | None = None,
    ) -> None:
        k = self.kind
        self.url = url
        self.rate_hz = positive_number(k, "rate_hz", rate_hz, "Hz")
        self.stale_timeout_s = positive_number(k, "stale_timeout_s", stale_timeout_s, "s")
        if drain_budget_s is None:
            drain_budget_s = DRAIN_BUDGET_PERIODS / self.rate_hz
        self.drain_budget_s = positive_number(
            k, "drain_budget_s", drain_budget_s, "s", zero_ok=True
        )
        if duration_s is not None and not (
            isinstance(duration_s, int | float) and math.isfinite(duration_s) and duration_s > 0
        ):
            raise ConfigError(f"{k} duration_s: must be > 0 s or None, got {duration_s!r}")
        self.duration_s: float | None = None if duration_s is None else float(duration_s)
        #: "duration" once ``duration_s`` ended the ticks (io.base.EndingSource)
        self.ended = ""
        self.busy_wait = bool(busy_wait)
        self._iterating = False
        self.due_time: float | None = None  # when the last tick was due, monotonic s

    # ------------------------------------------------------------------ subclass hooks

    def _link(self) -> Any:
        """The open socket or connection, None when closed."""
        raise NotImplementedError

    def _reader(self, link: Any) -> tuple[Callable[[], bool], Any]:
        """For the open ``link``: a function that reads one datagram or message into the
        state (False when nothing is waiting), and the object to ``select`` on for more
        (None: poll every millisecond)."""
        raise NotImplementedError

    def _iterate(self) -> Iterator[AircraftState]:
        """The ticks of an open source (:meth:`_iter_live` by default)."""
        return self._iter_live()

    def _service(self, now: float) -> None:
        """Called once per live tick before the state is built (requests, subscriptions)."""

    def _peer(self) -> str:
        """What the stale and recovery log lines name after "no fresh sample" (e.g. the
        system id); empty by default."""
        return ""

    # ------------------------------------------------------------------ state

    def _reset_state(self) -> None:
        self._c: dict[str, int] = dict.fromkeys(self._COUNTERS, 0)
        self._values = [0.0, 0.0, -STANDARD_GRAVITY, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        self._times = [-math.inf] * N_SLOTS  # arrival of each slot's value, source clock s
        self._new = False
        self._tick = _NOT_STARTED
        self._was_fresh = False
        self._rate_window_start = math.nan
        self._rate_window_count = 0
        self._rate_hz = 0.0
        self._live_start = math.inf  # when live ticking began, monotonic s

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        """Open the link (called by ``with``)."""
        raise NotImplementedError

    def close(self) -> None:
        """Close the link. Idempotent."""
        raise NotImplementedError

    def __iter__(self) -> Iterator[AircraftState]:
        if self._link() is None:
            raise SourceError(
                f"{self.kind} source is not open; use 'with source: for state in source'"
            )
        if self._iterating:
            raise SourceError(f"{self.kind} source: already being iterated; make one iterator")
        return self._iterate()

    @property
    def tick(self) -> LiveTick:
        """Freshness of the state most recently yielded."""
        return self._tick

    @property
    def fresh(self) -> bool:
        """True when the state most recently yielded is fresh (see :class:`LiveTick`)."""
        return self._tick.fresh

    @property
    def sample_age_s(self) -> float:
        """Age of the state most recently yielded, s (inf before any sample)."""
        return self._tick.sample_age_s

    def _store(self, first: int, values: Any, arrival: float) -> None:
        """Put ``values`` in slots ``first, first + 1, ...``, arrived at ``arrival``."""
        v, t = self._values, self._times
        for i, x in enumerate(values, first):
            v[i] = float(x)
            t[i] = arrival
        self._new = True

    # ------------------------------------------------------------------ ticking

    def _tick_count(self) -> int | None:
        """Ticks in ``duration_s`` (at least one), or None without a duration."""
        if self.duration_s is None:
            return None
        n = self.duration_s * self.rate_hz  # (inf for a duration such as 1e308 s: no end)
        return max(1, round(n)) if math.isfinite(n) else None

    def _iter_live(self) -> Iterator[AircraftState]:
        """Ticks on the wall clock, reading the link between them."""
        period = 1.0 / self.rate_hz
        n_max = self._tick_count()
        self._iterating = True
        try:
            start = time.monotonic()
            self._live_start = start
            k = 0
            self.ended = ""
            while n_max is None or k < n_max:
                deadline = start + k * period
                self._pump_until(deadline)
                now = time.monotonic()
                if now - deadline > period:
                    self._c["late_ticks"] += 1
                    if now - deadline > 0.25:  # stalled: re-anchor the clock, keep k contiguous
                        start = now - k * period
                self._update_rate(now)
                self._service(now)
                self.due_time = deadline  # (the pipeline counts a late command from it)
                yield self._make_state(k, now)
                k += 1
            self.ended = "duration"
        finally:
            self._iterating = False

    def _pump_until(self, deadline: float) -> None:
        """Read what arrives until ``deadline`` (monotonic s), then return.

        Reading stops at ``deadline + drain_budget_s`` even while datagrams keep
        coming (after :data:`MIN_READS` reads in the pass at least): the rest stays
        queued in the socket for the next tick.
        """
        link = self._link()
        if link is None:
            raise SourceError(f"{self.kind} {self.url}: the source was closed while running")
        read_one, waitable = self._reader(link)
        busy = self.busy_wait
        clock = time.monotonic
        stop_reading = deadline + self.drain_budget_s
        while True:
            n = 0
            while read_one():
                n += 1
                if n >= MIN_READS and clock() >= stop_reading:
                    return  # the budget is spent: what is still queued waits for the next tick
            now = clock()
            remaining = deadline - now
            if remaining <= 0.0:
                return
            if busy:  # keep the processor: poll the link again in a moment
                wait_until(min(deadline, now + _POLL_S), busy=True, clock=clock)
                continue
            if waitable is None:
                time.sleep(min(remaining, 0.001))
                continue
            try:
                select.select([waitable], [], [], remaining)
            except (OSError, ValueError):
                time.sleep(min(remaining, 0.001))

    def _update_rate(self, now: float) -> None:
        if math.isnan(self._rate_window_start):
            self._rate_window_start = now
            self._rate_window_count = self._c["accepted"]
            return
        span = now - self._rate_window_start
        if span >= 1.0:
            self._rate_hz = (self._c["accepted"] - self._rate_window_count) / span
            self._rate_window_start = now
            self._rate_window_count = self._c["accepted"]

    def _make_state(self, k: int, now: float) -> AircraftState:
        """Tick k's state (a hold of the latest values) and its freshness at ``now``."""
        oldest = min(self._times)
        newest = max(self._times)
        age = now - oldest
        fresh = age <= self.stale_timeout_s
        self._tick = LiveTick(
            fresh=fresh,
            sample_age_s=age,
            new_sample=self._new,
            arrival_s=newest if math.isfinite(newest) else math.nan,
        )
        self._new = False
        c = self._c
        c["ticks"] += 1
        if not fresh:
            c["stale_ticks"] += 1
            if self._was_fresh:
                c["gaps"] += 1
                _log.warning(
                    "%s: no fresh sample%s for %.2f s; holding the last state, marked stale",
                    self.label,
                    self._peer(),
                    age,
                )
        elif not self._was_fresh and c["gaps"] > 0:
            _log.info("%s: fresh samples again%s", self.label, self._peer())
        self._was_fresh = fresh
        v = self._values
        return AircraftState(
            t=k / self.rate_hz,
            specific_force=v[F_SLOTS],
            angular_velocity=v[W_SLOTS],
            attitude=v[ATT_SLOTS],
        )


class UdpLiveSource(SampleHoldSource):
    """Base of the live UDP sources: one socket, fixed-rate ticks holding the latest sample.

    Parameters
    ----------
    url : str, optional
        The source URL, parsed by :meth:`_parse_url`; None takes :attr:`default_url`.
    rate_hz, duration_s, busy_wait, stale_timeout_s, drain_budget_s
        See :class:`SampleHoldSource`.
    free_port : bool
        The URL may listen on port 0, any free port (see :attr:`local_address`); False
        refuses it, as ``motionbase stream`` does: nobody could send to a port it does
        not show.

    Notes
    -----
    Subclasses set :attr:`kind`, :attr:`label` and :attr:`default_url`, and
    implement :meth:`_parse_url`, :meth:`_bind_address` and :meth:`_on_packet`;
    they may override :meth:`_on_open`, :meth:`_on_close`, :meth:`_service` and
    :meth:`_extra_stats`.
    """

    default_url = ""
    paces_itself = True  # ticks come on the wall clock: the pipeline's loop does not pace them
    _COUNTERS = (
        "received",
        "rejected_invalid",
        "bad_data",
        "bad_bytes",
        *SampleHoldSource._COUNTERS,
    )

    def __init__(
        self,
        url: str | None = None,
        *,
        rate_hz: float = 100.0,
        duration_s: float | None = None,
        busy_wait: bool = False,
        stale_timeout_s: float = 0.5,
        free_port: bool = True,
        drain_budget_s: float | None = None,
    ) -> None:
        if url is None:
            url = self.default_url
        if not isinstance(url, str):
            raise ConfigError(f"{self.kind} URL: expected a string, got {url!r}")
        self.free_port = bool(free_port)
        self._parse_url(url)
        super().__init__(
            url.strip(),
            rate_hz=rate_hz,
            duration_s=duration_s,
            busy_wait=busy_wait,
            stale_timeout_s=stale_timeout_s,
            drain_budget_s=drain_budget_s,
        )
        self._sock: socket.socket | None = None
        self._reset_state()

    # ------------------------------------------------------------------ subclass hooks

    def _parse_url(self, url: str) -> None:
        """Read the URL into attributes, or raise a one-line ConfigError (port 0 to listen
        on only with :attr:`free_port`)."""
        raise NotImplementedError

    def _bind_address(self) -> tuple[str, int]:
        """(host, port) to listen on."""
        raise NotImplementedError

    def _on_packet(self, data: bytes, addr: Any, arrival: float) -> None:
        """Decode one datagram; store accepted values with :meth:`_store`."""
        raise NotImplementedError

    def _on_open(self) -> None:
        """Called once the socket is bound (X-Plane: subscribe)."""

    def _on_close(self) -> None:
        """Called before the socket closes (X-Plane: unsubscribe)."""

    def _extra_stats(self) -> dict[str, Any]:
        """Source-specific figures for :attr:`stats`."""
        return {}

    # ------------------------------------------------------------------ lifecycle

    def open(self) -> None:
        """Bind the socket (called by ``with``).

        Raises
        ------
        SourceError
            The address does not resolve or the port cannot be bound.
        """
        if self._sock is not None:
            return
        host, port = self._bind_address()
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except OSError as exc:
            raise SourceError(
                f"{self.kind} {self.url}: cannot resolve {host!r} ({exc}); give an IP address "
                "of this machine, 127.0.0.1 or 0.0.0.0"
            ) from None
        family, _, _, _, sockaddr = infos[0]
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.bind(sockaddr)
        except OSError as exc:
            sock.close()
            raise SourceError(
                f"{self.kind} {self.url}: cannot listen on {host}:{port} ({exc.strerror}); "
                + bind_fix(exc, "is the address not on this machine?")
            ) from None
        sock.setblocking(False)
        self._reset_state()
        self._sock = sock
        if not is_loopback(host):
            _log.warning("%s: listening on %s (not loopback), as requested", self.label, host)
        try:
            self._on_open()
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Close the socket (after :meth:`_on_close`). Idempotent."""
        sock = self._sock
        if sock is None:
            return
        try:
            self._on_close()
        finally:
            self._sock = None
            sock.close()

    @property
    def local_address(self) -> tuple[str, int] | None:
        """(host, port) the socket is bound to, or None when closed."""
        if self._sock is None:
            return None
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    # ------------------------------------------------------------------ public state

    @property
    def stats(self) -> LiveStats:
        """A frozen snapshot of the counters."""
        return LiveStats(
            **self._c,
            last_sample_age_s=self._tick.sample_age_s,
            message_rate_hz=self._rate_hz,
            extra=MappingProxyType(self._extra_stats()),
        )

    def stats_line(self) -> str:
        """One line for the end of a run: datagrams, rejects, stale ticks."""
        st = self.stats
        extra = "".join(f", {k} {v}" for k, v in st.extra.items())
        return (
            f"{self.label}: {st.received} datagrams received, {st.accepted} used, "
            f"{st.rejected_invalid} rejected as invalid, {st.bad_data} not {self.label} "
            f"data; {st.stale_ticks} of {st.ticks} ticks stale, {st.gaps} gaps{extra}"
        )

    def describe(self) -> dict[str, Any]:
        """Plain-data description for the log's metadata."""
        return {
            "kind": self.kind,
            "url": self.url,
            "rate_hz": self.rate_hz,
            "duration_s": self.duration_s,
            "busy_wait": self.busy_wait,
            "stale_timeout_s": self.stale_timeout_s,
        }

    # ------------------------------------------------------------------ helpers for subclasses

    def _send(self, data: bytes, addr: Any) -> None:
        """Send one datagram from the listening socket; a failure is logged, not raised."""
        if self._sock is None:
            return
        try:
            self._sock.sendto(data, addr)
        except OSError as exc:
            _log.debug("%s: send to %s failed: %s", self.label, addr, exc)

    # ------------------------------------------------------------------ iteration

    def _link(self) -> socket.socket | None:
        return self._sock

    def _reader(self, sock: socket.socket) -> tuple[Callable[[], bool], Any]:
        recvfrom = sock.recvfrom
        on_packet = self._on_packet
        c = self._c
        clock = time.monotonic

        def read_one() -> bool:
            try:
                data, addr = recvfrom(_RECV_BYTES)
            except BlockingIOError:
                return False
            except (ConnectionRefusedError, ConnectionResetError):
                return True  # an ICMP error for an earlier send (Windows reports these)
            except OSError as exc:
                raise SourceError(f"{self.kind} {self.url}: socket failed ({exc})") from None
            c["received"] += 1
            on_packet(data, addr, clock())
            return True

        return read_one, sock
