"""Does `jmlgdsl fit` find the truth, and are its standard errors honest?

For each case, many independent data sets are simulated from a plant with known values, the spec with
those values unknown is fitted to each, and we count how often the estimate lies within 3 standard
errors of the truth and how often the +-1.96 se interval covers it (95 % nominal; with 50 data sets
the count's own standard error is about 3 points, so 90-98 % is what honest errors give).

    python benchmarks/fit/coverage.py [--runs 50] [--jobs 2] [--case cstr|dryer|dryer-unlabelled] [--out DIR]

Each case's table and figures go to OUT/<case>.md and .json and to the results ledger (fit/coverage/<case>;
the shares are figures, the times per fit timings).

Cases:
  cstr              the nonlinear CSTR (ODEs integrated, `simulate --nonlinear`), 2,000 labelled samples
                    through normal and the three fouling modes; unknowns k0, U and the three fouling
                    fractions (examples/fit/cstr10_unknown.jmlg)
  dryer             the dryer's four modes, 1,200 labelled samples under a random telegraph current;
                    unknown: every gain and time constant (examples/fit/dryer_unknown.jmlg)
  dryer-unlabelled  the same data without the mode column: the IMM likelihood
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: threads only fight over the cores (BENCHMARKS.md)

import argparse
import json
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.data import Data
from jmlgdsl import fit

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
import ledger  # noqa: E402  (benchmarks/ledger.py, the results ledger)
CSTR_TRUTH = {"k0": 1.43, "U": 1.2, "f1": 0.95, "f2": 0.90, "f3": 0.85}
CSTR_SCHEDULE = "1-500:normal,501-1000:fouling1,1001-1500:fouling2,1501-2000:fouling3"
DRYER_TRUTH = {"g_normal": 1.94, "tau_normal": 30.45, "g_fan": 1.44, "tau_fan": 25.10,
               "g_grill": 2.34, "tau_grill": 41.68, "g_both": 1.61, "tau_both": 32.96}
DRYER_SCHEDULE = "1-300:normal,301-600:fan,601-900:grill,901-1200:fan_grill"
CASES = {
    "cstr": ("examples/fit/cstr10_unknown.jmlg", CSTR_TRUTH),
    "dryer": ("examples/fit/dryer_unknown.jmlg", DRYER_TRUTH),
    "dryer-unlabelled": ("examples/fit/dryer_unknown.jmlg", DRYER_TRUTH),
}


def telegraph(T: int, rng: np.random.Generator, level=15.0, swing=3.0, mean_hold=20.0) -> np.ndarray:
    """A random telegraph signal: the heater current jumps between level +- swing after holds of
    geometric length, so every mode's gain and time constant show."""
    u, value, t = np.empty(T), level + swing, 0
    while t < T:
        hold = int(rng.geometric(1.0 / mean_hold))
        u[t:t + hold] = value
        value = 2 * level - value
        t += hold
    return u[:, None]


def dataset(case: str, seed: int) -> Data:
    """One simulated recording of the case's plant with its true values."""
    if case == "cstr":
        sim = jmlgdsl.simulate_nonlinear(str(ROOT / "specs/cstr10.jmlg"), seed=seed, modes=CSTR_SCHEDULE)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = jmlgdsl.load(ROOT / "specs/dryer.jmlg")
        rng = np.random.default_rng([seed, 1])
        sim = jmlgdsl.simulate(model, seed=rng, modes=DRYER_SCHEDULE, u=telegraph(1200, rng))
    data = Data(time=None, y=sim.y, u=sim.u, modes=sim.modes, source=f"{case}-{seed}")
    return replace(data, modes=None) if case == "dryer-unlabelled" else data


def one(case: str, seed: int) -> dict:
    """Fit the case's spec to data set `seed`: estimates, standard errors and the time it took."""
    spec, truth = CASES[case]
    start = time.perf_counter()
    result = fit(ROOT / spec, dataset(case, seed))
    values = result.values()
    return {"seed": seed, "seconds": time.perf_counter() - start, "evaluations": result.evaluations,
            "estimate": values, "se": dict(zip(result.names, map(float, result.se))), "notes": result.notes}


