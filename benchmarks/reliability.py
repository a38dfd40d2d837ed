"""Reliability count (issue 14): many generated and mutated specs, malformed data files and careless
command lines, each sorted by what came of it. The counts that must be zero: tracebacks, hangs over
5 s, accepted specs with non-finite matrices or sample time, NaN posteriors from finite data, unclear
error messages, and outputs written over inputs. A hang is a spec still loading, simulating or
filtering after 5 s of CPU time (CPU time, so a machine busy with other work does not count).

    python benchmarks/reliability.py                      # 10,000 specs, 2,000 data files
    python benchmarks/reliability.py --specs 1000 --data 200 --workers 2

The generators are the fuzz tests' own (tests/test_fuzz.py), drawn by hypothesis with one seed per
worker, so a run is reproducible for the same --specs, --data and --workers. docs/reliability.md
explains the checks and holds the table of the last run.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import resource
import sys
import time
from collections import Counter
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))
os.environ.setdefault("JMLGDSL_FUZZ", "1")  # mutate every bundled spec, the slow ODE plants too

import test_fuzz as fuzz  # noqa: E402  (the generators and checks of the fuzz tests)
from hypothesis import HealthCheck, Phase, given, seed, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

HANG_SECONDS = 5
KEEP = 5  # failing cases kept per worker, kind and outcome
BAD = ("traceback", "hang", "non-finite model", "NaN posterior", "unclear message", "data lost")


def _drive(strategy, examples, worker, body):
    """Call body(example) on `examples` draws of `strategy`, seeded by `worker`, generating only."""
    @seed(worker)
    @settings(max_examples=examples, database=None, deadline=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(strategy)
    def each(example):
        body(example)

    each()


def specs(job):
    """(kind, worker, examples) -> the outcomes of that many specs, and a few failing texts."""
    kind, worker, examples = job
    counts, failures = Counter(), []
    strategy = fuzz.mutated_specs() if kind == "mutated" else st.one_of(fuzz.GRAMMAR_SPECS, fuzz.spliced_specs())

    def body(text):
        try:
            outcome = fuzz.spec_outcome(text, HANG_SECONDS)
        except Exception as exc:  # what the count is for: any exception other than SpecError
            outcome = "traceback"
            text = f"# {type(exc).__name__}: {exc}\n{text}"
        counts[f"{kind} specs: {outcome}"] += 1
        if outcome in BAD and counts[f"{kind} specs: {outcome}"] <= KEEP:
            failures.append(f"# outcome: {outcome}\n{text}")

    _drive(strategy, examples, worker, body)
    return counts, failures


def command_outcome(argv) -> str:
    """'clean' (exit 0, or exit 2 with one error line), 'unclear message' or 'traceback'."""
    try:
        status, err = fuzz.command(argv)
    except Exception:
        return "traceback"
    try:
        fuzz.assert_clean(status, err)
    except AssertionError:
        return "unclear message" if status == 2 else "traceback"
    return "clean"


def data(job):
    """(worker, examples) -> the outcomes of that many malformed files read and run, and a few failures."""
    worker, examples = job
    counts, failures = Counter(), []

    def body(content):
        path = fuzz.written(content, f"data-{worker}.csv")
        try:
            fuzz.read_csv(path, fuzz.dryer())
            read = "read"
        except fuzz.DataError:
            read = "data error"
        except Exception:
            read = "traceback"
        ran = command_outcome(["run", fuzz.MODEL, path])
        counts[f"data files, read: {read}"] += 1
        counts[f"data files, run: {ran}"] += 1
        if (read in BAD or ran in BAD) and len(failures) < KEEP:
            failures.append(f"# read: {read}, run: {ran}\n{content!r}")

    with contextlib.redirect_stderr(open(os.devnull, "w")):  # read_csv's warnings
        _drive(fuzz.DATA, examples, worker, body)
    return counts, failures


def command_lines(folder: Path):
    """Careless command lines (issue 14, items 12-18): (what, argv, file that must be left as it was)."""
    spec, model = ROOT / "specs" / "dryer.jmlg", fuzz.MODEL
    good = folder / "good.csv"
    assert fuzz.main(["simulate", str(model), "--modes", "1-20:normal,21-40:fan", "--seed", "1", "-o", str(good)]) == 0
    result = folder / "result.csv"
    assert fuzz.command(["run", model, good, "-o", result])[0] == 0
    files = {
        "latin1.csv": "time,temp\n1,5\xb00\n".encode("latin-1"), "utf16.csv": "time,temp\n1,50\n".encode("utf-16"),
        "binary.csv": b"\x89PNG\r\n\x1a\n\x00\x00", "long.csv": b"time,temp\n1," + b"5" * 200_000 + b"\n",
        "ragged.csv": b"time,one,temp,mode\n1,1,50\n", "comma.csv": b"time,one,temp\n1,1,50,5\n",
        "semicolon.csv": b"time;one;temp\n1;1;50,5\n", "blank-mode.csv": b"one,temp,mode\n1,50,\n1,51,fan\n",
        "backwards.csv": b"time,one,temp\n2,1,50\n1,1,51\n", "empty.csv": b"", "header.csv": b"time,temp\n",
        "huge.csv": b"time,one,temp\n1,1e300,50\n", "latin1-result.csv": result.read_bytes() + b"\xe9\n",
        "one.mat": b"MATLAB 5.0", "existing": b"x",
    }
    for name, content in files.items():
        (folder / name).write_bytes(content)
    f = {name: folder / name for name in files}
    cases = [(f"run on {name}", ["run", model, f[name]], None) for name in files if name.endswith(".csv")]
    cases += [
        ("run -o its own data", ["run", model, good, "-o", good], good),
        ("simulate -o its spec", ["simulate", spec, "--steps", "3", "-o", spec], spec),
        ("compile -o its spec", ["compile", spec, "-o", spec], spec),
        ("plot of a Latin-1 table", ["plot", f["latin1-result.csv"], "-o", folder / "p.png"], None),
        ("plot of a binary file", ["plot", f["binary.csv"], "-o", folder / "p.png"], None),
        ("plot -o p.txt", ["plot", result, "-o", folder / "p.txt"], None),
        ("plot into a missing folder", ["plot", result, "-o", folder / "no" / "p.png"], None),
        ("compile -o m.txt", ["compile", spec, "-o", folder / "m.txt"], None),
        ("compile into a file's folder", ["compile", spec, "-o", f["existing"] / "m.json"], None),
        ("bench -o an existing file", ["bench", spec, good, "-o", f["existing"]], f["existing"]),
        ("bench --particles 1e9", ["bench", spec, "--simulate", "10", "--particles", "1000000000", "-o", folder / "b"], None),
        ("bench --runs 1e9", ["bench", spec, "--simulate", "10", "--runs", "1000000000", "-o", folder / "b"], None),
        ("bench --prefilter ma:1e20", ["bench", spec, good, "--prefilter", "ma:99999999999999999999", "-o", folder / "b"], None),
        ("simulate --steps 1e9", ["simulate", spec, "--steps", "1000000000"], None),
        ("simulate --steps 0", ["simulate", spec, "--steps", "0"], None),
        ("simulate --modes to 1e11", ["simulate", spec, "--modes", "1-99999999999:normal"], None),
        ("simulate --inputs SPEC", ["simulate", spec, "--inputs", spec], None),
        ("simulate --inputs, more rows than --modes", ["simulate", spec, "--inputs", good, "--modes", "1-5:normal"], None),
        ("run on a .mat model", ["run", f["one.mat"], good], None),
        ("check a .mat model", ["check", f["one.mat"]], None),
        ("run --prefilter ma:1e20", ["run", model, good, "--prefilter", "ma:99999999999999999999"], None),
        ("run --particles 0", ["run", model, good, "--particles", "0"], None),
        ("run --plot fig.txt", ["run", model, good, "--plot", folder / "fig.txt"], None),
        ("run --plot into a missing folder", ["run", model, good, "--plot", folder / "no" / "fig.png"], None),
        ("run -o into a missing folder", ["run", model, good, "-o", folder / "no" / "r.csv"], None),
        ("learn --dt inf", ["learn", "--mode", f"a={good}", "--output", "temp", "--dt", "inf"], None),
        ("learn -o into a missing folder", ["learn", "--mode", f"a={good}", "--output", "temp", "-o", folder / "no" / "s.jmlg"], None),
        ("prbs --dt inf", ["prbs", "--dt", "inf"], None),
        ("prbs --amplitude nan", ["prbs", "--amplitude", "nan"], None),
        ("prbs --around inf", ["prbs", "--around", "inf"], None),
        ("prbs --cells 20 --periods 1000", ["prbs", "--cells", "20", "--periods", "1000"], None),
        ("prbs -o into a missing folder", ["prbs", "-o", folder / "no" / "u.csv"], None),
    ]
    return cases


def run_command_lines(folder: Path):
    """The outcomes of every careless command line, and the ones that failed by name."""
    counts, failures = Counter(), []
    for what, argv, kept in command_lines(folder):
        before = kept.read_bytes() if kept is not None else None
        outcome = command_outcome(argv)
        if kept is not None and kept.read_bytes() != before:
            outcome = "data lost"
        counts[f"command lines: {outcome}"] += 1
        if outcome in BAD:
            failures.append(f"{what}: {outcome}")
    # A closed standard input, in process: sys.stdin is None as after `<&-`.
    stdin, sys.stdin = sys.stdin, None
    try:
        outcome = command_outcome(["run", fuzz.MODEL, "-"])
    finally:
        sys.stdin = stdin
    counts[f"command lines: {outcome}"] += 1
    if outcome in BAD:
        failures.append(f"run - with standard input closed: {outcome}")
    return counts, failures


def split(total, parts):
    """`total` examples over `parts` workers as evenly as whole numbers allow."""
    return [total // parts + (i < total % parts) for i in range(parts)]


def table(counts: Counter) -> str:
    """The counts as a Markdown table, grouped by what was tried."""
    lines = ["| cases | outcome | count |", "| --- | --- | ---: |"]
    for key in sorted(counts):
        group, outcome = key.rsplit(": ", 1)
        mark = " **(must be 0)**" if outcome in BAD else ""
        lines.append(f"| {group} | {outcome}{mark} | {counts[key]:,} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--specs", type=int, default=10_000, help="specs to try (4 in 5 mutated, 1 in 5 from the grammar)")
    parser.add_argument("--data", type=int, default=2_000, help="malformed data files to read and run")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes")
    parser.add_argument("--failures", type=Path, help="folder to keep the failing specs and data in")
    parser.add_argument("--memory", type=float, default=4.0,
                        help="GiB of address space per process, so a request too large fails here rather "
                             "than exhausting the machine (default 4)")
    args = parser.parse_args(argv)
    limit = int(args.memory * (1 << 30))
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    start = time.perf_counter()
    mutated, grammar = args.specs - args.specs // 5, args.specs // 5
    jobs = ([(specs, ("mutated", w, n)) for w, n in enumerate(split(mutated, args.workers)) if n]
            + [(specs, ("grammar", w, n)) for w, n in enumerate(split(grammar, args.workers)) if n]
            + [(data, (w, n)) for w, n in enumerate(split(args.data, args.workers)) if n])
    counts, failures = run_command_lines(fuzz.FOLDER)
    with Pool(args.workers) as pool:
        for found, failed in pool.starmap(_call, jobs):
            counts.update(found)
            failures += failed
    print(table(counts))
    bad = sum(n for key, n in counts.items() if key.rsplit(": ", 1)[1] in BAD)
    print(f"\n{args.specs:,} specs, {args.data:,} data files and {len(command_lines(fuzz.FOLDER)) + 1} command "
          f"lines in {time.perf_counter() - start:.0f} s on {args.workers} process{'es' * (args.workers != 1)}; "
          f"{bad} must-be-zero cases")
    for failure in failures:
        print("\n--- failure ---\n" + failure[:2000])
    if args.failures:
        args.failures.mkdir(parents=True, exist_ok=True)
        for i, failure in enumerate(failures):
            (args.failures / f"failure-{i:03d}.txt").write_text(failure)
    return 1 if bad else 0


def _call(function, job):
    return function(job)


if __name__ == "__main__":
    sys.exit(main())
