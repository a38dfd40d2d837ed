"""The `jmlgdsl` command: a thin argparse shell over the Python API.

Each subcommand is a module in jmlgdsl/commands/ with `register(subparsers)`, which adds its parser
and sets `func(args) -> exit status`. With no arguments the full help, every command with a line,
goes to standard error with exit status 2, as for any other usage error. User errors (JmlgError)
print as located messages, exit 2; so does a request that runs out of memory after the up-front
checks let it through. Warnings about the data (DataWarning) print as `warning: ...` lines.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import warnings

from . import __version__, commands
from .errors import JmlgError, SpecError, SpecWarning

ORDER = ("check", "compile", "simulate", "run", "monitor", "dashboard", "export", "plot", "bench", "prbs", "learn", "fit")


def _command_modules():
    found = {m.name for m in pkgutil.iter_modules(commands.__path__)}
    names = [n for n in ORDER if n in found] + sorted(found - set(ORDER))
    return [importlib.import_module(f"{commands.__name__}.{n}") for n in names]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jmlgdsl",
        description="Fault diagnosis with jump Markov linear Gaussian models: write a plant in the "
                    ".jmlg language, check and compile it, simulate it, and find which mode it is in "
                    "from measured data with particle filters.",
        epilog="Run 'jmlgdsl COMMAND --help' for the options of one command.")
    parser.add_argument("--version", action="version", version=f"jmlgdsl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in _command_modules():
        module.register(sub)
    return parser


def _printable(text: str) -> str:
    """A message as it may reach a terminal: characters that are not printable (a control code from a
    damaged file, a line separator) escaped, so a one-line message stays one line."""
    return "".join(c if c.isprintable() or c == "\n" else repr(c)[1:-1] for c in text)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    text = str(message) if issubclass(category, SpecWarning) else f"warning: {message}"
    print(_printable(text), file=sys.stderr)


def main(argv=None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:  # no command: the list of commands, as a usage error (nothing was done)
        parser.print_help(sys.stderr)
        return 2
    args = parser.parse_args(argv)
    warnings.showwarning = _show_warning
    try:
        return args.func(args) or 0
    except JmlgError as exc:
        print(_printable(str(exc) if isinstance(exc, SpecError) else f"error: {exc}"), file=sys.stderr)
        return 2
    except MemoryError:
        print("error: not enough memory for this request; ask for fewer steps, particles or runs",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
