"""The teleop mouse window's own process: a Tk window that reports the pointer and the
E-stop keys and draws what it is sent (:class:`motionbase.io.cursor_input.TkCursor`
starts it with the ``spawn`` context of :mod:`multiprocessing`).

Tk runs here, not in the process that drives the robot: when the X display goes away
(``xvfb-run``'s Xvfb killed by the same Ctrl-C, a remote display dropped), Xlib ends the
process it is in (its IO error handler calls ``exit(1)``; Tk cannot replace it), and that
must not be the process that parks the robot. This module imports nothing of motionbase,
so the window opens without loading the pipeline's libraries a second time.

Messages to the parent over the pipe: ``("ready",)`` once Tk is up, or ``("error", text)``
when it cannot open or fails; then, every poll (about 100 a second),
``("pointer", u, v, inside)`` (pixels, and whether the pointer is over the window: the
parent's sign of life too); ``("key", keysym)`` for Escape and space; ``("drawn",)`` after
each drawing; ``("closed",)`` when the window is closed. From the parent: the background's
drawing ops first (the workspace, some 100 kB: on the pipe, not as an argument of the
process, which ``spawn`` would write for ever to a process that ended before it read them
all), then ``("draw", ops, status)`` (the robot's items, replacing the previous ones, and
the status line) and ``("quit",)``. A drawing op is ``(kind, coords, options)``: the
canvas's ``create_<kind>(*coords, **options)``.
"""

from __future__ import annotations

import signal
from typing import Any

#: The signals the parent handles (it stops the run and parks the robot): ignored here, so
#: a Ctrl-C sent to the whole process group leaves the window up while the robot parks.
#: The parent blocks them while it starts this process (the mask is inherited), so none
#: arrives before they are ignored.
PARENT_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)

#: The longest wait for the parent's messages between two looks at the pointer, s.
POLL_S = 0.01


def draw(canvas: Any, ops: list[tuple[str, list[float], dict[str, Any]]], tags: str = "") -> None:
    """Run the drawing ops on ``canvas``, the items tagged ``tags``."""
    for kind, coords, options in ops:
        getattr(canvas, f"create_{kind}")(*coords, tags=tags, **options)


def main(conn: Any, title: str, size_px: tuple[int, int]) -> None:
    """The window's process: open the window, draw the background the parent sends first,
    then report the pointer and keys and draw what the parent sends until it quits, the
    window is closed or the pipe ends (the parent is gone)."""
    for sig in PARENT_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, PARENT_SIGNALS)
    try:
        try:
            import tkinter as tk

            root = tk.Tk()
        except Exception as exc:  # TclError without a display, ImportError without Tk
            conn.send(("error", str(exc)))
            return
        _run(conn, tk, root, title, size_px)
    except (EOFError, OSError):  # the parent is gone
        pass
    except Exception as exc:  # noqa: BLE001 - said to the parent, which parks the robot
        conn.send(("error", f"{type(exc).__name__}: {exc}"))


def _run(conn: Any, tk: Any, root: Any, title: str, size_px: tuple[int, int]) -> None:
    root.title(title)
    w, h = size_px
    canvas = tk.Canvas(root, width=w, height=h, background="#f2f2f2")
    canvas.pack()
    conn.send(("ready",))
    draw(canvas, conn.recv())
    status = canvas.create_text(8, 60, anchor="nw", fill="#c0392b", text="")
    closed: list[bool] = []
    root.protocol("WM_DELETE_WINDOW", lambda: closed.append(True))
    for key in ("<Escape>", "<space>"):
        root.bind(key, lambda event: conn.send(("key", event.keysym)))
    root.update()
    while not closed:
        root.update()
        u = canvas.winfo_pointerx() - canvas.winfo_rootx()
        v = canvas.winfo_pointery() - canvas.winfo_rooty()
        conn.send(("pointer", float(u), float(v), 0 <= u < w and 0 <= v < h))
        latest = None
        if conn.poll(POLL_S):
            while True:  # the latest drawing only: older ones are stale
                msg = conn.recv()
                if msg[0] == "quit":
                    return
                latest = msg
                if not conn.poll():
                    break
        if latest is not None:
            canvas.delete("robot")
            draw(canvas, latest[1], "robot")
            canvas.itemconfigure(status, text=latest[2])
            conn.send(("drawn",))
    conn.send(("closed",))
