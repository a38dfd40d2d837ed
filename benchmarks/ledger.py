"""The results ledger: every figure the README, docs/ and BENCHMARKS.md quote as a result, with the
command that made it, the commit it ran at and the machine (benchmarks/ledger.json).

    python benchmarks/ledger.py show [KEY ...]   # the entries, or some of them
    python benchmarks/ledger.py check            # every marked figure in the docs against the ledger
    python benchmarks/ledger.py render           # rewrite every marked figure and table from the ledger

A benchmark script records what it measured with `record(key, figures, command)`: one entry per key,
replaced whole, the file written whole or not at all. `figures` maps a name to a number (or to a
Markdown table, a string); `tolerance` says, per figure, by how much a re-run may differ from the
recorded value and still reproduce it (absent: exactly), and `timings` holds what was timed on
the way, recorded and never compared.

A doc quotes a figure through a mark that names it, so a figure is never typed by hand:

    strict F1 <!--ledger skab/strict f1 .2f-->0.81<!--/ledger-->
    <!--ledger skab/strict table-->
    | ... the table, as the script rendered it ... |
    <!--/ledger-->

`render` writes the ledger's value (a number formatted by the format spec, when one is given; a
text as it is, on lines of its own when it has several, or as a fenced code block with the format
`code`) between the marks; `check` (and tests/test_ledger.py) fails on any mark whose text differs
from what `render` would write, or that names an entry or a figure the ledger lacks.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

from jmlgdsl.output import writing

REPO = Path(__file__).resolve().parents[1]
LEDGER = REPO / "benchmarks" / "ledger.json"
DOCS = ("README.md", "BENCHMARKS.md", "docs/*.md")
MARK = re.compile(r"<!--ledger (?P<key>[^\s>]+) (?P<name>[^\s>]+)(?: (?P<format>[^\s>]+?))?-->(?P<text>.*?)<!--/ledger-->",
                  re.S)


def machine() -> str:
    """The machine a figure was measured on, in the words BENCHMARKS.md uses: processor, cores, system,
    Python and the numerical libraries' versions, and the BLAS kernel numpy runs."""
    import numpy
    import scipy

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    kernel = ""
    try:
        from threadpoolctl import threadpool_info

        kernel = next((f", OpenBLAS {i['architecture']}" for i in threadpool_info()
                       if i.get("internal_api") == "openblas"), "")
    except ImportError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.machine()}, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}, scipy {scipy.__version__}{kernel}")


#: What makes a figure: a change to these since the commit makes the recorded commit '+changes' (what
#: the benchmarks write themselves, their results/ folders and this ledger, does not count).
MAKERS = ("jmlgdsl", "grammars", "specs", "examples", "benchmarks", ":!benchmarks/ledger.json",
          ":!benchmarks/*/results/*")


def commit() -> str:
    """The checkout's commit, with '+changes' when the code and data that make the figures (MAKERS)
    differ from it (a figure from code that is not committed yet); 'unknown' outside a git checkout."""
    def git(*args):
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()
    try:
        head = git("rev-parse", "--short=10", "HEAD")
        changed = git("status", "--porcelain", "--untracked-files=no", "--", *MAKERS)
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+changes" if changed else "")


def load(path: Path = LEDGER) -> dict:
    """The ledger: {key: entry}; empty where the file does not exist yet."""
    return json.loads(path.read_text()) if path.exists() else {}


def record(key: str, figures: dict, command: str, tolerance: dict | None = None, timings: dict | None = None,
           path: Path = LEDGER) -> dict:
    """Put one entry into the ledger at `path` (replacing the key's old entry) and return it."""
    unknown = set(tolerance or {}) - set(figures)
    if unknown:
        raise ValueError(f"tolerance for figures that {key} does not record: {sorted(unknown)}")
    entry = {"command": command, "commit": commit(), "machine": machine(),
             "date": datetime.date.today().isoformat(), "figures": figures}
    if tolerance:
        entry["tolerance"] = tolerance
    if timings:
        entry["timings"] = timings
    ledger = load(path)
    ledger[key] = entry
    with writing(path) as f:  # whole or not at all
        f.write(json.dumps(dict(sorted(ledger.items())), indent=1, ensure_ascii=False) + "\n")
    return entry


