"""FlightGear's native FDM protocol (``FGNetFDM``) over UDP as a fixed-rate live source.

FlightGear sends it with ``--native-fdm=socket,out,HZ,HOST,PORT,udp``; JSBSim
sends the same packet through its ``<output type="FLIGHTGEAR" ...>`` directive.
URL: ``fgnative:udp:HOST:PORT`` (listen on HOST:PORT; ``0.0.0.0`` to hear a
simulator on another PC, port 0 picks a free one, see ``local_address``).

The packet
----------
The layout below is written from the documented structure, not copied: the
``FGNetFDM`` class of FlightGear's ``src/Network/net_fdm.hxx`` (version 24 in
every release up to 2020.3, version 25 on FlightGear's ``next`` branch since
October 2020, so in 2024.1 and later) and JSBSim's ``src/input_output/net_fdm.hxx``
(version 24, filled by ``FGOutputFG::SocketDataFill`` in ``FGOutputFG.cpp``). Network
byte order (big endian), no padding: ``uint32 version, uint32 padding``, three ``double``
(longitude, latitude, altitude), then ``float`` from ``agl`` on. Versions 24 and
25 differ only after the engine block (25 adds per-tank selection and volumes),
so every field read here sits at the same offset in both; a datagram is checked
against its version's full size (408 and 552 bytes).

Fields used, and the conversions at this edge:

* ``phi, theta, psi`` (offset 36): Euler angles, rad, ``float``. ``psi`` is
  wrapped to [-pi, pi).
* ``phidot, thetadot, psidot`` (offset 56): the *Euler angle rates*, rad/s, not
  the body rates: JSBSim fills them from ``FGAuxiliary::GetEulerRates`` and
  FlightGear from ``get_Phi_dot_degps`` & co. (``/orientation/roll-rate-degps``,
  its Euler rates). The body rates follow from the angles:
  ``p = phidot - psidot sin(theta)``,
  ``q = thetadot cos(phi) + psidot sin(phi) cos(theta)``,
  ``r = -thetadot sin(phi) + psidot cos(phi) cos(theta)``. FlightGear's YASim
  fills them otherwise (``Glue::calcEulerRates``): ``p``, ``thetadot`` and the rate
  about the vertical, ``psidot - phidot sin(theta)``; exact in level flight, off by
  about ``sin(theta)`` times the rates when pitched (1 deg/s of roll rate in a
  10 deg climbing turn at 6 deg/s; a quarter of a 1 rad/s roll at 30 deg of pitch).
  The packet says nothing of the FDM, so this is left as it is.
* ``A_X_pilot, A_Y_pilot, A_Z_pilot`` (offset 100): the specific force at the
  pilot's eye point, body axes FRD, ft/s^2 (times 0.3048). It is what an
  accelerometer reads, not the kinematic acceleration: JSBSim's
  ``GetPilotAccel`` is ``accelerations/a-pilot-*-ft_sec2``, about
  (0, 0, -32.2) ft/s^2 at rest on the runway (checked on real packets in
  ``tests/test_fgnative_source.py``); YASim's ``getPilotAccel`` adds the
  gravity term the same way.

An unknown version is refused: its datagrams are counted as ``bad_data`` and
one warning per distinct version number is logged, for the first three (the run goes on:
the watchdog holds the platform at neutral while nothing valid arrives). A datagram
shorter than the smallest FGNetFDM (408 bytes) and of no known version is not taken for
a new version: it is counted as too short, with one warning for the first. A datagram
of a known version but not its size (one warning for the first: FlightGear's builds of
July to October 2020 sent version 24 in the 552-byte layout), or with a NaN, infinite or
absurd value (a specific force or a body rate beyond the pipeline's plausibility bounds,
:mod:`motionbase.physics`: 150 m/s^2, 20 rad/s; an angle out of range), is rejected whole
and counted. A pilot's acceleration of exactly zero is taken (it may be a free fall),
but a second of it is warned of once: FlightGear's UFO, magic-carpet and null flight
models, and JSBSim held down, do not fill it.

One sender at a time: while the datagrams of one address are fresh (one accepted at
most ``stale_timeout_s`` ago), those of any other address are refused, counted as
``bad_data`` (``other senders``) with one warning; two interleaved streams would
take turns in the state. A new address (a restarted FlightGear) is taken once the
first one is stale.
"""

from __future__ import annotations

import logging
import math
import struct
from typing import Any

import numpy as np

from motionbase.errors import ConfigError
from motionbase.io.live_source import (
    UdpLiveSource,
    attitude_ok,
    finite_within,
    split_host_port,
    wrap_pi,
)
from motionbase.physics import (
    MAX_ANGULAR_VELOCITY,
    MAX_SPECIFIC_FORCE,
    body_rates_from_euler_rates,
)

__all__ = ["FG_NET_FDM_SIZES", "FgNativeSource", "decode_fgnetfdm", "parse_fgnative_url"]

_log = logging.getLogger("motionbase")

FT_TO_M = 0.3048

