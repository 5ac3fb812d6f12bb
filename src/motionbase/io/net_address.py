"""Checks of the HOST:PORT in a network URL, before any socket is opened.

One place says what is wrong with an address, so every URL (a motor-drive output, a MAVLink
link, a cursor source) gets the same one-line message: a port out of range, a port that is not
a number, a host name that does not resolve.
"""

from __future__ import annotations

import socket

from motionbase.errors import ConfigError

__all__ = ["check_host_port"]


def check_host_port(what: str, host: str, port: str, *, bind: bool = False) -> tuple[str, int]:
    """Validate a host and port from a URL.

    Parameters
    ----------
    what : str
        Names the URL in the message (``"output 'udp:h:p'"``).
    host : str
        Host name or IP address (brackets of an IPv6 literal already removed).
    port : str
        The port as written in the URL.
    bind : bool
        The address is one to listen on: port 0 (any free port) is allowed.

    Returns
    -------
    (str, int)
        The host and the port number.

    Raises
    ------
    ConfigError
        One line with every problem found: a port that is not a number or out of range
        (1..65535, or 0..65535 with ``bind``), no host, or a host name that does not resolve.
    """
    problems = []
    lowest = 0 if bind else 1
    digits = port.removeprefix("-")  # a negative port is a number, out of range
    number = int(port) if digits.isascii() and digits.isdigit() else None
    if number is None:
        problems.append(f"port {port!r} is not a number")
    elif not lowest <= number <= 65535:
        problems.append(f"port {number} is out of range ({lowest}..65535)")
    if not host:
        problems.append("no host (write HOST:PORT, e.g. 127.0.0.1:4123)")
    else:
        try:
            socket.getaddrinfo(host, None)
        except (socket.gaierror, UnicodeError):
            problems.append(
                f"host name {host!r} does not resolve (check its spelling or give an IP address)"
            )
    if problems:
        raise ConfigError(f"{what}: {'; '.join(problems)}")
    assert number is not None
    return host, number