def ledger_argument(parser: argparse.ArgumentParser):
    """--ledger PATH: where a benchmark script records its figures (a re-run that only checks them
    writes a copy elsewhere)."""
    parser.add_argument("--ledger", type=Path, default=LEDGER, metavar="PATH",
                        help=f"the results ledger to record the figures in (default: {LEDGER.relative_to(REPO)})")


def disagreements(entry: dict, again: dict) -> list[str]:
    """What a re-run's entry `again` gives beyond the recorded `entry`'s tolerances, one line a figure
    (Markdown tables, as rendered from figures that are compared, are not compared themselves)."""
    lines = []
    tolerance = entry.get("tolerance", {})
    for name, value in entry["figures"].items():
        if isinstance(value, str):
            continue
        new = again["figures"].get(name)
        if new is None or value is None:
            if new is not value:
                lines.append(f"{name}: recorded {value}, now {new}")
        elif abs(new - value) > tolerance.get(name, 0):
            lines.append(f"{name}: recorded {value}, now {new} (tolerance {tolerance.get(name, 0)})")
    return lines


def doc_files(root: Path = REPO) -> list[Path]:
    return sorted({p for pattern in DOCS for p in root.glob(pattern)})


def rendered(mark: re.Match, ledger: dict) -> str:
    """The text a mark should hold: the figure from the ledger, formatted; raises KeyError naming what
    the ledger lacks."""
    key, name, spec = mark["key"], mark["name"], mark["format"]
    if key not in ledger:
        raise KeyError(f"no ledger entry {key!r}")
    if name not in ledger[key]["figures"]:
        raise KeyError(f"ledger entry {key!r} has no figure {name!r}")
    value = ledger[key]["figures"][name]
    if isinstance(value, str):
        body = value.strip("\n")
        if spec == "code":
            body = f"```\n{body}\n```"
        return f"\n{body}\n" if "\n" in body else body
    return format(value, spec or "")


def check(root: Path = REPO, ledger: dict | None = None) -> list[str]:
    """Every mark in the docs whose text is not what the ledger says, as 'file:line: what'."""
    ledger = load() if ledger is None else ledger
    problems = []
    for path in doc_files(root):
        text = path.read_text()
        for mark in MARK.finditer(text):
            where = f"{path.relative_to(root)}:{text.count(chr(10), 0, mark.start()) + 1}"
            try:
                want = rendered(mark, ledger)
            except KeyError as e:
                problems.append(f"{where}: {e.args[0]}")
                continue
            if mark["text"] != want:
                problems.append(f"{where}: {mark['key']} {mark['name']} says {mark['text'].strip()!r}, "
                                f"the ledger {want.strip()!r}")
    return problems


def render(root: Path = REPO, ledger: dict | None = None) -> list[Path]:
    """Rewrite every mark in the docs from the ledger; the files that changed."""
    ledger = load() if ledger is None else ledger
    changed = []
    for path in doc_files(root):
        text = path.read_text()
        new = MARK.sub(lambda m: m[0][:m.start("text") - m.start()] + rendered(m, ledger) + "<!--/ledger-->", text)
        if new != text:
            with writing(path) as f:
                f.write(new)
            changed.append(path)
    return changed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="verb", required=True)
    show = sub.add_parser("show", help="print the ledger's entries (all, or those named)")
    show.add_argument("keys", nargs="*")
    sub.add_parser("check", help="every marked figure in the docs against the ledger")
    sub.add_parser("render", help="rewrite every marked figure and table in the docs from the ledger")
    args = parser.parse_args(argv)
    if args.verb == "show":
        ledger = load()
        missing = [k for k in args.keys if k not in ledger]
        if missing:
            parser.error(f"no ledger entry {', '.join(missing)} (there are: {', '.join(ledger)})")
        print(json.dumps({k: v for k, v in ledger.items() if not args.keys or k in args.keys}, indent=1,
                         ensure_ascii=False))
    elif args.verb == "check":
        problems = check()
        print("\n".join(problems) or "every marked figure agrees with the ledger")
        return 1 if problems else 0
    else:
        try:
            changed = render()
        except KeyError as e:
            print(f"nothing more rewritten: {e.args[0]} (run the script that records it first)", file=sys.stderr)
            return 1
        print("\n".join(f"rewrote {p.relative_to(REPO)}" for p in changed) or "the docs already agree with the ledger")
    return 0


if __name__ == "__main__":
    sys.exit(main())
