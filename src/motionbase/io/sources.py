"""Choosing the live source of ``motionbase stream`` by its URL.

* ``fgnative:udp:HOST:PORT``: FlightGear (or JSBSim) native-FDM packets,
  :class:`~motionbase.io.fgnative_source.FgNativeSource`;
* ``xplane:HOST:PORT[?listen=...&version=...]``: X-Plane 11 or 12,
  :class:`~motionbase.io.xplane_source.XPlaneSource`;
* no URL: MAVLink, :class:`~motionbase.io.mavlink_source.MavlinkSource`, on the
  pymavlink connection string (or log file) given as ``mavlink``.
"""

from __future__ import annotations

import os
from typing import Any

from motionbase.errors import ConfigError

__all__ = ["DEFAULT_MAVLINK", "LIVE_SCHEMES", "open_live_source", "stats_line"]

LIVE_SCHEMES = ("fgnative", "xplane")
"""URL schemes of the simulator sources (MAVLink has its own option)."""

DEFAULT_MAVLINK = "udpin:127.0.0.1:14550"
"""The MAVLink link when no source is named: listen on loopback only."""

_EXAMPLES = "fgnative:udp:0.0.0.0:5500 or xplane:127.0.0.1:49000"


def open_live_source(
    url: str | None,
    *,
    mavlink: str | None = None,
    rate_hz: float = 100.0,
    duration_s: float | None = None,
    realtime: bool = True,
    busy_wait: bool = False,
    stale_timeout_s: float = 0.5,
    free_port: bool = True,
    **mavlink_options: Any,
) -> Any:
    """The source for a URL, not yet entered (use it in a ``with`` block).

    Parameters
    ----------
    url : str or None
        ``fgnative:udp:HOST:PORT`` or ``xplane:HOST:PORT[?...]``; None for MAVLink.
    mavlink : str, optional
        The pymavlink connection string or log file (default :data:`DEFAULT_MAVLINK`);
        not with ``url``: one source at a time.
    rate_hz : float
        Pipeline rate, Hz: every source ticks at it, holding its latest sample.
    duration_s : float, optional
        Stop after this long, s.
    realtime : bool
        MAVLink logs only: replay at the recorded timing (False: as fast as
        possible). A simulator or a live MAVLink link is always live (False is
        refused).
    busy_wait : bool
        Wait for each tick by busy-waiting (see :mod:`motionbase.pacing`).
    stale_timeout_s : float
        The watchdog's timeout, s.
    free_port : bool
        A source that listens may do so on port 0, any free port (read back from its
        ``local_address``); False refuses port 0, as ``motionbase stream`` does.
    **mavlink_options
        ``sysid``, ``compid``, ``signing_key`` (and the other keywords of
        :class:`~motionbase.io.mavlink_source.MavlinkSource`): MAVLink only. None
        leaves one unset (``sysid`` 1, every component, no signing), and is the only
        value allowed with ``url``.

    Raises
    ------
    ConfigError
        An unknown URL scheme, a malformed URL, a MAVLink link and a simulator URL
        both, a MAVLink-only option with a simulator URL, or ``realtime`` False with a
        live source (one line saying what to write instead).
    """
    if url is not None and mavlink is not None:
        raise ConfigError(
            f"--mavlink {mavlink} and --source {url}: one source at a time; drop one of them"
        )
    if url is None:
        from motionbase.io.mavlink_source import MavlinkSource

        source = MavlinkSource(
            DEFAULT_MAVLINK if mavlink is None else mavlink,
            rate_hz=rate_hz,
            duration_s=duration_s,
            realtime=realtime,
            busy_wait=busy_wait,
            stale_timeout_s=stale_timeout_s,
            free_port=free_port,
            **{k: v for k, v in mavlink_options.items() if v is not None},
        )
        if not realtime and not source.is_log:
            if ":" not in source.url and not os.path.exists(source.url):  # no link, no file
                raise ConfigError(
                    f"mavlink {source.url}: no such log (--fast replays a MAVLink log file, "
                    "named .tlog or .bin; check the path)"
                )
            raise ConfigError(
                f"--fast replays MAVLink log files; {source.url} is live: drop --fast"
            )
        return source
    if not isinstance(url, str) or not url.strip():
        raise ConfigError(f"--source: empty URL; give e.g. {_EXAMPLES}")
    scheme = url.strip().partition(":")[0].lower()
    if scheme not in LIVE_SCHEMES:
        hint = (
            "; MAVLink connections go in --mavlink"
            if scheme in ("udpin", "udpout", "udp", "tcp", "tcpin", "serial", "com")
            or url.startswith("/dev/")
            else ""
        )
        raise ConfigError(f"--source {url!r}: unknown kind {scheme!r}; give {_EXAMPLES}{hint}")
    used = sorted(k for k, v in mavlink_options.items() if v is not None)
    if used:
        names = ", ".join("--" + k.replace("_", "-") for k in used)
        what, them = ("a MAVLink option", "it") if len(used) == 1 else ("MAVLink options", "them")
        raise ConfigError(f"{names}: {what}, not for --source {url}; drop {them}")
    if not realtime:
        raise ConfigError(f"--fast replays MAVLink log files; {url} is live: drop --fast")
    options = dict(
        rate_hz=rate_hz,
        duration_s=duration_s,
        busy_wait=busy_wait,
        stale_timeout_s=stale_timeout_s,
        free_port=free_port,
    )
    if scheme == "fgnative":
        from motionbase.io.fgnative_source import FgNativeSource

        return FgNativeSource(url, **options)
    from motionbase.io.xplane_source import XPlaneSource

    return XPlaneSource(url, **options)


def stats_line(source: Any) -> str:
    """One line of counters for the end of a ``stream`` run, whatever the source."""
    return source.stats_line()
