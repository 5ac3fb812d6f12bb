"""X-Plane 11 and 12 over UDP (RREF subscriptions, or the legacy DATA output) as a live source.

URL: ``xplane:HOST:PORT`` with X-Plane's address and receive port (49000 unless
changed in X-Plane's network settings), and optional query parameters:

* ``listen=[ADDR:]PORT``: where this source listens, and where X-Plane's Data
  Output must send to for the legacy ``DATA`` packets. Default port 49005, on
  ``127.0.0.1`` when X-Plane is on this machine, else on ``0.0.0.0``. RREF
  answers come back to this address by themselves.
* ``version=11`` or ``version=12``: the X-Plane version, needed only to read
  ``DATA`` group 16 when X-Plane does not answer RREF requests (otherwise the
  source asks X-Plane, ``sim/version/xplane_internal_version``).

Example: ``xplane:192.168.1.20:49000?listen=49005``.

Sources for the formats (the code is written from them, not copied):
X-Plane's own "Exchanging Data with X-Plane.rtfd" (in ``Instructions/`` of an
X-Plane 11 or 12 installation: sections "SEND ME ALL THE DATAREFS I WANT: RREF"
and "SET A DATA OUTPUT TO A VALUE: DATA"), X-Plane's ``DataRefs.txt``
(``Resources/plugins/``), and open implementations that fly with these values
(listed with the signs under "References" below).

RREF (the default, nothing to set up in X-Plane beyond accepting incoming UDP)
------------------------------------------------------------------------------
Request, one per dataref, to HOST:PORT: ``"RREF\\0"`` + ``int32 freq`` +
``int32 index`` + the dataref path null-padded to 400 bytes (413 bytes,
little endian). ``freq`` is the number of answers per second (the pipeline
rate here); 0 stops the subscription, which this source sends for every
dataref when it closes. X-Plane answers to the requesting address and port
with ``"RREF"`` + one byte + ``(int32 index, float32 value)`` pairs, little
endian. The datarefs and their conversions:

======================================= ===================== =========================
dataref                                  X-Plane unit, sign    here
======================================= ===================== =========================
``sim/flightmodel/forces/g_axil``        g, aft positive       ``f_x = -g0 * g_axil``
``sim/flightmodel/forces/g_side``        g, right positive     ``f_y = +g0 * g_side``
``sim/flightmodel/forces/g_nrml``        g, up positive (1)    ``f_z = -g0 * g_nrml``
``sim/flightmodel/position/P, Q, R``     deg/s, body FRD       rad/s
``sim/flightmodel/position/phi, theta``  deg                   roll, pitch, rad
``sim/flightmodel/position/psi``         deg true, [0, 360)    yaw, rad, [-pi, pi)
======================================= ===================== =========================

The g-loads are the total non-gravitational force over the weight on X-Plane's
aircraft axes (ACF X right, Y up, Z aft), i.e. the specific force in g on those
axes (``g_nrml`` = 1 in level flight); FRD is (-Z, X, -Y), times g0 = 9.80665
m/s^2: a take-off roll (thrust forward) gives ``g_axil < 0`` and ``f_x > 0``, a
force pushing the airplane right gives ``g_side > 0`` and ``f_y > 0``.
``sim/version/xplane_internal_version`` is asked once a second (e.g. 120100 for
12.1.0).

Restarts: when no RREF answer has arrived for 1 s, the subscriptions are sent
again, once a second, until answers come back (an X-Plane that restarts has
forgotten them).

DATA (legacy: Settings > Data Output, "Network via UDP" ticked for the rows below)
-------------------------------------------------------------------------------
``"DATA"`` + one byte + 36-byte records, each ``int32 group`` + 8 ``float32``
(little endian). Groups read (0-based value positions):

* 4 "Mach, VVI, g-load": values 4, 5, 6 = g normal, axial, side, read as the
  same quantities and signs as ``g_nrml``, ``g_axil``, ``g_side``.
* 16 "Angular velocities": X-Plane 12 gives P, Q, R in deg/s; X-Plane 11 gives
  Q, P, R in rad/s (ArduPilot's SIM_XPlane.cpp reads them so). Ignored, with one
  warning, until the version is known.
* 17 "Pitch, roll, headings": values 0, 1, 2 = pitch, roll, true heading, deg.

References for the axes, signs and units (read, not copied):

* ``DataRefs.txt`` (X-Plane 12): ``forces/fside_plug_acf`` "ACF X axis, positive
  pushes airplane to the right", ``fnrml_plug_acf`` "ACF Y axis, positive pushes
  airplane up", ``faxil_plug_acf`` "ACF Z axis, positive pushes airplane
  backward", ``faxil_prop`` "Force backward ... (usually this is a negative
  number)"; ``override_forces``: "write to LMN and g_nrml/side/axil";
  ``position/P, Q, R`` deg/sec (``Prad, Qrad, Rrad`` rad/sec); ``phi, theta``
  deg; ``psi`` "true heading ... deg".
* Laminar's SDK sample MotionPlatformData (developer.x-plane.com/code-sample/
  motionplatformdata): motion-platform accelerations as the fside, fnrml, faxil
  force sums (ACF X, Y, Z) over the mass.
* px4xplane (github.com/alireza787b/px4xplane, ``src/MAVLinkManager.cpp``,
  v3.4.3, JOURNEY_LOG.md): FRD accelerometer ``(-g_axil, +g_side, -g_nrml) g``,
  fitted against accelerations from X-Plane 11 and 12 truth captures (Y error
  0.03 m/s^2 with ``+g_side``, 0.22 with ``-g_side``); gyro ``Prad, Qrad, Rrad``.
* INAV ``src/main/target/SITL/sim/xplane.c``: gyro from ``P, Q, R`` deg/s in
  FRD (``(P, -Q, -R)`` in its FLU frame), ``-g_axil`` forward, ``g_nrml`` up;
  its side sign (``-g_side`` right) disagrees with the three above.
* DATA users, ArduPilot ``libraries/SITL/SIM_XPlane.cpp`` (also PR 22972),
  QGroundControl ``src/comm/QGCXPlaneLink.cc``, TauLabs
  ``ground/gcs/src/plugins/hitl/xplanesimulator.cpp``, Mission Planner
  ``ExtLibs/HIL/XPlane.cs``: group 4 values 4, 5, 6 = normal, axial, side,
  ``f = (axial, side, -normal) g``: they agree on side and normal; their
  ``+axial`` (one lineage; none shows a check against a take-off) disagrees
  with the dataref evidence above and is not followed. Group 16 rates: X-Plane 12
  P, Q, R deg/s; 11 (and 10) Q, P, R rad/s. Group 17: pitch, roll, true heading.

While RREF values are fresh, DATA values for the same quantities are ignored
(one stream at a time, not two interleaved). Datagrams from another host than
HOST are refused (counted; when nothing came from HOST, the silence warning names the
last refused sender). A value that is NaN, infinite or absurd (beyond the
pipeline's plausibility bounds, :mod:`motionbase.physics`: 150 m/s^2, 20 rad/s; an
angle out of range) is rejected and counted; the rest of its datagram is still used.
"""

