"""Stop requests: the flag that signals, a key or a test raise to end a run.

Kept apart from :mod:`motionbase.pipeline` (which loads numba and the compiled kernels, a
second or more) so that the command line can route the stop signals to a run's
:class:`StopRequest` before anything else happens: a signal that comes while the program is
still loading then stops the run before it moves anything, instead of being lost.

Two kinds of stop (see the README's Safety section):

* a *stop* (the first SIGINT, SIGTERM, SIGHUP or SIGQUIT, and for a job that drives
  motors SIGTSTP, Ctrl-Z; the end of the input; a failing source or sink): the platform
  ramps back to park at the soft-start pace, over ``soft_start_s`` (2 s by default), as
  gently as it started;
* an *E-stop* (:meth:`motionbase.pipeline.Pipeline.estop`, a second stop signal while the
  run is stopping, teleop's E-stop key): the command heads for park at once, as fast as
  the actuators' speed and acceleration limits of the geometry allow (``max_speed``,
  ``max_accel``), never faster.
"""

from __future__ import annotations

import _thread
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = [
    "MOTION_STOP_SIGNALS",
    "STOP_SIGNALS",
    "StopRequest",
    "Stopped",
    "catch_early_stops",
    "insistent_ctrl_c",
    "install_signal_stop",
    "interrupting_signal",
    "other_signals_as_ctrl_c",
    "raise_if_stopped",
    "stop_on_signals",
    "stop_signals_for",
    "stopped_by",
]

#: The signals that stop a run: Ctrl-C, ``kill``, a closed terminal, Ctrl-\.
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name)
    for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT")
    if hasattr(signal, name)
)
#: The signals that stop a job that moves the platform: those, and Ctrl-Z (SIGTSTP), whose
#: default action suspends the process: the platform stayed where it was, moving, and its
#: drives were sent nothing more until the process was continued.
MOTION_STOP_SIGNALS: tuple[signal.Signals, ...] = STOP_SIGNALS + tuple(
    getattr(signal, name) for name in ("SIGTSTP",) if hasattr(signal, name)
)


def stop_signals_for(drives: bool) -> tuple[signal.Signals, ...]:
    """The signals that stop a job: :data:`MOTION_STOP_SIGNALS` when it drives motors
    (``--output``, a board's ``--serial``), else :data:`STOP_SIGNALS`: Ctrl-Z then suspends
    it, as any program, since nothing is left moving (an offline ``fly``, a ``replay
    --check``)."""
    return MOTION_STOP_SIGNALS if drives else STOP_SIGNALS


class StopRequest:
    """A thread-safe flag that signals, a key or a test raise to end a run.

    Attributes
    ----------
    reason : str
        Why the run was first asked to stop (``"SIGINT"``, ``"key Escape"``, ...); later
        requests keep it.
    estop : bool
        An E-stop was asked (by this request or a later one).
    estop_reason : str
        Why the E-stop was asked (empty when none was).
    """

    def __init__(self) -> None:
        self._event = threading.Event()
        #: ``is_set()``: True once a stop was asked (the event's own method: the loop's
        #: per-tick check, without a Python call in between)
        self.is_set = self._event.is_set
        self.estop = False
        self.reason = ""
        self.estop_reason = ""

    def set(self, reason: str = "stop", estop: bool = False) -> None:
        """Ask the run to stop (ramp to park at the soft-start pace), or to E-stop.

        Parameters
        ----------
        reason : str
            Said in the run's summary ("stopped by ...").
        estop : bool
            Head for park at once, at the actuators' speed and acceleration limits.
        """
        if not self._event.is_set():
            self.reason = reason
        if estop and not self.estop:
            self.estop_reason = reason
            self.estop = True
        self._event.set()

    def __bool__(self) -> bool:
        return self._event.is_set()


def stopped_by(first: str, stop: Any) -> str:
    """What ended a run, in its words: ``first`` (what asked it to stop first: a signal,
    the end of the input, a failure), then the E-stop ``stop`` was asked for after it,
    if any. ``"SIGINT, then an E-stop (SIGINT while stopping)"``: ``fly``'s summary
    (:func:`motionbase.pipeline.run`'s ``stopped_by``) and ``output --test``'s line.

    Parameters
    ----------
    first : str
        The first reason.
    stop : StopRequest
        The run's stop request (or an object with its ``estop`` and ``estop_reason``).
    """
    if stop.estop and stop.estop_reason and stop.estop_reason != first:
        return f"{first}, then an E-stop ({stop.estop_reason})"
    return first


