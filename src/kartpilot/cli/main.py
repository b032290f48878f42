"""``kartpilot``: one command, thin subcommands.

A known error (:class:`KartpilotError`) prints one line and exits 1; so does an operating-system error
(a full disk, a file that vanished: it names the file). SIGTERM (what service managers and containers send) ends
a command as Ctrl-C does, through the same clean-up (a drive stops the kart and closes its recording), and exits
143. A usage error, checked before any work by
:mod:`kartpilot.cli.values`, prints one line and exits 2. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Sequence

from kartpilot import __version__
from kartpilot.cli.arguments import add_parsers
from kartpilot.cli.values import OneLineParser, check_paths, output_dests
from kartpilot.core.errors import KartpilotError

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="kartpilot", description="Camera-only self-driving stack for karts.")
    parser.add_argument("--version", action="version", version=f"kartpilot {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log each stage's decisions")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_parsers(sub)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C's KeyboardInterrupt is, so every clean-up that handles one handles both."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated()


def _positionals(parser: argparse.ArgumentParser) -> frozenset[str]:
    names = set()
    for action in parser._actions:
        if not action.option_strings:
            names.add(action.dest)
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                names |= _positionals(sub)
    return frozenset(names)


def main(argv: Sequence[str] | None = None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        try:
            check_paths(args, output_dests(parser, args), _positionals(parser))
        except argparse.ArgumentTypeError as exc:
            parser.error(str(exc))
        if getattr(args, "check", None) is not None:  # a subcommand's check across its options (a usage error)
            args.check(args)
    except SystemExit as exc:  # --help, --version, or a usage error (already printed on one line)
        return exc.code if isinstance(exc.code, int) else 0
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    previous = signal.signal(signal.SIGTERM, _terminate) if threading.current_thread() is threading.main_thread() \
        else None
    try:
        return int(args.handler(args))
    except KartpilotError as exc:
        print(f"kartpilot: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"kartpilot: error: {exc}", file=sys.stderr)
        return 1
    except Terminated:
        print("kartpilot: terminated (SIGTERM)", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print("kartpilot: interrupted", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
