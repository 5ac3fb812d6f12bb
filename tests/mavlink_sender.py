"""The test vehicle's MAVLink samples, and a sender that runs as its own process.

``imu_values``/``att_values`` give sample ``i``'s values; ``send_good`` sends it with a
real pymavlink connection. Run as a script, this module is a vehicle in another process
(no thread of the test competes with it for the interpreter, so its timing holds under
load)::

    python mavlink_sender.py PORT RATE_HZ PHASES_JSON

It prints ``ready`` once connected, then sends sample ``i`` at ``i / RATE_HZ`` s during
the phases (``[[start_s, stop_s], ...]`` from ``ready``), and prints the JSON list of the
indices it sent when the last phase ends.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

G = 9.80665


def imu_values(i: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Specific force (m/s^2) and rates (rad/s) of sample i: varied, physically sane."""
    f = (0.5 * math.sin(0.1 * i), 0.3 * math.cos(0.1 * i), -G + 0.2 * math.sin(0.05 * i))
    w = (0.1 * math.sin(0.2 * i), -0.05 * math.cos(0.1 * i), 0.02 * math.sin(0.3 * i))
    return f, w


def att_values(i: int) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad) of sample i, yaw within [-pi, pi)."""
    yaw = (0.03 * i + math.pi) % (2 * math.pi) - math.pi
    return 0.2 * math.sin(0.07 * i), 0.1 * math.cos(0.05 * i), yaw


def send_good(mav: Any, i: int) -> None:
    """HIGHRES_IMU and ATTITUDE of sample i."""
    f, w = imu_values(i)
    mav.highres_imu_send(i * 10_000, *f, *w, 0.0, 0.0, 0.0, 1013.0, 0.0, 0.0, 20.0, 0x3F)
    mav.attitude_send(i * 10, *att_values(i), *w)


def send_loop(
    mav: Any,
    make: Callable[[Any, int], None],
    sent: list[int],
    rate_hz: float,
    phases: Sequence[Sequence[float]] | None = None,
    stop: threading.Event | None = None,
) -> None:
    """Send sample ``i`` with ``make(mav, i)`` at ``i / rate_hz`` s during ``phases``
    (``(start_s, stop_s)`` windows from now; None: always) until the last phase ends or
    ``stop`` is set; append each index sent to ``sent``."""
    stop = stop or threading.Event()
    t0 = time.monotonic()
    i = 0
    while not stop.is_set():
        now = time.monotonic() - t0
        if phases is not None and now > phases[-1][1]:
            return
        if phases is None or any(a <= now < b for a, b in phases):
            make(mav, i)
            sent.append(i)
        i += 1
        stop.wait(max(0.0, t0 + i / rate_hz - time.monotonic()))


def main(port: int, rate_hz: float, phases: list[list[float]]) -> None:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1)
    sent: list[int] = []
    print("ready", flush=True)
    send_loop(conn.mav, send_good, sent, rate_hz, phases)
    conn.close()
    print(json.dumps(sent), flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]), float(sys.argv[2]), json.loads(sys.argv[3]))
