"""Every stop signal reaches the StopRequest of a loop outside the pipeline, whether or not
``pipeline.install_signal_stop`` covers SIGHUP and SIGQUIT itself; the handlers go back after."""

from __future__ import annotations

import os
import signal
import time

import pytest

from motionbase import stop_signals
from motionbase.pipeline import StopRequest

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
    restore = stop_signals.install_stop_signals(stop)
    try:
        _deliver(sig, stop)
    finally:
        restore()
    assert stop and stop.reason == signal.Signals(sig).name
    assert {s: signal.getsignal(s) for s in ALL} == before


def test_signals_the_pipeline_already_routes_keep_its_handler(monkeypatch):
    """When install_signal_stop covers all four signals, its handlers stay in place."""
    seen = []

    def covering(stop):
        old = {s: signal.getsignal(s) for s in ALL}

        def handler(signum, _frame):
            seen.append(signum)
            stop.set(signal.Signals(signum).name, estop=True)

        for s in ALL:
            signal.signal(s, handler)
        return lambda: [signal.signal(s, h) for s, h in old.items()]

    monkeypatch.setattr(stop_signals, "install_signal_stop", covering)
    before = {s: signal.getsignal(s) for s in ALL}
    stop = StopRequest()
    restore = stop_signals.install_stop_signals(stop)
    try:
        _deliver(signal.SIGHUP, stop)
    finally:
        restore()
    assert seen == [signal.SIGHUP] and stop.estop
    assert {s: signal.getsignal(s) for s in ALL} == before
