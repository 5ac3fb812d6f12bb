"""Checks of the HOST:PORT in a network URL, before any socket is opened.

One place says what is wrong with an address, so every URL (a motor-drive output, a MAVLink
link, a simulator source, a cursor source) gets the same one-line message: a port out of
range, a port that is not a number, a host name that does not resolve; and
:func:`bind_fix` what to do about a port that cannot be bound (a listening source's).
"""

from __future__ import annotations

import errno
import socket

from motionbase.errors import ConfigError

__all__ = ["bind_fix", "check_host_port", "check_port"]


def _port_number(port: str, free_port: bool) -> tuple[int | None, str | None]:
    """(the port number, None), or (None, what is wrong with it)."""
    digits = port.removeprefix("-")  # a negative port is a number, out of range
    if not (digits.isascii() and digits.isdigit()):
        return None, f"port {port!r} is not a number"
    number = int(port)
    if not (0 if free_port else 1) <= number <= 65535:
        allowed = "1..65535, or 0 for any free port" if free_port else "1..65535"
        return None, f"port {number} is out of range ({allowed})"
    return number, None


def check_port(what: str, port: str, *, free_port: bool = False, example: str = "") -> int:
    """The port number written in a URL, or a one-line ConfigError (see :func:`check_host_port`;
    ``example``, when given, ends the message in brackets)."""
    number, problem = _port_number(port, free_port)
    if problem is not None:
        raise ConfigError(f"{what}: {problem}" + (f" ({example})" if example else ""))
    assert number is not None
    return number


def check_host_port(what: str, host: str, port: str, *, free_port: bool = False) -> tuple[str, int]:
    """Validate a host and port from a URL.

    Parameters
    ----------
    what : str
        Names the URL in the message (``"output 'udp:h:p'"``).
    host : str
        Host name or IP address (brackets of an IPv6 literal already removed).
    port : str
        The port as written in the URL.
    free_port : bool
        Port 0 is allowed: an address to listen on, on any free port, which the caller
        shows (``--live`` prints its address). Where nothing would show it, nobody could
        send to that port, and port 0 is refused like any out-of-range port.

    Returns
    -------
    (str, int)
        The host and the port number.

    Raises
    ------
    ConfigError
        One line with every problem found: a port that is not a number or out of range
        (1..65535, or 0..65535 with ``free_port``), no host, or a host name that does not
        resolve.
    """
    number, problem = _port_number(port, free_port)
    problems = [] if problem is None else [problem]
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


def bind_fix(exc: OSError, otherwise: str) -> str:
    """What to do about a socket that cannot be bound, by its error: a port in use, a port
    that needs privileges; ``otherwise`` for any other error (an address not on this
    machine, say)."""
    return {
        errno.EADDRINUSE: "another program listens there: choose another port",
        errno.EACCES: "a port below 1024 needs privileges: choose a port from 1024 up",
    }.get(exc.errno, otherwise)
