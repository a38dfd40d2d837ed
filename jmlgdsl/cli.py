"""The `jmlgdsl` command: a thin argparse shell over the Python API.

Each subcommand is a module in jmlgdsl/commands/ with `register(subparsers)`, which adds its parser
and sets `func(args) -> exit status` (a module whose name begins with an underscore holds what several
commands share). With no arguments the full help, every command with a line, goes to standard error
with exit status 2, as for any other usage error. User errors (JmlgError) print as located messages,
exit 2; so does a request that runs out of memory after the up-front checks let it through. Warnings
about the data (DataWarning) print as `warning: ...` lines.

The command's linear algebra runs on one BLAS thread unless the user sets a thread count
(OPENBLAS_NUM_THREADS, OMP_NUM_THREADS, MKL_NUM_THREADS): its matrices are small (a few dozen
states), where a second thread only waits on the first. Learning a 19-mode bank of 52 outputs took
147 s with OpenBLAS's two threads on a two-core machine, 30 s with one (BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import sys
import warnings

from . import __version__, commands
from .errors import JmlgError, SpecError, SpecWarning

ORDER = ("check", "compile", "simulate", "run", "monitor", "dashboard", "export", "plot", "bench", "prbs", "learn", "fit")


def _command_modules(only=None):
    """The command modules, in ORDER; with `only` a command's name, that module alone (a command pays
    for importing its own dependencies, not every command's: a second of start-up for `run`)."""
    found = {m.name for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_")}
    names = [only] if only in found else [n for n in ORDER if n in found] + sorted(found - set(ORDER))
    return [importlib.import_module(f"{commands.__name__}.{n}") for n in names]


def build_parser(command=None) -> argparse.ArgumentParser:
    """The command line's parser: every command's, or only `command`'s when that names one."""
    parser = argparse.ArgumentParser(
        prog="jmlgdsl",
        description="Fault diagnosis with jump Markov linear Gaussian models: write a plant in the "
                    ".jmlg language, check and compile it, simulate it, and find which mode it is in "
                    "from measured data with particle filters.",
        epilog="Run 'jmlgdsl COMMAND --help' for the options of one command.")
    parser.add_argument("--version", action="version", version=f"jmlgdsl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in _command_modules(command):
        module.register(sub)
    return parser


def _printable(text: str) -> str:
    """A message as it may reach a terminal: characters that are not printable (a control code from a
    damaged file, a line separator) escaped, so a one-line message stays one line."""
    return "".join(c if c.isprintable() or c == "\n" else repr(c)[1:-1] for c in text)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    text = str(message) if issubclass(category, SpecWarning) else f"warning: {message}"
    print(_printable(text), file=sys.stderr)


#: The variables by which a user sets the BLAS thread count; with none set, a command uses one thread.
THREAD_SETTINGS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _blas_threads():
    """One BLAS thread for the command, unless the user has set a thread count."""
    if any(os.environ.get(name) for name in THREAD_SETTINGS):
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv[0] if argv else None)
    if not argv:  # no command: the list of commands, as a usage error (nothing was done)
        parser.print_help(sys.stderr)
        return 2
    args = parser.parse_args(argv)
    warnings.showwarning = _show_warning
    try:
        with _blas_threads():
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
