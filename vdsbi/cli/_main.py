"""Argument parsing, command dispatch and the user-error wrapper."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from .. import __version__
from ..io import InputError

#: Exit status for bad user input (same as argparse's usage errors).
EXIT_INPUT = 2

#: Environment variable naming the folder of compiled programs kept between runs ("off": none).
CACHE_ENV = "VDSBI_COMPILATION_CACHE"
#: The folder's size limit; JAX evicts the least recently used programs beyond it.
CACHE_MAX_BYTES = 2 * 1024**3


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


def compilation_cache_dir(environ=os.environ) -> Path | None:
    """Where the `vdsbi` command keeps compiled programs: ``$VDSBI_COMPILATION_CACHE`` ("off":
    nowhere), else ``$XDG_CACHE_HOME/vdsbi/jax`` (``~/.cache/vdsbi/jax``). None (nothing to set)
    where the user set JAX's own ``JAX_COMPILATION_CACHE_DIR``: JAX reads that itself."""
    if environ.get("JAX_COMPILATION_CACHE_DIR"):
        return None
    value = environ.get(CACHE_ENV)
    if value is not None:
        return None if value.strip().lower() in ("", "off", "0", "none") else Path(value).expanduser()
    base = environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "vdsbi" / "jax"


def _use_compilation_cache(folder: Path | None) -> None:
    """Keep compiled programs in ``folder`` across runs: most of a small run is XLA compiling the
    simulator and the flow for the drive's shapes, which a resumed or repeated `identify`
    reuses. These are process-wide JAX settings, so only the command's own process sets them
    (`entry`), never the library or `main`."""
    if folder is None:
        return
    import jax

    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)


#: XLA flags the `vdsbi` command adds unless the user's ``XLA_FLAGS`` names them: XLA:CPU's older
#: loop emitters compile faster and run no slower, and LLVM's level-1 optimisation compiles
#: faster than its default 3 (a command compiles for about half its time); results move by
#: float32 rounding only.
CLI_XLA_FLAGS = {"xla_cpu_use_fusion_emitters": "false", "xla_backend_optimization_level": "1"}


def xla_flags(environ=os.environ, flags: dict[str, str] = CLI_XLA_FLAGS) -> str:
    """``XLA_FLAGS`` for the `vdsbi` process: the user's, plus those of ``flags`` they do not name."""
    own = environ.get("XLA_FLAGS", "")
    added = [f"--{k}={v}" for k, v in flags.items() if k not in own]
    return " ".join([own, *added]).strip()


def entry() -> None:
    """The ``vdsbi`` command: `main` in a process that keeps its compiled programs and compiles
    with `CLI_XLA_FLAGS`. Both are process-wide settings, so only the command sets them: XLA reads
    its flags when the first computation starts its backend, which `main` has not done yet."""
    os.environ["XLA_FLAGS"] = xla_flags()
    _use_compilation_cache(compilation_cache_dir())
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    entry()
