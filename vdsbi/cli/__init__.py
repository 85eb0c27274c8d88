"""Command-line interface: `vdsbi <command> ...`.

Each command lives in its own module exposing `add_parser(subparsers)` (adds and returns its
argparse sub-parser) and `run(args) -> int` (the exit status). `run` parses the arguments (option
values shared by several commands through `_args`), calls `vdsbi.api` and prints; the work is
done there. To add a command, write the module and list it in `COMMANDS`.
"""

#: Modules (relative to this package) that each provide one subcommand, in help order.
COMMANDS: tuple[str, ...] = (
    "._check",
    "._simulate",
    "._identify",
    "._predict",
    "._sample",
    "._demo",
    "._observability",
    "._design",
    "._diagnose",
    "._export",
    "._fleet",
)

from ..io import output_dir as output_dir  # noqa: E402
from ._main import build_parser as build_parser, entry as entry, main as main  # noqa: E402
