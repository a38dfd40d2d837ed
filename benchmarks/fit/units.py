"""A fleet of dryers whose units each settle at their own temperature: fit every unit its own numbers
from its own recording, then diagnose the fleet with its unit specs (docs/fleet.md, "Units with
their own numbers").

    python benchmarks/fit/units.py                   # 6 units, offsets of sd 1.5 degC
    python benchmarks/fit/units.py --units 20 --seed 3

Unit k's settled temperatures are the design's (examples/fit/dryer_unit.jmlg) plus its own offset,
drawn from Normal(0, --sd). Each unit has a training recording (--train rows of its own history
through TRAIN, unlabelled, as a plant's archive is) and a test recording (dryer sequence No. 1,
labelled, a fresh seed). Everything goes through the commands a user types:

    jmlgdsl fit examples/fit/dryer_unit.jmlg train/*.csv -o fitted/
    jmlgdsl run examples/fit/dryer_unit.jmlg test/*.csv --unit-specs fitted/   # each unit its own numbers
    jmlgdsl run examples/fit/dryer_unit.jmlg test/*.csv --unit-specs truth/    # each unit's true numbers
    jmlgdsl run examples/fit/dryer_unit.jmlg test/*.csv                        # one shared spec

The figures (records into the results ledger as `fleet/unit-specs`): how many units' fits land
within 3 standard errors of their true offsets, and the fleet's diagnosis error (rows over all
units) under the fitted unit specs, the true ones and the one shared spec.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.cli import main as jmlgdsl_main
from jmlgdsl.data import write_columns
from jmlgdsl.fitting import Family
from jmlgdsl.lang.parse import parse_file

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))
from ledger import ledger_argument, record  # noqa: E402

TEMPLATE = REPO / "examples" / "fit" / "dryer_unit.jmlg"
TRAIN = "1-300:normal,301-420:fan,421-700:normal,701-800:grill,801-1000:normal"  # a unit's history
TEST = "1-70:normal,71-238:fan,239-365:grill,366-513:normal,514-705:grill,706-1000:fan"  # sequence No. 1


def command(*argv) -> str:
    """A jmlgdsl command as a user runs it: its standard output (a failure raises)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = jmlgdsl_main([str(a) for a in argv])
    if status:
        raise SystemExit(f"jmlgdsl {' '.join(map(str, argv))} exited with {status}:\n{err.getvalue()}")
    return out.getvalue()


def recording(model, schedule, seed, path, labelled):
    """Simulate the model through the schedule and write its CSV (with the true mode when labelled)."""
    sim = jmlgdsl.simulate(model, modes=schedule, seed=seed)
    columns = {"time": np.arange(len(sim.y)) * model.dt, "temp": sim.y[:, 0], "current": sim.u[:, 0]}
    if labelled:
        columns["mode"] = [model.modes[k] for k in sim.modes]
    write_columns(path, columns)


def fleet_error(output: str) -> tuple[float, list[float]]:
    """The fleet's diagnosis error % (rows over every unit) and each unit's, from `run`'s unit lines."""
    errors = [float(e) for e in re.findall(r"diagnosis error ([0-9.]+) %", output)]
    return float(np.mean(errors)), errors  # every test recording has the same number of rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--units", type=int, default=6)
    parser.add_argument("--sd", type=float, default=1.5, help="spread of the units' offsets, degC (1.5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, help="units fitted at a time (default: every core)")
    ledger_argument(parser)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    offsets = rng.normal(0.0, args.sd, args.units)
    spec = parse_file(TEMPLATE)
    family = Family(spec)
    units = [f"dryer{k + 1:02d}" for k in range(args.units)]
    with tempfile.TemporaryDirectory() as name:
        root = Path(name)
        for folder in ("train", "test", "truth", "fitted"):
            (root / folder).mkdir()
        template = TEMPLATE.read_text()
        for k, (unit, offset) in enumerate(zip(units, offsets)):
            model = family.model(np.array([offset]))
            recording(model, TRAIN, (args.seed, k, 0), root / "train" / f"{unit}.csv", labelled=False)
            recording(model, TEST, (args.seed, k, 1), root / "test" / f"{unit}.csv", labelled=True)
            (root / "truth" / f"{unit}.jmlg").write_text(template.replace("param offset ~ Normal(0, 3)",
                                                                           f"param offset = {float(offset)!r}"))
        start = time.perf_counter()
        command("fit", TEMPLATE, *sorted((root / "train").glob("*.csv")), "-o", f"{root / 'fitted'}/", "-q",
                *(["--jobs", args.jobs] if args.jobs else []))
        fit_seconds = time.perf_counter() - start
        with open(root / "fitted" / "units.csv") as stream:
            fitted = {row["unit"]: row for row in csv.DictReader(stream)}
        tests = sorted((root / "test").glob("*.csv"))
        runs = {how: fleet_error(command("run", TEMPLATE, *tests, *extra)) for how, extra in (
            ("unit_specs", ["--unit-specs", root / "fitted"]), ("true_specs", ["--unit-specs", root / "truth"]),
            ("shared_spec", []))}
    rows = ["| unit | true offset | fitted | se | within 3 se | error %, unit spec | true spec | shared spec |",
            "|---|---:|---:|---:|---|---:|---:|---:|"]
    within = 0  # units whose fit lands within 3 se of the truth
    for k, (unit, offset) in enumerate(zip(units, offsets)):
        estimate, se = float(fitted[unit]["offset"]), float(fitted[unit]["offset_se"] or "nan")
        ok = bool(abs(estimate - offset) <= 3 * se)
        within += int(ok)
        rows.append(f"| {unit} | {offset:+.3f} | {estimate:+.3f} | {se:.3f} | {'yes' if ok else 'no'} | "
                    + " | ".join(f"{runs[how][1][k]:.2f}" for how in ("unit_specs", "true_specs", "shared_spec")) + " |")
    rows.append(f"| fleet | | | | {within} of {args.units} | "
                + " | ".join(f"**{runs[how][0]:.2f}**" for how in ("unit_specs", "true_specs", "shared_spec")) + " |")
    table = "\n".join(rows)
    print(table)
    print(f"\nfitting {args.units} units took {fit_seconds:.1f} s")
    figures = {"units": args.units, "sd": args.sd, "within_3se": within,
               **{f"{how}_error": round(runs[how][0], 4) for how in runs}, "table": table}
    record("fleet/unit-specs", figures, "python benchmarks/fit/units.py " + " ".join(argv or sys.argv[1:]),
           tolerance={f"{how}_error": 0.05 for how in runs}, timings={"fit_seconds": round(fit_seconds, 1)},
           path=args.ledger)
    return 0


if __name__ == "__main__":
    sys.exit(main())
