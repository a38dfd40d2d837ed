"""Fits on plants nobody tuned them for: a family of random tank trains, fitted with and without their
mode column (docs/fit.md, "A family of plants").

    python benchmarks/fit/family.py                    # 20 plants, one after the other
    python benchmarks/fit/family.py --plants 40 --seed 1

Plant k (its own Generator, from --seed and k) is a train of 2 to 4 tanks with random areas and
flow coefficients, fed by a pump whose flow is a random binary sequence; the first and last levels are
measured. Two of three faults, at random: a leak from a random tank (its coefficient unknown,
Uniform(0, 0.01)), a partly clogged random pipe, a last level sensor that reads high. Two flow
coefficients are unknown (a third where there is no leak), each with a LogNormal prior whose median
is 25 to 50 % off the truth on a random side. 2,000 rows at 5 s hold one episode of each fault.

Each plant is fitted twice with `jmlgdsl.fit`, as a user's fit runs on this machine (its starts side
by side on the cores): to its record with the `mode` column (the labelled fit: exact likelihood) and
without (the unlabelled fit). A plant is identifiable when its labelled
fit lands within 3 standard errors of every true value without a warning; the figure is the share of
those whose unlabelled fit does too, and every other unlabelled fit must say so with a warning.
The figures go to the results ledger as `fit/family`, with each plant's row in a table.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

import jmlgdsl
from jmlgdsl.compile import compile_text
from jmlgdsl.data import Data
from jmlgdsl.lang.parse import parse_text

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))
from ledger import ledger_argument, record  # noqa: E402

ROWS, EPISODE, FLOW = 2000, 300, 0.012


def plant(k: int, seed: int) -> dict:
    """Random tank train k: its spec with the true values, the spec with priors for the unknowns, the
    true values of the unknowns, the fault schedule and the pump flow."""
    rng = np.random.default_rng([seed, k])
    n = int(rng.integers(2, 5))
    area = rng.uniform(0.5, 1.5, n)
    flow = rng.uniform(0.011, 0.025, n)  # k_i: the pipe out of tank i (the last: the outlet)
    faults = [str(f) for f in sorted(rng.choice(["leak", "clog", "sensor"], 2, replace=False),
                                     key=["leak", "clog", "sensor"].index)]
    leaky, clogged = int(rng.integers(1, n + 1)), int(rng.integers(1, n + 1))
    unknown = list(rng.choice(n, 2 if "leak" in faults or n == 2 else 3, replace=False) + 1)
    truth = {f"k{i}": float(flow[i - 1]) for i in sorted(unknown)}
    if "leak" in faults:
        truth["kl"] = float(rng.uniform(0.002, 0.006))
    priors = {}
    for name, value in truth.items():
        if name == "kl":
            priors[name] = "Uniform(0, 0.01)"
        else:
            median = value * (1 + rng.choice([-1, 1]) * rng.uniform(0.25, 0.5))
            priors[name] = f"LogNormal(log({median:.6g}), 0.5)"
    levels = (FLOW / flow) ** 2
    lines = [f"plant train{k}", "sample 5 s", f"input q [m3/s] = {FLOW}",
             "state " + ", ".join(f"h{i} [m] = {levels[i - 1]:.4g}" for i in range(1, n + 1)),
             f"output l1 [m] = h1, l{n} [m] = h{n}" + (" + bias" if "sensor" in faults else "") if n > 1 else "",
             "param " + ", ".join(f"area{i} = {area[i - 1]:.4g}" for i in range(1, n + 1))]
    for i in range(1, n + 1):
        lines.append(f"param k{i} = {float(flow[i - 1])!r}" if f"k{i}" not in truth else f"param k{i} = K{i}")
    if "leak" in faults:
        lines.append("param kl = KL")
    lines.append("param kleak = 0, open = 1, bias = 0")
    lines.append("ode")
    for i in range(1, n + 1):
        inflow = "q" if i == 1 else f"{'open * ' if clogged == i - 1 else ''}k{i - 1} * sqrt(h{i - 1})"
        out = f"{'open * ' if clogged == i else ''}k{i} * sqrt(h{i})" + (f" - kleak * sqrt(h{i})" if leaky == i else "")
        lines.append(f"  der(h{i}) = ({inflow} - {out}) / area{i}")
    lines += ["noise process 0.002, measurement 0.005", "modes", "  normal"]
    schedule_modes = ["normal"]
    if "leak" in faults:
        lines.append(f'  leak "a leak from tank {leaky}": kleak = kl')
        schedule_modes.append("leak")
    if "clog" in faults:
        lines.append(f'  clog "pipe {clogged} partly clogged": open = {rng.uniform(0.5, 0.8):.3g}')
        schedule_modes.append("clog")
    if "sensor" in faults:
        lines.append(f'  sensor "level {n} reads high": bias = {rng.uniform(0.03, 0.06):.3g}')
        schedule_modes.append("sensor")
    lines.append("transitions stay 0.995, otherwise uniform")
    text = "\n".join(line for line in lines if line) + "\n"
    true_text, unknown_text = text, text
    for name, value in truth.items():
        token = name.upper()
        true_text = true_text.replace(f"= {token}\n", f"= {value!r}\n")
        unknown_text = unknown_text.replace(f"{name} = {token}\n", f"{name} ~ {priors[name]}\n")
    starts = sorted(rng.choice(np.arange(2, ROWS // EPISODE - 1), len(schedule_modes) - 1, replace=False))
    modes = ["normal"] * ROWS
    for fault, start in zip(schedule_modes[1:], starts):
        modes[start * EPISODE:start * EPISODE + EPISODE] = [fault] * EPISODE
    q = FLOW + 0.002 * np.repeat(rng.choice([-1, 1], ROWS // 20 + 1), 20)[:ROWS, None]
    return {"k": k, "tanks": n, "faults": faults, "truth": truth, "true_text": true_text,
            "unknown_text": unknown_text, "modes": modes, "q": q}


def fit_plant(k: int, seed: int) -> dict:
    """Plant k simulated, then fitted with and without its mode column: the estimates, standard errors,
    warnings and times of both fits (BLAS on one thread, as `jmlgdsl fit` runs it)."""
    with threadpool_limits(1):
        return _fit_plant(k, seed)


def _fit_plant(k: int, seed: int) -> dict:
    p = plant(k, seed)
    model = compile_text(p["true_text"])
    sim = jmlgdsl.simulate(model, seed=np.random.default_rng([seed, k, 1]), modes=p["modes"], u=p["q"])
    data = Data(time=None, y=sim.y, u=sim.u, modes=sim.modes, source=f"train{k}")
    spec = parse_text(p["unknown_text"])
    out = {"k": k, "tanks": p["tanks"], "faults": p["faults"], "truth": p["truth"]}
    for how, d in (("labelled", data), ("unlabelled", replace(data, modes=None))):
        start = time.perf_counter()
        try:
            result = jmlgdsl.fit(spec, d)
        except Exception as exc:  # a plant whose fit fails outright counts as flagged, with its error
            out[how] = {"error": f"{type(exc).__name__}: {exc}", "seconds": time.perf_counter() - start}
            continue
        values = result.values()
        within = all(math.isfinite(se) and abs(values[name] - true) <= 3 * se
                     for (name, true), se in zip(p["truth"].items(), result.se))
        out[how] = {"estimate": values, "se": dict(zip(result.names, map(float, result.se))),
                    "within": within, "warnings": result.warnings, "seconds": result.seconds,
                    "evaluations": result.evaluations}
    return out


def summary(results: list[dict]) -> dict:
    """The family's figures: identifiable plants, the unlabelled fits within 3 se among them, the
    misses the fit flagged and those it did not, the median times."""
    def ok(r, how):
        return "error" not in r[how] and r[how]["within"] and not r[how]["warnings"]

    identifiable = [r for r in results if ok(r, "labelled")]
    within = [r for r in identifiable if "error" not in r["unlabelled"] and r["unlabelled"]["within"]]
    missed = [r for r in identifiable if r not in within]
    flagged = [r for r in missed if "error" in r["unlabelled"] or r["unlabelled"]["warnings"]]
    return {"plants": len(results), "identifiable": len(identifiable), "unlabelled_within": len(within),
            "share_within": round(len(within) / max(len(identifiable), 1), 4),
            "missed_flagged": len(flagged), "missed_unflagged": len(missed) - len(flagged),
            "median_unlabelled_seconds": round(float(np.median([r["unlabelled"]["seconds"] for r in results])), 1),
            "median_labelled_seconds": round(float(np.median([r["labelled"]["seconds"] for r in results])), 1)}


def table(results: list[dict]) -> str:
    """A row per plant: its shape, each fit's verdict and time."""
    def verdict(fit):
        if "error" in fit:
            return f"failed ({fit['error'][:60]})"
        return ("within 3 se" if fit["within"] else "off") + (", warned" if fit["warnings"] else "")

    lines = ["| plant | tanks | faults | unknowns | labelled fit | unlabelled fit | unlabelled s |",
             "|---|---:|---|---|---|---|---:|"]
    for r in results:
        lines.append(f"| train{r['k']} | {r['tanks']} | {', '.join(r['faults'])} | {', '.join(r['truth'])} | "
                     f"{verdict(r['labelled'])} | {verdict(r['unlabelled'])} | {r['unlabelled']['seconds']:.0f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--plants", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1,
                        help="plants fitted at a time (1: each fit has the cores to itself, as a user's has)")
    ledger_argument(parser)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        results = []
        for r in pool.map(fit_plant, range(args.plants), [args.seed] * args.plants):
            results.append(r)
            print(f"train{r['k']}: {r['tanks']} tanks, {', '.join(r['faults'])}; labelled "
                  f"{'ok' if r['labelled'].get('within') else 'off'}, unlabelled "
                  f"{'ok' if r['unlabelled'].get('within') else 'off'} in {r['unlabelled']['seconds']:.0f} s",
                  file=sys.stderr, flush=True)
    figures = summary(results)
    figures["table"] = table(results)
    print(figures["table"])
    print({k: v for k, v in figures.items() if k != "table"})
    record("fit/family", figures, "python benchmarks/fit/family.py " + " ".join(sys.argv[1:] if argv is None else argv),
           timings={"seconds": round(time.perf_counter() - start, 1)}, path=args.ledger)
    return 0


if __name__ == "__main__":
    sys.exit(main())
