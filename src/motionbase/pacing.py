"""Waiting for the wall clock in the real-time loops: by sleeping, or by busy-waiting.

The paced pipeline loops (a ``--realtime`` JSBSim flight, a live or replayed MAVLink
stream, the pipeline's own loop pacing a replay or a flight with motor drives, the park
ramp after a run) wait for their next tick with :func:`wait_until`.
Two ways:

* sleep (the default): the thread sleeps until the tick is due. The processor is free
  between ticks, but an idle processor is one that the operating system, or a virtual
  machine's host, may take for something else: waking up and the first microseconds
  after waking are where a 1 kHz loop meets most of its late ticks.
* busy-wait (``busy=True``): the thread keeps its processor between ticks, reading the
  clock and yielding the interpreter lock to the other threads (the MCAP writer, the
  motor-drive sender) at every turn. It costs one processor at 100 %, and on a machine
  that takes the CPU away from idle processors it turns fewer ticks late and readies each
  command sooner after its due time (see ``benchmarks/RESULTS.md``, issue 7). The usual
  choice for a 1 kHz loop on a core of its own.

(Teleoperation and the motor wiring check run in the pipeline's loop too. Sinks never
wait: the motor-drive outputs send from a thread of their own at a fixed rate.)

Times are seconds on :func:`time.perf_counter` unless a ``clock`` is given
(:func:`time.monotonic` is the same clock on Linux).

Python's cyclic garbage collector runs whenever enough objects were allocated, in the
middle of whatever code allocated the last one: in a 1 kHz loop, inside a tick. Its
middle generation takes about 0.5-1.5 ms here, a few times a second: that alone makes a
tick late. :class:`GarbageBetweenTicks` moves it between the ticks of a paced run.
"""

from __future__ import annotations

import gc
import os
import time
from collections.abc import Callable
from types import TracebackType

_yield = getattr(os, "sched_yield", lambda: time.sleep(0))


def wait_until(
    deadline: float, *, busy: bool = False, clock: Callable[[], float] = time.perf_counter
) -> None:
    """Return when ``clock()`` reaches ``deadline`` (at once when it has passed).

    Parameters
    ----------
    deadline : float
        When to return, s on ``clock``.
    busy : bool
        Busy-wait (keep the processor, yield the interpreter lock at every turn)
        instead of sleeping.
    clock : callable
        The clock ``deadline`` is on, s (default :func:`time.perf_counter`).
    """
    if busy:
        while clock() < deadline:
            _yield()  # releases the GIL: the writer and sender threads run meanwhile
        return
    delay = deadline - clock()
    if delay > 0.0:
        time.sleep(delay)


class GarbageBetweenTicks:
    """The cyclic garbage collector run after a tick's commands are out, not inside a tick.

    A context manager for a paced loop. On entry the objects alive then (the program,
    its modules, the pipeline: everything made before the first tick) are frozen out of
    every later collection (:func:`gc.freeze`) and automatic collection is switched off;
    the loop calls :meth:`after_tick` once its tick's commands have gone to the sinks,
    which collects with the interpreter's own thresholds (the youngest generation after
    ``threshold0`` net allocations, the middle one every ``threshold1``-th time, the
    oldest every ``threshold1 * threshold2``-th), so as much garbage is freed as without
    it. On exit the collector is as it was and the frozen objects are collected again
    like any other.
    """

    def __init__(self) -> None:
        self._collections = 0
        self._was_enabled = True
        self._thresholds = (700, 10, 10)

    def __enter__(self) -> GarbageBetweenTicks:
        t0, t1, t2 = gc.get_threshold()
        self._thresholds = (max(t0, 1), max(t1, 1), max(t2, 1))
        self._was_enabled = gc.isenabled()
        gc.disable()
        gc.freeze()
        return self

    def after_tick(self) -> None:
        """Collect when the interpreter would have (a few times a second at 1 kHz)."""
        t0, t1, t2 = self._thresholds
        if gc.get_count()[0] < t0:
            return
        self._collections += 1
        k = self._collections
        gc.collect(2 if k % (t1 * t2) == 0 else 1 if k % t1 == 0 else 0)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        gc.unfreeze()
        if self._was_enabled:
            gc.enable()


__all__ = ["GarbageBetweenTicks", "wait_until"]
