"""Where the tuner's evaluations run: this process, local worker processes, or a Dask cluster.

This module never imports the tuner (nor, through it, the pipeline): it runs
``problem.evaluate(params)`` for whatever problem it is given, and the workers unpickle
the problem's classes themselves.

:func:`open_evaluator` gives ``evaluate_many(candidates) -> scores`` (results in the
order of the candidates, whatever finishes first), the function
:func:`motionbase.tuning.tune` calls once per CMA-ES generation:

- ``workers=1``: in this process, one after the other;
- ``workers=K`` (default: the processors this process may use): a
  :class:`concurrent.futures.ProcessPoolExecutor` of K processes (started with
  ``spawn``), each reading the problem (the manoeuvre arrays) once, from a file this
  process writes, in its initializer.
  More than four per processor is refused: the evaluations are CPU bound. The workers
  leave the stop signals (Ctrl-C, SIGTERM, SIGHUP, SIGQUIT, also when they are sent to the
  whole process group, as ``timeout`` and service managers do) to the main process, which
  cancels what is queued and kills the workers (what they were evaluating is thrown away,
  and an evaluation can take a minute: the first one in a fresh installation compiles the
  pipeline, an MPC one solves thousands of programmes); they exit on their own when the
  main process dies (a kill), instead of waiting for work forever. A worker that dies
  anyway (killed, out of memory) ends the run with a one-line error;
- ``scheduler="tcp://HOST:8786"``: a Dask distributed scheduler; the problem is
  scattered to every worker once and each evaluation refers to it. The workers need
  motionbase (the same version) installed, which is checked before the tuning starts;
  ``pip install 'motionbase[cluster]'`` installs Dask on the machine running ``tune``.
  A scheduler that goes away, or takes the workers with it, ends the run with a one-line
  error.
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing import active_children, get_context, parent_process
from multiprocessing.connection import wait
from typing import TYPE_CHECKING

from motionbase.errors import ConfigError, MotionbaseError, SourceError
from motionbase.stopping import STOP_SIGNALS, StopRequest, raise_if_stopped

if TYPE_CHECKING:
    from distributed import Client
    from distributed import Future as DaskFuture

    from motionbase.tuning import EvaluateMany, SetScore, TuningProblem
    from motionbase.washout.params import WashoutParams

__all__ = ["check_workers", "default_workers", "open_evaluator"]

#: Seconds to wait for a Dask scheduler to answer.
CONNECT_TIMEOUT_S = 10.0

#: Seconds between two looks at the stop request while evaluations run elsewhere.
STOP_POLL_S = 0.05

#: Local workers allowed per processor (more is a mistake: each evaluation is CPU bound).
MAX_WORKERS_PER_PROCESSOR = 4


def check_workers(workers: int | None) -> int:
    """The number of local worker processes ``workers`` asks for (None: one per processor).

    Raises
    ------
    ConfigError
        Not a whole number >= 1, or more than four per processor.
    """
    n = default_workers() if workers is None else workers
    if isinstance(n, bool) or not (isinstance(n, int) and n >= 1):
        raise ConfigError(f"--workers must be a whole number >= 1, got {workers!r}")
    if n > MAX_WORKERS_PER_PROCESSOR * default_workers():
        raise ConfigError(
            f"--workers {n}: this process may use {default_workers()} processors, and more "
            f"than {MAX_WORKERS_PER_PROCESSOR} workers per processor only slow each other "
            f"down; give at most {MAX_WORKERS_PER_PROCESSOR * default_workers()} (the default, "
            f"{default_workers()}, is one per processor), or --scheduler for a cluster"
        )
    return n


def default_workers() -> int:
    """The processors this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


