"""Every stop signal reaches the StopRequest of a loop outside the pipeline (teleop, the
motor-drive wiring check) through ``stopping.install_signal_stop``; the handlers go back
after."""

from __future__ import annotations

import os
import signal
import time

import pytest
from signalled import signalled

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


@pytest.mark.parametrize("after_s", [0.3, 1.0, 2.0])
def test_ctrl_c_during_a_measurement_is_one_line_and_exit_130(after_s, tmp_path):
    """``omct`` moves nothing: Ctrl-C simply ends it, at any moment, with one line and
    exit 130, also while it loads matplotlib (whose imports turn the KeyboardInterrupt
    into a RuntimeError)."""
    args = ["omct", "--out", str(tmp_path / "o")]
    status, err = signalled(args, lambda _: time.sleep(after_s))
    assert err.strip() == "motionbase omct: interrupted"
    assert status == 130


def test_an_error_caused_by_ctrl_c_counts_as_ctrl_c():
    from motionbase.cli import _raised_by_ctrl_c

    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("Error calling __set_name__") from exc
    except RuntimeError as wrapped:
        assert _raised_by_ctrl_c(wrapped)
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise ValueError("raised while handling it") from None
    except ValueError as hidden:
        assert _raised_by_ctrl_c(hidden)  # the context is still there
    assert not _raised_by_ctrl_c(RuntimeError("a bug"))
