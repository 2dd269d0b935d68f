"""`civic` command line: one module per subcommand under civic/commands/.

Every subcommand module defines `register(subparsers)`, which adds its parser
and sets `func` to a callable taking the parsed args and returning an exit code.
User errors (`CivicError`) become one line on stderr and exit status 2.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from civic import __version__
from civic.errors import CivicError

COMMANDS = ("train", "crossval", "replay", "evaluate", "configure", "watch", "monitor", "opcua-user", "simulate",
            "diagnose")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="civic", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"civic {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module_name = f"civic.commands.{name.replace('-', '_')}"
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:
                continue  # subcommand not built in this checkout
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CivicError as exc:
        print(f"civic {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"civic {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1


if __name__ == "__main__":
    sys.exit(main())
