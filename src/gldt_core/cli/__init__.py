"""The ``gldt`` command line.

Every module in this package that defines ``register(subparsers)`` contributes one
subcommand, so a new feature adds a file here and never edits a shared list. Modules must
keep their imports light (argparse only at module level) so ``gldt --help`` stays fast and
torch-free; the handler imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Callable, Sequence


class CliError(Exception):
    """An error the user can fix; printed as one line without a traceback."""


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with one subparser per discovered command module."""
    from gldt_core import __version__

    parser = argparse.ArgumentParser(
        prog="gldt",
        description="GL-DT: find small drones in video and keep a stable identity on each.",
    )
    parser.add_argument("--version", action="version", version=f"gldt {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module_info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if module_info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{module_info.name}")
        register: Callable[[argparse._SubParsersAction], None] | None = getattr(module, "register", None)
        if register is not None:
            register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``gldt`` console script; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler = getattr(args, "func", None)
    if handler is None:
        parser.print_help()
        return 2
    try:
        result = handler(args)
    except CliError as error:
        print(f"gldt {args.command}: error: {error}", file=sys.stderr)
        return 2
    except (FileNotFoundError, ValueError) as error:
        print(f"gldt {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"gldt {args.command}: interrupted", file=sys.stderr)
        return 130
    return int(result or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
