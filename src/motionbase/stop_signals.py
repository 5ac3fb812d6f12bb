"""Every signal that asks a run to stop, routed to a :class:`~motionbase.pipeline.StopRequest`.

The loops outside :func:`motionbase.pipeline.run` (teleoperation, the motor-drive wiring
check) install these before anything moves: SIGINT and SIGTERM through
:func:`~motionbase.pipeline.install_signal_stop`, and SIGHUP (the terminal closed) and SIGQUIT
(Ctrl-\\) as well, whose default actions would end the process with the motors wherever they
were. When :func:`~motionbase.pipeline.install_signal_stop` already routes a signal, its
handler is kept; this only fills in the signals it leaves alone.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable

from motionbase.pipeline import StopRequest, install_signal_stop

__all__ = ["install_stop_signals"]

#: Signals that end a process by default and must park the platform instead.
EXTRA_SIGNALS = tuple(getattr(signal, n) for n in ("SIGHUP", "SIGQUIT") if hasattr(signal, n))


def install_stop_signals(stop: StopRequest) -> Callable[[], None]:
    """Route SIGINT, SIGTERM, SIGHUP and SIGQUIT to ``stop``; returns a function restoring
    the previous handlers. A no-op outside the main thread (Python delivers signals there)."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    before = {sig: signal.getsignal(sig) for sig in EXTRA_SIGNALS}
    restore_main = install_signal_stop(stop)
    mine = [sig for sig in EXTRA_SIGNALS if signal.getsignal(sig) is before[sig]]

    def handler(signum: int, _frame: object) -> None:
        stop.set(signal.Signals(signum).name)

    for sig in mine:
        signal.signal(sig, handler)

    def restore() -> None:
        for sig in mine:
            signal.signal(sig, before[sig])
        restore_main()

    return restore