@contextmanager
def open_evaluator(
    problem: TuningProblem,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    stop: StopRequest | None = None,
) -> Iterator[EvaluateMany]:
    """Evaluate parameter sets on ``problem`` here, in local processes or on a cluster.

    Parameters
    ----------
    problem : TuningProblem
        Sent once to each worker.
    workers : int, optional
        Local processes (>= 1); default :func:`default_workers`. Ignored with ``scheduler``.
    scheduler : str, optional
        Address of a Dask distributed scheduler, ``tcp://HOST:PORT``.
    stop : StopRequest, optional
        Watched while evaluating: once set, ``evaluate_many`` cancels what has not
        started and raises :class:`~motionbase.stopping.Stopped`.

    Yields
    ------
    callable
        ``evaluate_many(list of WashoutParams) -> list of SetScore``, in order.

    Raises
    ------
    ConfigError
        ``workers`` < 1 or more than four per processor, a scheduler address that is not
        ``tcp://HOST:PORT``, or Dask not installed.
    SourceError
        The scheduler does not answer.
    MotionbaseError
        A local worker process died (killed, out of memory).
    """
    if scheduler is not None:
        with _dask(problem, scheduler, stop) as evaluate_many:
            yield evaluate_many
        return
    n = check_workers(workers)
    if n == 1:

        def evaluate_here(candidates: list[WashoutParams]) -> list[SetScore]:
            scores = []
            for params in candidates:
                raise_if_stopped(stop)
                scores.append(problem.evaluate(params))
            return scores

        yield evaluate_here
        return
    _start_resource_tracker()
    others = set(active_children())  # (processes this one had started before the pool)
    # The workers read the problem from a file: sent with their start-up data, its arrays
    # (hundreds of kB) filled the pipe, and this process, its stop signals held back, then
    # waited for each worker to import motionbase (a minute or more on a loaded machine with
    # an empty numba cache) before it could take the rest, a stop signal with it.
    folder = tempfile.TemporaryDirectory(prefix="motionbase-tune-")
    problem_file = os.path.join(folder.name, "problem.pickle")
    with open(problem_file, "wb") as fh:
        pickle.dump(problem, fh, protocol=pickle.HIGHEST_PROTOCOL)
    pool = ProcessPoolExecutor(
        max_workers=n,
        mp_context=get_context("spawn"),
        initializer=_init_worker,
        initargs=(problem_file,),
    )
    try:
        _results(_start_workers(pool, n), stop)  # (a stop while they start up ends here)
        yield lambda candidates: _results(
            [pool.submit(_evaluate_here, p) for p in candidates], stop
        )
    except BrokenProcessPool:
        pool.shutdown(wait=True, cancel_futures=True)
        raise_if_stopped(stop)  # a stop signal sent to the whole group, before a worker set up
        raise MotionbaseError(
            "tune: a worker process died (killed, or out of memory); nothing was written; "
            "run again, with fewer --workers if memory is short"
        ) from None
    except BaseException:  # a stop, or an error here: the evaluations under way are not wanted
        for worker in set(active_children()) - others:
            worker.kill()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        folder.cleanup()
    pool.shutdown(wait=True)


def _results(futures: list[Future], stop: StopRequest | None) -> list[SetScore]:
    """The futures' results in order; on a stop, cancel those not started and raise
    :class:`~motionbase.stopping.Stopped` (the caller then kills the workers)."""
    pending = set(futures)
    while pending:
        if stop:
            for future in pending:
                future.cancel()
            raise_if_stopped(stop)
        _, pending = wait_futures(pending, timeout=None if stop is None else STOP_POLL_S)
    return [future.result() for future in futures]


def _start_workers(pool: ProcessPoolExecutor, n: int) -> list[Future]:
    """Start all ``n`` workers now (n tasks at once: each finds no idle worker); their tasks'
    futures, done once every worker has set up.

    The stop signals are held back while the workers are spawned (each is sent its start-up
    data as it is spawned, in this thread), here and in the workers until their initializer
    ignores them (a spawned process inherits the blocked set): a signal while a worker is
    being sent its start-up data cuts that data, and the half-started worker prints a
    traceback; a SIGTERM sent to the whole group would kill a worker before it ignores it.
    They are not held back while the workers import and set up: that takes a minute or more
    on a loaded machine whose numba cache is empty, and a stop then must not wait for it."""
    block = threading.current_thread() is threading.main_thread() and hasattr(
        signal, "pthread_sigmask"
    )
    before = signal.pthread_sigmask(signal.SIG_BLOCK, set(STOP_SIGNALS)) if block else None
    try:
        return [pool.submit(_worker_pid, i) for i in range(n)]
    finally:
        if before is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, before)