# FGNetFDM version 24, big endian, field by field (net_fdm.hxx): header, position,
# attitude & aero angles, 11 velocities, 3 pilot accelerations, stall, engines (num + 4
# states + 9 x 4 floats), tanks (num + 4), gear (num + 3 wow + 3 x 3 floats),
# environment (cur_time, warp, visibility), 10 control surfaces.
_V24 = ">II 3d 6f 11f 3f 2f I4I36f I4f I3I9f Iif 10f"
# version 25 inserts, after fuel_quantity[4]: tank_selected uint32[4] and 4 x double[4]
_V25 = ">II 3d 6f 11f 3f 2f I4I36f I4f 4I16d I3I9f Iif 10f"

FG_NET_FDM_SIZES: dict[int, int] = {24: struct.calcsize(_V24), 25: struct.calcsize(_V25)}
"""Datagram size, bytes, of each supported ``FG_NET_FDM_VERSION`` (408 and 552)."""

_HEAD = struct.Struct(">II 3d 6f 11f 3f")  # version .. A_Z_pilot: 112 bytes, same in 24 and 25
_VERSION = struct.Struct(">I")

#: Distinct unknown protocol versions warned of (garbage on the port would give one each).
MAX_VERSION_WARNINGS = 3
_MIN_SIZE = min(FG_NET_FDM_SIZES.values())  # a shorter datagram of no known version: not FGNetFDM
_SIZES = " and ".join(f"{v} is {n} bytes" for v, n in sorted(FG_NET_FDM_SIZES.items()))


def decode_fgnetfdm(data: bytes) -> tuple[int, tuple[float, ...] | None]:
    """The protocol version and the nine values of one ``FGNetFDM`` datagram.

    Parameters
    ----------
    data : bytes
        One datagram.

    Returns
    -------
    version : int
        ``FG_NET_FDM_VERSION`` of the datagram (-1 when shorter than 4 bytes).
    values : tuple of 9 float or None
        ``(f_x, f_y, f_z, p, q, r, roll, pitch, yaw)`` in m/s^2, rad/s, rad (specific
        force FRD, body rates, Euler angles; yaw as sent, not yet wrapped), or None
        when the version is unknown or the size does not match it. Not validated.
    """
    if len(data) < 4:
        return -1, None
    (version,) = _VERSION.unpack_from(data, 0)
    if FG_NET_FDM_SIZES.get(version) != len(data):
        return version, None
    h = _HEAD.unpack_from(data, 0)
    # h: 0 version, 1 padding, 2-4 lon lat alt, 5 agl, 6 phi, 7 theta, 8 psi, 9 alpha,
    # 10 beta, 11 phidot, 12 thetadot, 13 psidot, 14-21 vcas..v_body_w, 22-24 A_*_pilot
    phi, theta, psi = h[6], h[7], h[8]
    with np.errstate(all="ignore"):  # NaN or inf angles: the caller refuses the values
        p, q, r = body_rates_from_euler_rates(phi, theta, h[11], h[12], h[13])
    return version, (
        h[22] * FT_TO_M,
        h[23] * FT_TO_M,
        h[24] * FT_TO_M,
        p,
        q,
        r,
        phi,
        theta,
        psi,
    )


def parse_fgnative_url(url: str, *, free_port: bool = True) -> tuple[str, int]:
    """(host, port) to listen on from ``fgnative:udp:HOST:PORT``, or a one-line ConfigError
    (port 0, any free port, only with ``free_port``)."""
    example = "e.g. fgnative:udp:0.0.0.0:5500"
    text = url.strip()
    if not text.lower().startswith("fgnative:"):
        raise ConfigError(f"fgnative URL {url!r}: must start with fgnative:udp: ({example})")
    rest = text[len("fgnative:") :]
    proto, sep, addr = rest.partition(":")
    if not sep or proto.lower() != "udp":
        raise ConfigError(
            f"fgnative URL {url!r}: only UDP is supported, as fgnative:udp:HOST:PORT ({example})"
        )
    return split_host_port(addr, f"fgnative URL {url!r}", example, free_port=free_port)