def summarise(case: str, runs: list[dict]) -> dict:
    """Per unknown: mean estimate, mean se, spread of the estimates, share within 3 se, coverage."""
    truth = CASES[case][1]
    rows = {}
    for name, true in truth.items():
        est = np.array([r["estimate"][name] for r in runs])
        se = np.array([r["se"][name] for r in runs])
        z = (est - true) / se
        rows[name] = {"truth": true, "mean": float(est.mean()), "sd_of_estimates": float(est.std(ddof=1)),
                      "mean_se": float(np.nanmean(se)), "within_3se": float(np.mean(np.abs(z) <= 3)),
                      "coverage_95": float(np.mean(np.abs(z) <= 1.96))}
    every = np.concatenate([[abs((r["estimate"][n] - t) / r["se"][n]) <= 1.96 for r in runs]
                            for n, t in truth.items()])
    seconds = np.array([r["seconds"] for r in runs])
    return {"case": case, "runs": len(runs), "unknowns": rows, "coverage_all": float(every.mean()),
            "seconds_median": float(np.median(seconds)), "seconds_max": float(seconds.max())}


def table(summary: dict) -> str:
    """The Markdown table docs/fit.md shows."""
    lines = [f"**{summary['case']}**: {summary['runs']} data sets, all intervals together cover the truth in "
             f"{summary['coverage_all']:.1%} of cases; a fit takes {summary['seconds_median']:.1f} s "
             f"(median; longest {summary['seconds_max']:.1f} s)", "",
             "| unknown | truth | mean estimate | sd of estimates | mean se | within 3 se | ±1.96 se covers |",
             "|---|---|---|---|---|---|---|"]
    for name, r in summary["unknowns"].items():
        lines.append(f"| {name} | {r['truth']:g} | {r['mean']:.5g} | {r['sd_of_estimates']:.2g} | {r['mean_se']:.2g} "
                     f"| {r['within_3se']:.0%} | {r['coverage_95']:.0%} |")
    return "\n".join(lines)


def figures(summary: dict) -> dict:
    """The ledger's figures of a case: the table, and per unknown its mean estimate, the share within 3 se
    and the coverage of the 95 % interval; all intervals' coverage."""
    found = {"table": table(summary), "coverage_all": round(summary["coverage_all"], 4)}
    for name, r in summary["unknowns"].items():
        found.update({f"{name}_mean": r["mean"], f"{name}_within_3se": r["within_3se"],
                      f"{name}_coverage_95": r["coverage_95"]})
    return found


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--jobs", type=int, default=1, help="processes working side by side")
    parser.add_argument("--case", action="append", choices=list(CASES), help="repeat for several (default: all)")
    parser.add_argument("--out", default=str(ROOT / "benchmarks/fit/results"))
    ledger.ledger_argument(parser)
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for case in args.case or list(CASES):
        start = time.perf_counter()
        runs = []
        with ProcessPoolExecutor(args.jobs) as pool:
            for run in pool.map(one, [case] * args.runs, range(1, args.runs + 1)):
                runs.append(run)
                print(f"{case} {len(runs)}/{args.runs}: {run['seconds']:.1f} s", flush=True)
        summary = summarise(case, runs)
        (out / f"{case}.json").write_text(json.dumps({"summary": summary, "runs": runs}, indent=1))
        (out / f"{case}.md").write_text(table(summary) + "\n")
        print(table(summary), f"\n({time.perf_counter() - start:.0f} s)\n", flush=True)
        ledger.record(f"fit/coverage/{case}", figures(summary),
                      f"python benchmarks/fit/coverage.py --runs {args.runs} --jobs {args.jobs} --case {case}",
                      timings={"seconds_median": round(summary["seconds_median"], 1),
                               "seconds_max": round(summary["seconds_max"], 1), "jobs": args.jobs},
                      path=args.ledger)


if __name__ == "__main__":
    main()
