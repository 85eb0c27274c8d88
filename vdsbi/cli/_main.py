"""Argument parsing, command dispatch and the user-error wrapper."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from .. import __version__
from ..io import InputError

#: Exit status for bad user input (same as argparse's usage errors).
EXIT_INPUT = 2


def build_parser() -> argparse.ArgumentParser:
    from . import COMMANDS

    parser = argparse.ArgumentParser(
        prog="vdsbi",
        description="Vehicle-dynamics identification by simulation-based inference.",
    )
    parser.add_argument("--version", action="version", version=f"vdsbi {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        module = importlib.import_module(name, package=__package__)
        sp = module.add_parser(sub)
        sp.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; return the exit status (0 ok, 1 unexpected failure, 2 bad input).

    Bad user input (`InputError`, which every reader raises) prints one line
    ``vdsbi: error: <file>: <field>: <what>`` to stderr without a traceback; any other exception
    propagates with its traceback.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except InputError as err:
        print(f"vdsbi: error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("vdsbi: interrupted", file=sys.stderr)
        return 130


def entry() -> None:  # pragma: no cover - console-script shim
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
