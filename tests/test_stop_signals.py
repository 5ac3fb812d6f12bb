"""Every stop signal reaches the StopRequest of a loop outside the pipeline (teleop, the
motor-drive wiring check) through ``stopping.install_signal_stop``; the handlers go back
after."""

from __future__ import annotations

import os
import signal
import time

import pytest

from motionbase.pipeline import StopRequest
from motionbase.stopping import install_signal_stop

ALL = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


def _deliver(sig: int, stop: StopRequest) -> None:
    os.kill(os.getpid(), sig)  # handled in the main thread at its next bytecode
    for _ in range(200):
        if stop:
            return
        time.sleep(0.005)


@pytest.mark.parametrize("sig", ALL, ids=lambda s: signal.Signals(s).name)
def test_each_stop_signal_raises_the_request_and_the_handlers_go_back(sig):
    before = {s: signal.getsignal(s) for s in ALL}
    stop = StopRequest()
    restore = install_signal_stop(stop)
    try:
        _deliver(sig, stop)
    finally:
        restore()
    assert stop and stop.reason == signal.Signals(sig).name
    assert {s: signal.getsignal(s) for s in ALL} == before