from __future__ import annotations

import logging
import math
import socket
import struct
import time
from typing import Any
from urllib.parse import parse_qs

from motionbase.errors import ConfigError, SourceError
from motionbase.io.live_source import (
    UdpLiveSource,
    attitude_ok,
    finite_within,
    is_loopback,
    split_host_port,
    wrap_pi,
)
from motionbase.io.net_address import check_host_port, check_port
from motionbase.physics import MAX_ANGULAR_VELOCITY, MAX_SPECIFIC_FORCE, STANDARD_GRAVITY

__all__ = ["DATAREFS", "DEFAULT_LISTEN_PORT", "XPlaneSource", "parse_xplane_url"]

_log = logging.getLogger("motionbase")

DEFAULT_LISTEN_PORT = 49005
"""Where the source listens by default (and where X-Plane's Data Output should send)."""

#: subscribed datarefs, in slot order (specific force, body rates, attitude)
DATAREFS: tuple[str, ...] = (
    "sim/flightmodel/forces/g_axil",
    "sim/flightmodel/forces/g_side",
    "sim/flightmodel/forces/g_nrml",
    "sim/flightmodel/position/P",
    "sim/flightmodel/position/Q",
    "sim/flightmodel/position/R",
    "sim/flightmodel/position/phi",
    "sim/flightmodel/position/theta",
    "sim/flightmodel/position/psi",
)
VERSION_DATAREF = "sim/version/xplane_internal_version"

