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
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

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


__all__ = ["wait_until"]
