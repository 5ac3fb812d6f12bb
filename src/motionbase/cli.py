"""The ``motionbase`` command line: parsing only, every action is a library call.

Subcommands: ``fly``, ``stream``, ``replay``, ``teleop``, ``workspace``, ``report``.
A user mistake (bad file, bad value) prints one line to stderr and exits with
status 2; it is never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from motionbase import __version__
from motionbase.errors import MotionbaseError

# Each subcommand registers (name, add_arguments, run). ``run(args) -> int``.
_Command = tuple[str, str, Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], int]]
COMMANDS: list[_Command] = []


def command(name: str, help_text: str, add_arguments: Callable[[argparse.ArgumentParser], None]):
    """Decorator registering ``run(args)`` as the subcommand ``name``."""

    def register(run: Callable[[argparse.Namespace], int]):
        COMMANDS.append((name, help_text, add_arguments, run))
        return run

    return register


class _Parser(argparse.ArgumentParser):
    """argparse that exits with status 2 and a one-line message (its default, kept explicit)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"motionbase {self.prog.split()[-1]}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="motionbase", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"motionbase {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, help_text, add_arguments, run in COMMANDS:
        p = sub.add_parser(name, help=help_text, description=help_text)
        add_arguments(p)
        p.set_defaults(_run=run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except MotionbaseError as exc:
        print(f"motionbase {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"motionbase {args.command}: interrupted", file=sys.stderr)
        return 130


# --- subcommands -----------------------------------------------------------------
# One block per subcommand: an ``_args_<name>`` function adding its arguments and a
# ``run`` function decorated with @command that only calls into the library.


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