def _start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (the pool's locks register with it) with
    every stop signal blocked, which it inherits: it ignores SIGINT and SIGTERM itself, but
    a SIGHUP or SIGQUIT sent to the whole group (a closed terminal) would kill it, and the
    pool would then print its tracebacks while it shuts down."""
    from multiprocessing import resource_tracker

    block = threading.current_thread() is threading.main_thread() and hasattr(
        signal, "pthread_sigmask"
    )
    before = signal.pthread_sigmask(signal.SIG_BLOCK, set(STOP_SIGNALS)) if block else None
    try:
        resource_tracker.ensure_running()
    finally:
        if before is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, before)


def _worker_pid(_: int) -> int:
    return os.getpid()


def _init_worker(problem_file: str) -> None:
    """A pool worker: leave the stop signals to the main process, die with it, and keep the
    problem (read from ``problem_file``)."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):  # blocked by _start_workers when spawned
        signal.pthread_sigmask(signal.SIG_UNBLOCK, set(STOP_SIGNALS))
    parent = parent_process()
    if parent is not None:

        def watch() -> None:
            wait([parent.sentinel])  # ready when the main process has exited
            os._exit(1)

        threading.Thread(target=watch, name="motionbase-parent-watch", daemon=True).start()
    global _PROBLEM
    with open(problem_file, "rb") as fh:
        _PROBLEM = pickle.load(fh)  # noqa: S301 - written by this run's main process


#: The problem of this pool worker (set by :func:`_init_worker`).
_PROBLEM: TuningProblem | None = None


def _evaluate_here(params: WashoutParams) -> SetScore:
    """Score ``params`` on this pool worker's problem."""
    if _PROBLEM is None:
        raise RuntimeError("a tuning worker without its problem (the initializer did not run)")
    return _PROBLEM.evaluate(params)


def _evaluate(problem: TuningProblem, params: WashoutParams) -> SetScore:
    """Score ``params`` on ``problem`` (a Dask task; the problem is the scattered one)."""
    return problem.evaluate(params)


@contextmanager
def _dask(problem: TuningProblem, address: str, stop: StopRequest | None) -> Iterator[EvaluateMany]:
    host, _, port = address.removeprefix("tcp://").rpartition(":")
    if not address.startswith("tcp://") or not host or not port.isdigit():
        raise ConfigError(
            f"--scheduler {address!r}: expected the scheduler's address, tcp://HOST:PORT "
            "(e.g. tcp://192.168.1.10:8786)"
        )
    if not 1 <= int(port) <= 65535:  # (port 0 or 99999 waited out the timeout, then blamed
        raise ConfigError(  # the scheduler for not answering)
            f"--scheduler {address!r}: port {int(port)} is out of range (1..65535); the "
            "scheduler's is 8786 unless it was started with another"
        )
    try:
        from distributed import Client
        from distributed.comm import CommClosedError
    except ImportError:
        raise ConfigError(
            "--scheduler needs Dask distributed: pip install 'motionbase[cluster]'"
        ) from None
    with _dask_logs_off():
        try:
            client = _connect(Client, address, stop)
        except OSError as exc:
            raise SourceError(
                f"--scheduler {address}: no Dask scheduler answers there ({exc}); start one "
                "(dask scheduler) or check the address and the firewall"
            ) from None
        try:
            _check_cluster(client, address)
            shared = client.scatter(problem, broadcast=True)

            def evaluate_many(candidates: list[WashoutParams]) -> list[SetScore]:
                futures = [client.submit(_evaluate, shared, p, pure=False) for p in candidates]
                try:
                    return _results([_concurrent(f) for f in futures], stop)
                except (CancelledError, CommClosedError):  # (it used to be a traceback)
                    raise SourceError(
                        f"--scheduler {address}: the cluster lost the evaluations (the "
                        "scheduler or all its workers went away); nothing was written; run "
                        "again once the scheduler and its workers are back"
                    ) from None

            yield evaluate_many
        finally:
            client.close()


@contextmanager
def _dask_logs_off() -> Iterator[None]:
    """Dask's log lines off while the tuning uses it: a lost scheduler logged warnings and
    tracebacks of its own around the one-line error that says so."""
    loggers = [
        logging.getLogger(name)
        for name in list(logging.root.manager.loggerDict)
        if name.partition(".")[0] in ("distributed", "tornado")
    ]
    levels = [log.level for log in loggers]
    for log in loggers:
        log.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for log, level in zip(loggers, levels, strict=True):
            log.setLevel(level)


def _concurrent(future: DaskFuture) -> Future:
    """A :class:`concurrent.futures.Future` that ends as the Dask ``future`` does. (Dask's
    own, from ``Client.get_executor``, never ended when the result was lost with the
    scheduler after the task had finished: the tuning then waited forever.)"""
    concurrent: Future = Future()
    concurrent.set_running_or_notify_cancel()  # (a stop leaves it: the client's close ends it)

    def settle(done: DaskFuture) -> None:  # (in Dask's callback thread)
        try:
            concurrent.set_result(done.result())
        except BaseException as exc:  # the task's error, or its loss
            concurrent.set_exception(exc)

    future.add_done_callback(settle)
    return concurrent


def _connect(client_class: type[Client], address: str, stop: StopRequest | None) -> Client:
    """A client of the scheduler at ``address``, connected in a thread of its own, so that
    a stop need not wait for the connection (a Ctrl-C waited out its timeout, then was
    told that no scheduler answers, exit 2) and nothing waits much past
    :data:`CONNECT_TIMEOUT_S` (Dask waits forever for a peer that takes the connection
    and says nothing, Ctrl-C or not).

    Raises
    ------
    OSError
        No scheduler answered in time.
    Stopped
        ``stop`` was set meanwhile.
    """
    connected: Future = Future()

    def connect() -> None:
        try:
            client = client_class(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except BaseException as exc:  # handed to the waiting thread, if it still waits
            if connected.set_running_or_notify_cancel():
                connected.set_exception(exc)
            return
        if connected.set_running_or_notify_cancel():
            connected.set_result(client)
        else:  # given up: nobody will close it
            client.close()

    threading.Thread(target=connect, name="motionbase-dask-connect", daemon=True).start()
    patience_s = CONNECT_TIMEOUT_S + 1.0  # (Dask's own timeout, where it keeps it, first)
    deadline = time.monotonic() + patience_s
    while not wait_futures([connected], timeout=STOP_POLL_S).done:
        if (stop or time.monotonic() > deadline) and connected.cancel():
            raise_if_stopped(stop)
            raise OSError(f"no answer within {patience_s:g} s")
    return connected.result()


def _check_cluster(client: Client, address: str) -> None:
    """Raise unless the scheduler has workers and each runs this version of motionbase
    (a worker without it failed the problem's scatter with a traceback; with none, the
    scatter timed out with one)."""
    from motionbase import __version__

    found = client.run(_motionbase_version, on_error="return")
    if not found:
        raise SourceError(
            f"--scheduler {address}: the scheduler has no workers; start them "
            f"(dask worker {address}) on machines with motionbase installed"
        )
    for worker, version in sorted(found.items()):
        if version != __version__:
            has = (
                f"cannot run motionbase ({version})"
                if isinstance(version, BaseException)
                else f"runs motionbase {version}"
            )
            raise ConfigError(
                f"--scheduler {address}: the worker {worker} {has}, this is motionbase "
                f"{__version__}; install this version on every machine (pip install "
                f"'motionbase[cluster]=={__version__}')"
            )


def _motionbase_version() -> str:
    """This process's motionbase version (run on each Dask worker by :func:`_check_cluster`)."""
    from motionbase import __version__

    return __version__