class FgNativeSource(UdpLiveSource):
    """Aircraft states from FlightGear (or JSBSim) native-FDM packets, at a fixed rate.

    Parameters
    ----------
    url : str, optional
        ``fgnative:udp:HOST:PORT``: listen on HOST:PORT (``127.0.0.1`` for a
        simulator on this machine, ``0.0.0.0`` for one on another PC; port 0 picks
        a free port, unless ``free_port`` is False). Default ``fgnative:udp:127.0.0.1:5500``.
    rate_hz, duration_s, busy_wait, stale_timeout_s, free_port, drain_budget_s
        See :class:`~motionbase.io.live_source.UdpLiveSource`.

    Examples
    --------
    >>> with FgNativeSource("fgnative:udp:127.0.0.1:5500") as src:  # doctest: +SKIP
    ...     for state in src:
    ...         if not src.fresh:
    ...             ...  # the watchdog fades to neutral
    """

    kind = "fgnative"
    label = "FlightGear"
    default_url = "fgnative:udp:127.0.0.1:5500"

    def _parse_url(self, url: str) -> None:
        self.host, self.port = parse_fgnative_url(url, free_port=self.free_port)

    def _reset_state(self) -> None:
        super()._reset_state()
        self._versions: dict[int, int] = {}  # accepted datagrams per protocol version
        self._warned_versions: set[int] = set()
        self._bad_size = 0
        self._too_short = 0
        self._sender: Any = None  # address of the datagrams in use
        self._sender_time = -math.inf  # when its last datagram was accepted, s
        self._other_senders = 0  # datagrams refused from another address meanwhile
        self._zero_force_since = math.inf  # arrival of the first of a run of exact zeros, s
        self._warned_zero_force = False

    def _bind_address(self) -> tuple[str, int]:
        return self.host, self.port

    def _on_packet(self, data: bytes, addr: Any, arrival: float) -> None:
        c = self._c
        if (
            addr != self._sender
            and self._sender is not None
            and arrival - self._sender_time <= self.stale_timeout_s
        ):  # one stream at a time: two interleaved would take turns in the state
            c["bad_data"] += 1
            c["bad_bytes"] += len(data)
            self._other_senders += 1
            if self._other_senders == 1:
                _log.warning(
                    "FlightGear: refusing datagrams from %s, another sender than %s, while "
                    "that one is fresh; further ones are counted as bad data, not reported",
                    addr,
                    self._sender,
                )
            return
        version, values = decode_fgnetfdm(data)
        if values is None:
            c["bad_data"] += 1
            c["bad_bytes"] += len(data)
            host = addr[0] if isinstance(addr, tuple) else addr
            if version in FG_NET_FDM_SIZES:
                self._bad_size += 1
                if self._bad_size == 1:
                    _log.warning(
                        "FlightGear: refusing a datagram of %d bytes from %s: FGNetFDM "
                        "version %d is %d bytes; further ones are counted as bad data, not "
                        "reported",
                        len(data),
                        host,
                        version,
                        FG_NET_FDM_SIZES[version],
                    )
            elif len(data) < _MIN_SIZE:  # garbage, not a new version: keep those warnings
                self._too_short += 1
                if self._too_short == 1:
                    _log.warning(
                        "FlightGear: refusing a datagram of %d bytes from %s, too short to be "
                        "FGNetFDM (version %s); further ones are counted as bad data, not "
                        "reported",
                        len(data),
                        host,
                        _SIZES,
                    )
            elif (
                version not in self._warned_versions
                and len(self._warned_versions) < MAX_VERSION_WARNINGS
            ):
                self._warned_versions.add(version)
                last = len(self._warned_versions) == MAX_VERSION_WARNINGS
                _log.warning(
                    "FlightGear: refusing datagrams of FGNetFDM version %d from %s "
                    "(supported: 24 and 25, the native-fdm protocol of FlightGear and JSBSim)%s",
                    version,
                    host,
                    "; further unknown versions are counted as bad data, not reported"
                    if last
                    else "",
                )
            return
        if not (
            finite_within(values[0:3], MAX_SPECIFIC_FORCE)
            and finite_within(values[3:6], MAX_ANGULAR_VELOCITY)
            and attitude_ok(*values[6:9])
        ):
            c["rejected_invalid"] += 1
            return
        if addr != self._sender and self._sender is not None:
            _log.info("FlightGear: now using the datagrams from %s", addr)
        self._sender, self._sender_time = addr, arrival
        self._note_zero_force(values[0:3], arrival)
        self._store(0, (*values[:8], wrap_pi(values[8])), arrival)
        self._versions[version] = self._versions.get(version, 0) + 1
        c["accepted"] += 1

    def _note_zero_force(self, force: Any, arrival: float) -> None:
        """Warn once when the pilot's acceleration has read exactly zero for a second: the
        flight model does not fill it (a real free fall of that long is a parabolic flight)."""
        if any(force):
            self._zero_force_since = math.inf
            return
        self._zero_force_since = min(self._zero_force_since, arrival)
        if not self._warned_zero_force and arrival - self._zero_force_since >= 1.0:
            self._warned_zero_force = True
            _log.warning(
                "FlightGear: the pilot's acceleration (A_X/Y/Z_pilot) has read 0 for 1 s: "
                "this flight model does not fill it (FlightGear's UFO, magic-carpet and null "
                "models, JSBSim held down), so the platform cues a free fall; fly a JSBSim or "
                "YASim aircraft"
            )

    def _extra_stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self._versions:
            out["versions"] = "/".join(str(v) for v in sorted(self._versions))
        if self._warned_versions:
            out["refused versions"] = "/".join(str(v) for v in sorted(self._warned_versions))
        if self._bad_size:
            out["wrong size"] = self._bad_size
        if self._too_short:
            out["too short"] = self._too_short
        if self._other_senders:
            out["other senders"] = self._other_senders
        return out

    def describe(self) -> dict[str, Any]:
        """Plain-data description for the log's metadata."""
        out = super().describe()
        out.update(
            protocol="FGNetFDM",
            listen=f"{self.host}:{self.port}",
            versions=sorted(FG_NET_FDM_SIZES),
            rates="body rates from the packet's Euler angle rates",
        )
        return out
