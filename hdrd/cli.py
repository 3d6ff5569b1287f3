"""The ``hdrd`` command line: the parser built from the commands' table
(:mod:`hdrd.clicommands`) and the dispatch.

Each subcommand names the function that implements it (``module:function``, taking the
parsed arguments and returning an exit status); the module is imported only when the
subcommand runs, so ``hdrd --help`` stays fast. Exit statuses: 0 success, 1 failure,
2 usage error (a malformed command line: unknown option, missing or malformed argument, a
choice not in its list, such as an unknown --drive), 78 configuration error (EX_CONFIG: a
value that fails the configuration's checks, from the file or from a flag that overrides
it, e.g. ``--heading0 400``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from hdrd import __version__
from hdrd.cliargs import HelpFormatter
from hdrd.clicommands import COMMANDS
from hdrd.daemon.signals import command_of, hold_hangup


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hdrd",
        description="Heuristic Drift Reduction daemon and tools for a vehicle yaw-rate gyro "
        "(Borenstein & Ojeda, SPIE 7305, 2009). Rates in deg/s, + = counter-clockwise.",
    )
    parser.add_argument("--version", action="version", version=f"hdrd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (target, help_, add) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_, formatter_class=HelpFormatter)
        add(p)
        p.set_defaults(_target=target, _parser=p)
    return parser


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The parsed command line; on a usage error exit 2 with the usage of the subcommand
    the error is in (argparse's subparsers hand unknown options up to the top-level parser,
    whose usage would not help: ``hdrd run --simualte``)."""
    args, extra = build_parser().parse_known_args(argv)
    if extra:
        args._parser.error("unrecognized arguments: " + " ".join(extra))
    return args


def main(argv: Sequence[str] | None = None) -> int:
    if command_of(list(sys.argv[1:] if argv is None else argv)) == "run":
        # SIGHUP's default action ends the process: hold it from here (the entry point,
        # hdrd.__main__, already has), before parsing, the slow imports and the config,
        # until the daemon installs its reload handler (which takes a held one as a reload).
        hold_hangup()
    args = parse_args(argv)
    module, _, func = args._target.partition(":")
    impl = getattr(importlib.import_module(module), func)
    try:
        return int(impl(args) or 0)
    except KeyboardInterrupt:
        print(f"hdrd {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`hdrd replay ... | head`): not an error worth a traceback.
        _silence_stdout()
        return 0


def _silence_stdout() -> None:
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
