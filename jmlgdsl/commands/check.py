"""`jmlgdsl check SPEC...`: parse, check and compile specs; print a short summary of each."""

from __future__ import annotations

import sys
import warnings

from ..errors import JmlgError, SpecError, SpecWarning


def register(sub):
    p = sub.add_parser(
        "check", help="check specs and summarise them",
        description="Parse, check and compile each .jmlg spec. Prints a summary (modes, sizes, sample "
                    "time, warnings) or every error found as file:line:col. Exit status 0 when every "
                    "spec is valid, 2 otherwise.")
    p.add_argument("specs", nargs="+", metavar="SPEC", help=".jmlg files to check")
    p.add_argument("-q", "--quiet", action="store_true", help="print errors and warnings only")
    p.set_defaults(func=run)


def summary(model) -> str:
    """A few lines describing a compiled model."""
    from ..names import plural

    modes = ", ".join(model.modes)
    return (f"plant {model.name}: {plural(model.K, 'mode')} ({modes})\n"
            f"  states {model.nx} ({', '.join(model.states)}), outputs {model.ny} ({', '.join(model.outputs)}), "
            f"inputs {model.nu} ({', '.join(model.inputs) or '-'}), sample time {_seconds(model.dt)}")


def _seconds(dt: float) -> str:
    for unit, size in (("h", 3600.0), ("min", 60.0)):
        if dt >= size and (dt / size) == round(dt / size, 6):
            return f"{dt / size:g} {unit}"
    return f"{dt:g} s"


def run(args) -> int:
    from .. import load
    from ..names import plural

    status = 0
    for path in args.specs:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", SpecWarning)
            try:
                model = load(path)
            except JmlgError as exc:  # a spec's errors are located lines; any other is one `error:` line
                print(exc if isinstance(exc, SpecError) else f"error: {exc}", file=sys.stderr)
                status = 2
                continue
        for w in caught:
            print(w.message, file=sys.stderr)
        if not args.quiet:
            note = f", {plural(len(caught), 'warning')}" if caught else ""
            print(f"{path}: ok{note}\n  " + summary(model).replace("\n", "\n  "))
    return status
