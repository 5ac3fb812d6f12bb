"""The ``motionbase`` command, and ``python -m motionbase ARGS``."""

import sys


def main() -> int:
    """The command line (:mod:`motionbase.cli`), with the stop signals (Ctrl-C, SIGTERM,
    SIGHUP, SIGQUIT) held from its first line: its imports take a few tenths of a second,
    and a stop signal meanwhile stops the job as it starts instead of killing the process
    (:func:`motionbase.stopping.catch_early_stops`)."""
    from motionbase.stopping import catch_early_stops  # (the standard library only)

    catch_early_stops()
    from motionbase.cli import main as command_line  # (its imports guard Ctrl-C)

    return command_line()


if __name__ == "__main__":
    sys.exit(main())