_INDEX_BASE = 1700  # RREF indices: 1700 + slot; the version dataref is 1700 + 9
_VERSION_INDEX = _INDEX_BASE + len(DATAREFS)
_RREF_REQUEST = struct.Struct("<4sxii400s")  # "RREF\0", freq, index, path[400]
_RREF_PAIR = struct.Struct("<if")
_DATA_RECORD = struct.Struct("<i8f")
_RESUBSCRIBE_S = 1.0  # RREF silence before subscribing again, s
_SILENT_WARN_S = 3.0  # silence after the first subscription before one warning, s
_RAD = math.pi / 180.0

# g_axil, g_side, g_nrml (X-Plane's aircraft axes: aft, right, up) -> specific force FRD, m/s^2
_G_SCALE = (-STANDARD_GRAVITY, STANDARD_GRAVITY, -STANDARD_GRAVITY)


def parse_xplane_url(url: str, *, free_port: bool = True) -> tuple[str, int, str, int, int | None]:
    """Parse ``xplane:HOST:PORT[?listen=[ADDR:]PORT][&version=11|12]``.

    ``listen`` may give port 0 (any free port) only with ``free_port``; X-Plane's port
    is never 0.

    Returns
    -------
    host, port : str, int
        X-Plane's address and receive port.
    listen_host, listen_port : str, int
        Where to listen.
    version : int or None
        The X-Plane major version given, if any.

    Raises
    ------
    ConfigError
        One line naming what is wrong, with an example (X-Plane's host name that does not
        resolve, too).
    """
    example = "e.g. xplane:127.0.0.1:49000 or xplane:192.168.1.20:49000?listen=49005"
    text = url.strip()
    if not text.lower().startswith("xplane:"):
        raise ConfigError(f"xplane URL {url!r}: must start with xplane: ({example})")
    addr, _, query = text[len("xplane:") :].partition("?")
    host, port = split_host_port(addr, f"xplane URL {url!r}", example, free_port=False)
    check_host_port(f"xplane URL {url!r}", host, str(port))  # resolves, before anything listens
    listen_host = "127.0.0.1" if is_loopback(host) else "0.0.0.0"
    listen_port = DEFAULT_LISTEN_PORT
    version: int | None = None
    try:
        params = parse_qs(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise ConfigError(
            f"xplane URL {url!r}: cannot read the query {query!r} ({example})"
        ) from None
    for key, values in params.items():
        value = values[-1]
        if key == "listen":
            what, listen_example = f"xplane URL {url!r}: listen", "e.g. listen=0.0.0.0:49005"
            if ":" in value:
                listen_host, listen_port = split_host_port(
                    value, what, listen_example, free_port=free_port
                )
            else:
                listen_port = check_port(what, value, free_port=free_port, example=listen_example)
        elif key == "version":
            if value not in ("11", "12"):
                raise ConfigError(
                    f"xplane URL {url!r}: version must be 11 or 12, got {value!r} ({example})"
                )
            version = int(value)
        else:
            raise ConfigError(
                f"xplane URL {url!r}: unknown option {key!r} (known: listen, version; {example})"
            )
    if port == listen_port and (is_loopback(host) or host == listen_host):
        raise ConfigError(  # (it subscribed to itself and read its requests as answers)
            f"xplane URL {url!r}: X-Plane's port {port} is the port motionbase listens on; give "
            f"X-Plane's own receive port (49000 unless changed in its network settings) ({example})"
        )
    return host, port, listen_host, listen_port, version


def _rref_request(freq: int, index: int, path: str) -> bytes:
    return _RREF_REQUEST.pack(b"RREF", freq, index, path.encode("ascii"))


class XPlaneSource(UdpLiveSource):
    """Aircraft states from X-Plane 11 or 12 (RREF or DATA over UDP), at a fixed rate.

    Parameters
    ----------
    url : str, optional
        ``xplane:HOST:PORT[?listen=[ADDR:]PORT][&version=11|12]`` (see the module
        docstring). Default ``xplane:127.0.0.1:49000``.
    rate_hz, duration_s, busy_wait, stale_timeout_s, free_port, drain_budget_s
        See :class:`~motionbase.io.live_source.UdpLiveSource`. The datarefs are
        requested at ``rate_hz`` answers per second (X-Plane sends at most one
        per frame).

    Examples
    --------
    >>> with XPlaneSource("xplane:127.0.0.1:49000") as src:  # doctest: +SKIP
    ...     for state in src:
    ...         ...
    """

    kind = "xplane"
    label = "X-Plane"
    default_url = "xplane:127.0.0.1:49000"

    def _parse_url(self, url: str) -> None:
        (
            self.host,
            self.port,
            self.listen_host,
            self.listen_port,
            self.version_given,
        ) = parse_xplane_url(url, free_port=self.free_port)

    @property
    def freq(self) -> int:
        """Answers per second asked of X-Plane for each dataref: the rate, at least 1."""
        return max(1, round(self.rate_hz))

    # ------------------------------------------------------------------ lifecycle

    def _reset_state(self) -> None:
        super()._reset_state()
        self._rref_times = [-math.inf] * len(DATAREFS)  # last RREF value per slot
        self._last_rref = -math.inf  # arrival of the last RREF answer of ours
        self._sub_time = -math.inf  # when the subscriptions were last sent
        self._first_sub = -math.inf
        self._subscriptions = 0  # times the subscriptions were sent
        self._resubscribing = False
        self._warned_silent = False
        self._warned_rates = False
        self._internal_version: int | None = None
        self._x = dict.fromkeys(
            ("rref", "data", "unknown_index", "other_host", "data_groups_ignored"), 0
        )
        self._xplane_addr: Any = None  # X-Plane's address, once resolved at open
        self._xplane_ips: frozenset[str] = frozenset()
        self._other_host = ""  # the last host whose datagrams were refused

    def _bind_address(self) -> tuple[str, int]:
        return self.listen_host, self.listen_port

    def _on_open(self) -> None:
        assert self._sock is not None
        try:
            infos = socket.getaddrinfo(self.host, self.port, self._sock.family, socket.SOCK_DGRAM)
        except OSError as exc:
            raise SourceError(
                f"xplane {self.url}: cannot resolve X-Plane's host {self.host!r} ({exc}); give "
                "the IP address of the PC that runs X-Plane"
            ) from None
        self._xplane_addr = infos[0][4]
        self._xplane_ips = frozenset(str(i[4][0]) for i in infos)
        self._subscribe(time.monotonic())

    def _on_close(self) -> None:
        if self._xplane_addr is None or self._subscriptions == 0:
            return
        for index, path in self._requests():
            self._send(_rref_request(0, index, path), self._xplane_addr)

    def _requests(self) -> list[tuple[int, str]]:
        out = [(_INDEX_BASE + i, path) for i, path in enumerate(DATAREFS)]
        out.append((_VERSION_INDEX, VERSION_DATAREF))
        return out

    def _subscribe(self, now: float) -> None:
        for index, path in self._requests():
            freq = 1 if index == _VERSION_INDEX else self.freq
            self._send(_rref_request(freq, index, path), self._xplane_addr)
        self._sub_time = now
        if self._subscriptions == 0:
            self._first_sub = now
        self._subscriptions += 1

    def _service(self, now: float) -> None:
        """Subscribe again while X-Plane is silent (it forgets subscriptions when restarted)."""
        if self._xplane_addr is None:
            return
        if now - self._last_rref < _RESUBSCRIBE_S:
            return
        if math.isfinite(self._last_rref) and not self._resubscribing:
            self._resubscribing = True
            _log.warning(
                "X-Plane: no RREF answer from %s:%d for %.1f s (restarted?); subscribing again "
                "every %.0f s",
                self.host,
                self.port,
                now - self._last_rref,
                _RESUBSCRIBE_S,
            )
        if (
            not self._warned_silent
            and self._c["accepted"] == 0
            and now - self._first_sub >= _SILENT_WARN_S
        ):
            self._warned_silent = True
            _log.warning("%s", self._silence_hint(now - self._first_sub))
        if now - self._sub_time >= _RESUBSCRIBE_S:
            self._subscribe(now)

    def _silence_hint(self, silent_s: float) -> str:
        """The warning for an X-Plane silent ``silent_s`` s after subscribing: the refused
        sender, when datagrams came from another host (X-Plane's Data Output sending from
        another address), else where X-Plane must send to."""
        head = f"X-Plane: nothing from {self.host}:{self.port} {silent_s:.0f} s after subscribing"
        if self._other_host:
            return (
                f"{head}, but {self._x['other_host']} datagrams from {self._other_host} were "
                f"refused (not X-Plane's host); if X-Plane runs there, give its address: "
                f"xplane:{self._other_host}:{self.port}"
            )
        host, port = self.local_address or (self.listen_host, self.listen_port)
        if host in ("0.0.0.0", "::"):  # (listening on every address: no place to send to)
            host = "this PC's IP address"
        return (
            f"{head}; in X-Plane, allow incoming UDP (Settings > Network) or set Data Output "
            f"to send to {host}, port {port}"
        )

    # ------------------------------------------------------------------ packets

    def _on_packet(self, data: bytes, addr: Any, arrival: float) -> None:
        c, x = self._c, self._x
        if addr[0] not in self._xplane_ips:
            x["other_host"] += 1
            self._other_host = str(addr[0])
            c["bad_data"] += 1
            c["bad_bytes"] += len(data)
            return
        head = data[:4]
        if head == b"RREF" and len(data) >= 5 and (len(data) - 5) % 8 == 0:
            used = self._on_rref(data, arrival)
            x["rref"] += 1
        elif head == b"DATA" and len(data) >= 5 and (len(data) - 5) % 36 == 0:
            used = self._on_data(data, arrival)
            x["data"] += 1
        else:
            c["bad_data"] += 1
            c["bad_bytes"] += len(data)
            return
        if used:
            c["accepted"] += 1

    def _on_rref(self, data: bytes, arrival: float) -> bool:
        c = self._c
        used = False
        ours = False
        for index, value in _RREF_PAIR.iter_unpack(memoryview(data)[5:]):
            slot = index - _INDEX_BASE
            if 0 <= slot < len(DATAREFS):
                ours = True
                converted = self._convert(slot, value)
                if converted is None:
                    c["rejected_invalid"] += 1
                    continue
                self._store(slot, (converted,), arrival)
                self._rref_times[slot] = arrival
                used = True
            elif index == _VERSION_INDEX:
                ours = True
                if math.isfinite(value) and 1e4 <= value < 1e7:
                    self._set_version(int(value))
            else:
                self._x["unknown_index"] += 1
        if ours:
            self._last_rref = arrival
            if self._resubscribing:
                self._resubscribing = False
                _log.info("X-Plane: RREF answers again from %s:%d", self.host, self.port)
        return used

    def _set_version(self, internal: int) -> None:
        if self._internal_version != internal:
            self._internal_version = internal
            _log.info("X-Plane: version %d (internal %d)", internal // 10000, internal)

    @property
    def xplane_major(self) -> int | None:
        """X-Plane's major version: from its answer, else from the URL's ``version``."""
        if self._internal_version is not None:
            return self._internal_version // 10000
        return self.version_given

    @staticmethod
    def _convert(slot: int, value: float) -> float | None:
        """One dataref value in X-Plane's units to SI and FRD, or None when invalid."""
        if slot < 3:
            f = _G_SCALE[slot] * value
            return f if -MAX_SPECIFIC_FORCE <= f <= MAX_SPECIFIC_FORCE else None
        if slot < 6:
            w = value * _RAD
            return w if -MAX_ANGULAR_VELOCITY <= w <= MAX_ANGULAR_VELOCITY else None
        a = value * _RAD
        if slot == 6:
            ok = attitude_ok(a, 0.0, 0.0)
        elif slot == 7:
            ok = attitude_ok(0.0, a, 0.0)
        else:
            ok = attitude_ok(0.0, 0.0, a)
            a = wrap_pi(a) if ok else a
        return a if ok else None

    def _on_data(self, data: bytes, arrival: float) -> bool:
        c = self._c
        used = False
        for rec in _DATA_RECORD.iter_unpack(memoryview(data)[5:]):
            group, v = rec[0], rec[1:]
            if group == 4:
                first, values = 0, (_G_SCALE[0] * v[5], _G_SCALE[1] * v[6], _G_SCALE[2] * v[4])
                ok = finite_within(values, MAX_SPECIFIC_FORCE)
            elif group == 16:
                major = self.xplane_major
                if major is None or major < 11:
                    self._x["data_groups_ignored"] += 1
                    if not self._warned_rates:
                        self._warned_rates = True
                        _log.warning(
                            "X-Plane: DATA group 16 (angular velocities) differs between X-Plane "
                            "11 and 12 and X-Plane does not say which it is; add ?version=11 or "
                            "?version=12 to the URL (or allow incoming UDP in X-Plane)"
                        )
                    continue
                if major >= 12:
                    values = (v[0] * _RAD, v[1] * _RAD, v[2] * _RAD)  # P, Q, R deg/s
                else:
                    values = (v[1], v[0], v[2])  # X-Plane 11: Q, P, R in rad/s
                first = 3
                ok = finite_within(values, MAX_ANGULAR_VELOCITY)
            elif group == 17:
                first = 6
                values = (v[1] * _RAD, v[0] * _RAD, v[2] * _RAD)  # roll, pitch, heading
                ok = attitude_ok(*values)
                if ok:
                    values = (values[0], values[1], wrap_pi(values[2]))
            else:
                self._x["data_groups_ignored"] += 1
                continue
            if not ok:
                c["rejected_invalid"] += 1
                continue
            # one stream at a time: skip while RREF values of these slots are fresh
            if arrival - max(self._rref_times[first : first + 3]) <= self.stale_timeout_s:
                continue
            self._store(first, values, arrival)
            used = True
        return used

    # ------------------------------------------------------------------ reporting

    def _extra_stats(self) -> dict[str, Any]:
        x = self._x
        out: dict[str, Any] = {
            "RREF datagrams": x["rref"],
            "DATA datagrams": x["data"],
            "subscriptions sent": self._subscriptions,
        }
        if self.xplane_major is not None:
            out["X-Plane version"] = self.xplane_major
        if x["other_host"]:
            out["from other hosts"] = x["other_host"]
        return out

    def describe(self) -> dict[str, Any]:
        """Plain-data description for the log's metadata."""
        out = super().describe()
        out.update(
            xplane=f"{self.host}:{self.port}",
            listen=f"{self.listen_host}:{self.listen_port}",
            rref_freq_hz=self.freq,
            datarefs=list(DATAREFS),
            data_groups=[4, 16, 17],
            version_given=self.version_given,
            xplane_internal_version=self._internal_version,
        )
        return out