class Stopped(Exception):
    """A job that nothing moves with (``tune``) gave up its work because it was asked to stop.

    Jobs that move the platform do not raise it: they park and report the stop in their
    summary. The command line says "interrupted" and exits with 128 + the signal's number
    (130 for Ctrl-C).

    Parameters
    ----------
    reason : str
        :attr:`StopRequest.reason` (``"SIGINT"``, ``"SIGTERM"``, ...).
    kept : str
        What the job kept of its work, said after "interrupted" (``"kept the best set of
        37 evaluations in o.toml"``); empty when it kept nothing.
    """

    def __init__(self, reason: str, kept: str = "") -> None:
        super().__init__(reason)
        self.reason = reason
        self.kept = kept

    @property
    def exit_status(self) -> int:
        """128 + the number of the signal that stopped the job (1 when no signal did)."""
        name = self.reason.split()[0] if self.reason else ""
        sig = getattr(signal, name, None) if name.startswith("SIG") else None
        return 128 + int(sig) if sig is not None else 1


def raise_if_stopped(stop: StopRequest | None) -> None:
    """Raise :class:`Stopped` when ``stop`` is set: where a job that moves nothing gives up."""
    if stop:
        raise Stopped(stop.reason)


#: Stop signals that came while the command line was starting, before a job routed the
#: signals (:func:`catch_early_stops`); the first job to route them takes them.
_EARLY: list[int] = []


def _remember(signum: int, _frame: object) -> None:
    _EARLY.append(signum)


def _default(sig: int) -> Any:
    """The handler a signal has in a Python process that did not change it."""
    return signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL


def catch_early_stops() -> None:
    """The stop signals are remembered, not acted on, until a job routes them.

    For the command line's first line: its imports take a few tenths of a second (more on
    a loaded machine), and meanwhile SIGTERM, SIGHUP or SIGQUIT would kill the process
    without a word and Ctrl-C cut an import short. The job that then routes the signals
    takes one that came meanwhile as if it came at that moment:
    :func:`install_signal_stop` (a job that moves the platform: a stop before the first
    tick moves nothing) or :func:`other_signals_as_ctrl_c` (a job that moves nothing: it
    is "interrupted"). Signals whose handler is not Python's default are left alone; a
    no-op outside the main thread.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is _default(sig):
            signal.signal(sig, _remember)


def _handlers(sigs: Iterable[int]) -> dict[int, Any]:
    """The signals' handlers now, :func:`catch_early_stops`' counted as the default (a job
    that routes the signals hands them back to the default when it ends)."""
    now = {sig: signal.getsignal(sig) for sig in sigs}
    return {sig: _default(sig) if h is _remember else h for sig, h in now.items()}


def _taken_early() -> list[int]:
    """The signals :func:`catch_early_stops` remembered, in order; forgotten here."""
    taken = list(_EARLY)
    _EARLY.clear()
    return taken


def install_signal_stop(
    stop: StopRequest, signals: Iterable[int] | None = None
) -> Callable[[], None]:
    """Route the stop signals to ``stop``; returns a function restoring the previous handlers.

    The first signal asks for a stop (``stop.set(name)``: the platform parks at the
    soft-start pace); any signal after it, while the run is stopping, asks for an E-stop
    (``stop.set(name, estop=True)``: park at once, within the speed and acceleration
    limits). A no-op outside the main thread (Python delivers signals to it only).

    Parameters
    ----------
    stop : StopRequest
    signals : iterable of int, optional
        Default :data:`MOTION_STOP_SIGNALS` (SIGINT, SIGTERM, SIGHUP, SIGQUIT and SIGTSTP
        where the platform has them).
    """
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    sigs = tuple(MOTION_STOP_SIGNALS if signals is None else signals)
    old = _handlers(sigs)

    def handler(signum: int, _frame: object) -> None:
        name = signal.Signals(signum).name
        if stop:
            stop.set(f"{name} while stopping", estop=True)
        else:
            stop.set(name)

    for sig in sigs:
        signal.signal(sig, handler)
    for signum in _taken_early():  # came while the command line was starting
        handler(signum, None)

    def restore() -> None:
        for sig, h in old.items():
            signal.signal(sig, h if h is not None else signal.SIG_DFL)

    return restore


@contextmanager
def stop_on_signals(
    stop: StopRequest | None = None, signals: Iterable[int] | None = None
) -> Iterator[StopRequest]:
    """A job's stop request, with the stop signals routed to it for the job's length.

    Entered first, before the job loads its modules (numba and the compiled kernels take a
    second or more), opens its source or starts its workers: a signal that comes meanwhile
    stops the job before it starts, instead of being lost or cutting an import short.

    Parameters
    ----------
    stop : StopRequest, optional
        A request the caller has already routed the signals to (the command line does,
        before it loads anything): used as it is. Default: a new one, routed here.
    signals : iterable of int, optional
        The signals routed (:func:`install_signal_stop`'s default: a job that moves the
        platform's; a job that moves nothing gives :data:`STOP_SIGNALS`, and Ctrl-Z then
        suspends it).
    """
    if stop is not None:
        yield stop
        return
    stop = StopRequest()
    restore = install_signal_stop(stop, signals)
    try:
        yield stop
    finally:
        restore()


@contextmanager
def insistent_ctrl_c(period_s: float = 0.2) -> Iterator[None]:
    """Ctrl-C raises ``KeyboardInterrupt``, and again every ``period_s`` until the block ends.

    For commands that move nothing (``omct``, ``report``, ``workspace``): Python prints and
    drops a ``KeyboardInterrupt`` raised while C code has called back into Python, and
    numba's compiler does that throughout a compilation (the first run of a fresh install
    compiles for several seconds), so a single one would be lost and the command run on.
    The dropped ones are not reported (``sys.unraisablehook``): the next one is raised;
    nor, once a Ctrl-C came, are the errors of the objects it left half-built when their
    finalizers run (llvmlite's, when it lands inside one's constructor: the frames a dropped
    one cut short are never freed; after the block, see :func:`keep_what_ctrl_c_cut_short`).
    An error that ends the block after a Ctrl-C came is raised as a ``KeyboardInterrupt``
    (from it): a Ctrl-C swallowed by compiled code can leave it half done and failing
    later, as numba's compiler does ("no compiled object yet"). A no-op outside the main
    thread, and where SIGINT is not Python's default handler (a background job ignores it;
    a host program has its own).

    Parameters
    ----------
    period_s : float
        Seconds between two raises, > 0.
    """
    ctrl_c = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or ctrl_c not in (
        signal.default_int_handler,
        _remember,  # (the command line's, while it starts: still Python's default)
    ):
        yield
        return
    done = threading.Event()
    repeater: list[threading.Thread] = []

    def repeat() -> None:
        while not done.wait(period_s):
            _thread.interrupt_main()  # runs the handler below in the main thread

    def handler(signum: int, _frame: object) -> None:
        if done.is_set():
            return  # a last repeat after the block ended
        if not repeater:
            repeater.append(threading.Thread(target=repeat, name="motionbase-ctrl-c", daemon=True))
            repeater[0].start()
        raise KeyboardInterrupt

    def quiet(unraisable: Any) -> None:  # a dropped one: raised again, not worth a traceback
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            if unraisable.exc_traceback is not None:  # its frames may hold half-built objects
                _keep_to_the_end(unraisable.exc_traceback)
        elif not repeater:
            previous_hook(unraisable)

    previous_hook = sys.unraisablehook
    sys.unraisablehook = quiet
    signal.signal(signal.SIGINT, handler)
    try:
        yield
    except Exception as exc:
        if repeater:  # a Ctrl-C came: the error is what it broke (numba's compiler, say)
            raise KeyboardInterrupt from exc
        raise
    finally:
        done.set()
        if repeater:
            repeater[0].join()  # its last repeat, if any, reaches the handler above
            _forget_escaped_ctrl_c()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        sys.unraisablehook = previous_hook


#: The signal an :func:`other_signals_as_ctrl_c` block turned into a Ctrl-C, if one did.
_INTERRUPTED_BY: list[int] = []


def interrupting_signal() -> signal.Signals:
    """The signal a ``KeyboardInterrupt`` came from: SIGINT, unless a block of
    :func:`other_signals_as_ctrl_c` turned another stop signal into it."""
    return signal.Signals(_INTERRUPTED_BY[0] if _INTERRUPTED_BY else signal.SIGINT)


@contextmanager
def other_signals_as_ctrl_c() -> Iterator[None]:
    """SIGTERM, SIGHUP and SIGQUIT end the block as a Ctrl-C does, for commands that move
    nothing (``omct``, ``report``, ``workspace``): their clean-up runs (no temporary file
    left by a writer that was cut short) and the command line says "interrupted (SIGTERM)"
    and exits with 128 + the signal's number (:func:`interrupting_signal`), where the
    signal's default action would kill the process without a word. Signals whose handler
    is not the default (a host program's) are left alone; a no-op outside the main thread.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _INTERRUPTED_BY.clear()  # (kept after the block: the command line reads it then)
    others = [s for s in STOP_SIGNALS if s != signal.SIGINT]
    old = _handlers(others)

    def handler(signum: int, frame: Any) -> None:
        if not _INTERRUPTED_BY:
            _INTERRUPTED_BY.append(signum)
        ctrl_c = signal.getsignal(signal.SIGINT)  # insistent_ctrl_c's, or Python's own
        if callable(ctrl_c):
            ctrl_c(signal.SIGINT, frame)
        raise KeyboardInterrupt

    mine = [s for s in others if old[s] is signal.SIG_DFL]
    for sig in mine:
        signal.signal(sig, handler)
    try:
        early = _taken_early()  # came while the command line was starting
        if early:
            handler(early[0], None)
        yield
    finally:
        for sig in mine:
            signal.signal(sig, old[sig])


#: What Ctrl-C cut short, kept to the process's end (:func:`keep_what_ctrl_c_cut_short`).
_CUT_SHORT: list[object] = []


def keep_what_ctrl_c_cut_short(exc: BaseException) -> None:
    """Never free what a Ctrl-C cut short, and say nothing of finalizers that fail.

    For a command that a Ctrl-C ended: it may have landed inside a library's constructor
    (llvmlite's, while numba compiles). Freed, the half-built object's finalizer fails, or
    crashes the process inside LLVM (a segmentation fault: the shell saw -11 right after
    the line "interrupted", instead of 130). ``exc``'s traceback holds the frames the
    Ctrl-C cut short, and they hold the object: they are kept until the process ends (the
    operating system takes the memory back). From now on, errors in finalizers
    (``sys.unraisablehook``) are not reported either: one line has said the command was
    interrupted, and that is all the user needs to read.

    Parameters
    ----------
    exc : BaseException
        The ``KeyboardInterrupt``, or the error a library made of it.
    """
    sys.unraisablehook = lambda unraisable: None
    _keep_to_the_end(exc)


def _keep_to_the_end(thing: object) -> None:
    """``thing`` (and what it holds) is never freed, not even as the interpreter exits."""
    _CUT_SHORT.append(thing)
    if sys.implementation.name == "cpython":  # the list itself goes when modules do, at exit
        import ctypes

        ctypes.pythonapi.Py_IncRef(ctypes.py_object(thing))


def _forget_escaped_ctrl_c() -> None:
    """Clear CPython's record of a KeyboardInterrupt that ended code a C library ran.

    When a Ctrl-C ends Python code that a compiled library runs through ``PyRun_String``
    (one of the libraries a measurement loads does, now and then), CPython notes an
    "unhandled" KeyboardInterrupt and, at exit, kills its own process with SIGINT: the
    command caught the Ctrl-C and returned 130, yet the shell would see -2. Every
    ``PyRun_SimpleString`` starts by clearing that note, so running an empty one forgets it.
    """
    if sys.implementation.name != "cpython":
        return
    try:
        import ctypes

        ctypes.pythonapi.PyRun_SimpleString(b"")
    except (AttributeError, OSError):  # no C API to call: the exit status may be -2
        pass
