"""wait_until: returns at its deadline, never before; busy-waiting lets the other threads run."""

from __future__ import annotations

import math
import threading
import time

import pytest

from motionbase.pacing import wait_until


class StepClock:
    """A clock that moves 1 ms each time it is read (no real time passes)."""

    def __init__(self) -> None:
        self.now = 0.0
        self.reads = 0

    def __call__(self) -> float:
        self.reads += 1
        self.now += 1e-3
        return self.now


def test_busy_wait_reads_the_clock_until_the_deadline() -> None:
    clock = StepClock()
    wait_until(0.0105, busy=True, clock=clock)
    assert clock.now >= 0.0105  # not before the deadline
    assert clock.reads == 11  # and not one reading after it: 1..10 ms are early, 11 ms is due
    again = StepClock()
    again.now = 1.0
    wait_until(0.5, busy=True, clock=again)  # a deadline in the past: one look, return
    assert again.reads == 1


@pytest.mark.parametrize("busy", [False, True], ids=["sleeping", "busy-waiting"])
def test_returns_at_the_deadline_never_before(busy: bool) -> None:
    for _ in range(20):
        deadline = time.perf_counter() + 2e-3
        wait_until(deadline, busy=busy)
        assert time.perf_counter() >= deadline
    # the same on another clock of the same machine
    deadline = time.monotonic() + 2e-3
    wait_until(deadline, busy=busy, clock=time.monotonic)
    assert time.monotonic() >= deadline


def test_busy_waiting_leaves_the_interpreter_to_other_threads() -> None:
    """The MCAP writer and the motor-drive sender run while the loop busy-waits: the wait
    gives the interpreter lock up at every turn, not only when the interpreter's switch
    interval forces it. With that interval made longer than the test, a thread that needs
    the lock still takes its turns during the wait; the wait's clock here is that thread's
    count of turns, so the wait ends once it had them (a watchdog ends it otherwise).

    (It counted the turns of a thread in 0.2 s of wall clock: a threshold a loaded machine
    could miss, and one the switch interval met alone, without the yield.)"""
    import sys

    turns = 0
    done = threading.Event()

    def worker() -> None:
        nonlocal turns
        while not done.is_set():
            turns += 1  # Python code: it needs the interpreter lock for each turn
            time.sleep(1e-5)

    watchdog = time.monotonic() + 30.0  # not a bound: only ends a wait that never would

    def clock() -> float:
        return math.inf if time.monotonic() > watchdog else float(turns)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1000.0)  # the interpreter never takes the lock away by itself
    thread = threading.Thread(target=worker)
    try:
        thread.start()
        wait_until(200.0, busy=True, clock=clock)
        seen = turns
    finally:
        done.set()
        thread.join()
        sys.setswitchinterval(interval)
    assert seen >= 200, "the busy-wait kept the interpreter lock: the other thread never ran"


def test_a_paced_run_collects_garbage_between_ticks_and_restores_the_collector() -> None:
    """Inside a paced run's ticks the cyclic collector never starts on its own; the
    cycles made during the run are still freed during the run (after the ticks), and
    afterwards the collector is on again with nothing left frozen."""
    import gc
    import weakref

    from motionbase.app import load_config
    from motionbase.pipeline import Pipeline, run
    from motionbase.state import AircraftState

    config = load_config(rate_hz=400.0)
    states = [AircraftState(i * config.dt, [0.0, 0.0, -9.80665], [0.0] * 3) for i in range(400)]

    class Node:
        def __init__(self) -> None:
            self.other = self  # a cycle: only the cyclic collector frees it
            self.pad = [[] for _ in range(20)]  # tracked objects: the collector's count grows

    class CycleMaker:
        def __init__(self) -> None:
            self.refs: list[weakref.ref] = []
            self.enabled_in_tick: set[bool] = set()
            self.freed_during_run = 0

        def write(self, out) -> None:
            self.enabled_in_tick.add(gc.isenabled())
            self.refs.append(weakref.ref(Node()))
            self.freed_during_run = sum(r() is None for r in self.refs)

    assert gc.isenabled()
    sink = CycleMaker()
    run(Pipeline(config), states, [sink], paced=True)
    assert sink.enabled_in_tick == {False}
    assert sink.freed_during_run > len(sink.refs) // 2  # most cycles freed while it ran
    assert gc.isenabled() and gc.get_freeze_count() == 0
    gc.collect()
    assert all(r() is None for r in sink.refs)
