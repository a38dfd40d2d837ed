"""Diagnosis error and time per step of every filter on the published plants (BENCHMARKS.md).

    python benchmarks/bench_filters.py              # everything (several minutes on 2 cores)
    python benchmarks/bench_filters.py --seeds 5    # fewer runs per setting
    python benchmarks/bench_filters.py --only speed
    python benchmarks/bench_filters.py --only example --seeds 25    # the issue's error targets

Each setting is run on `--seeds` independent data sets (simulated with seed s) and filter seeds;
errors are the mean (SD) over those runs; times are wall-clock time per step of the filtering alone
(no I/O): the mean over the runs in the accuracy tables, the median in the speed table (the median
is less sensitive to other work on a shared machine). Tables are printed as Markdown.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl import Model
from jmlgdsl.simulation.linear import simulate

ROOT = Path(__file__).resolve().parent.parent
SPECS = ROOT / "specs"
sys.path.insert(0, str(ROOT / "benchmarks" / "studies"))
from studies import DRYER  # noqa: E402  (the published sequences, written once)
sys.path.insert(0, str(ROOT / "benchmarks"))
import ledger  # noqa: E402  (benchmarks/ledger.py, the results ledger)

DRYER_SEQ1 = DRYER["seq1"]
SETTINGS = [("pf", 50), ("pf", 200), ("pf", 800), ("rbpf", 25), ("rbpf", 100), ("rbpf", 400),
            ("la-rbpf", 4), ("la-rbpf", 10), ("la-rbpf", 25), ("la-rbpf", 100),
            ("fc-rbpf", 1), ("fc-rbpf", 2), ("fc-rbpf", 4), ("fc-rbpf", 10), ("imm", None)]
TARGETS = [("la-rbpf", 10, 4.0), ("fc-rbpf", 4, 1.6), ("rbpf", 100, 5.0), ("pf", 200, 4.0), ("imm", None, None)]
PLANTS = ["dryer", "level_tank4", "level_tank5", "heat_exchanger", "robot_smooth", "robot8"]


def cstr10() -> tuple[Model, str]:
    """The 10-mode CSTR from specs/cstr10.jmlg, or a stand-in of the same size and kind until it exists:
    ten stable 3x3 perturbations of the published normal-mode A, C = I, process noise 0.01,
    measurement noise 0.06."""
    spec = SPECS / "cstr10.jmlg"
    if spec.exists():
        return jmlgdsl.load(spec), "specs/cstr10.jmlg"
    rng = np.random.default_rng(0)
    normal = np.array([[0.9752, -0.0002149, -3.55e-7], [0.2376, 0.9943, 0.003256], [0.001767, 0.01465, 0.9596]])
    K = 10
    A = np.empty((K, 3, 3))
    for k in range(K):
        M = normal + 0.003 * rng.normal(size=(3, 3))
        A[k] = M * min(1.0, 0.99 / np.abs(np.linalg.eigvals(M)).max())
    F = np.array([[0.1299], [-0.1635], [2.056]]) * (1 + 0.05 * rng.normal(size=(K, 3, 1)))
    P = np.full((K, K), 0.002 / (K - 1)) + np.eye(K) * (0.998 - 0.002 / (K - 1))
    p0 = np.full(K, 0.003 / (K - 1))
    p0[0] = 0.997
    steady = np.linalg.solve(np.eye(3) - A, F)[..., 0]
    model = Model.from_arrays(A=A, B=0.01 * np.eye(3), C=np.eye(3), D=0.06 * np.eye(3), F=F, P=P, p0=p0,
                              mu0=steady, Sigma0=0.0, input_defaults=[1.0], name="cstr10-standin")
    return model, "random stand-in (specs/cstr10.jmlg absent)"


def run(model, sim, algorithm, particles, seed):
    """(diagnosis error %, ms per step) of one filter run."""
    res = jmlgdsl.filter(model, sim.y, sim.u, algorithm=algorithm, particles=particles, seed=seed)
    return res.diagnosis_error(sim.modes), 1e3 * res.seconds / len(sim.y)


def accuracy_table(name, model, sims, settings):
    """Print Markdown rows: filter, N, error mean (SD), ms/step, and error x time (lower is better)."""
    print(f"\n### {name}\n\n| filter | N | error % mean (SD) | ms / step | error x ms |\n|---|---|---|---|---|")
    for algorithm, n in settings:
        out = np.array([run(model, sim, algorithm, n, seed) for seed, sim in enumerate(sims)])
        err, ms = out[:, 0], out[:, 1].mean()
        print(f"| {algorithm} | {n or '-'} | {err.mean():.2f} ({err.std():.2f}) | {ms:.3f} | {err.mean() * ms:.3f} |",
              flush=True)


def plant_sims(name, seeds):
    """A published plant's spec and `seeds` simulated 1,000-step runs (the dryer through sequence No. 1)."""
    model = jmlgdsl.load(SPECS / f"{name}.jmlg")
    if name == "dryer":
        return model, [simulate(model, 1000, seed=s, modes=DRYER_SEQ1) for s in range(seeds)]
    return model, [simulate(model, 1000, seed=s) for s in range(seeds)]


def speed_table(seeds):
    """Print the time per step against N on the dryer (K = 4, nx = ny = 1) and the 10-mode CSTR (nx = ny = 3)."""
    dryer, sims = plant_sims("dryer", 1)
    cstr, source = cstr10()
    schedule = ",".join(f"{100 * i + 1}-{100 * (i + 1)}:{cstr.modes[i]}" for i in range(10))
    csims = [simulate(cstr, 1000, seed=s, modes=schedule) for s in range(seeds)]
    print(f"\n### Time per step (CSTR: {source})\n\n| plant | filter | N | ms / step | error % |\n|---|---|---|---|---|")
    for plant, model, data, grid in (("dryer", dryer, sims, (10, 100, 1000)), ("cstr10", cstr, csims, (10, 100, 1000))):
        for algorithm in ("pf", "rbpf", "la-rbpf", "fc-rbpf", "imm"):
            for n in (grid if algorithm != "imm" else (None,)):
                out = np.array([run(model, sim, algorithm, n, seed) for seed, sim in enumerate(data)])
                print(f"| {plant} | {algorithm} | {n or '-'} | {np.median(out[:, 1]):.3f} | {out[:, 0].mean():.2f} |",
                      flush=True)


def example_table(seeds, ledger_path):
    """The diagnosis error on the bundled examples/dryer_seq1.csv over filter seeds, against the targets,
    and the README's run of it, printed and recorded in the ledger (dryer/seq1)."""
    from jmlgdsl.data import read_csv

    model = jmlgdsl.load(SPECS / "dryer.jmlg")
    data = read_csv(ROOT / "examples" / "dryer_seq1.csv", model)
    lines = ["| filter | N | error % mean (SD) | target |", "|---|---|---|---|"]
    figures, tolerance = {}, {}
    for algorithm, n, target in TARGETS:
        err = np.array([jmlgdsl.filter(model, data.y, data.u, algorithm=algorithm, particles=n, seed=s)
                        .diagnosis_error(data.modes) for s in range(seeds)])
        key = f"{algorithm}_{n or 0}".replace("-", "_")
        figures[f"{key}_mean"], figures[f"{key}_sd"] = round(err.mean(), 3), round(err.std(), 3)
        # Seeds reproduce a run bit for bit on one machine; on another BLAS kernel a particle filter's
        # weights can round differently, a resampling step then draws other particles, and its runs
        # are new draws: their mean may move by a few standard errors (3 sqrt(2) sd / sqrt(seeds)).
        if algorithm != "imm":
            tolerance[f"{key}_mean"] = round(3 * np.sqrt(2) * max(err.std(), 0.1) / np.sqrt(seeds), 3)
            tolerance[f"{key}_sd"] = round(max(err.std(), 0.1), 3)
        lines.append(f"| {algorithm} | {n or '-'} | {err.mean():.2f} ({err.std():.2f}) | "
                     f"{f'<= {target}' if target else '-'} |")
    figures["table"] = "\n".join(lines)
    print(f"\n### examples/dryer_seq1.csv, {seeds} filter seeds\n\n{figures['table']}")
    command = ["jmlgdsl", "run", "specs/dryer.jmlg", "examples/dryer_seq1.csv"]  # the installed console script
    script = shutil.which("jmlgdsl", path=str(Path(sys.executable).parent)) or shutil.which("jmlgdsl")
    shown = subprocess.run([script, *command[1:]], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    figures["transcript"] = f"$ {' '.join(command)}\n{shown}"
    for name, pattern in (("diagnosis_error", r"diagnosis error: ([\d.]+) %"), ("f1", r"rows: F1 ([\d.]+)"),
                          ("nab_standard", r"NAB .*: standard ([\d.]+)"), ("loglik", r"log-likelihood: (-?[\d.]+)")):
        figures[f"run_{name}"] = float(re.search(pattern, shown)[1])
    ledger.record("dryer/seq1", figures, f"python benchmarks/bench_filters.py --only example --seeds {seeds}",
                  tolerance=tolerance, path=ledger_path)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10, help="runs per setting (data and filter seeds)")
    parser.add_argument("--only", choices=["speed", "example", "accuracy"], help="one part only")
    parser.add_argument("--plants", nargs="*", default=PLANTS, help="published plants for the accuracy tables")
    ledger.ledger_argument(parser)
    args = parser.parse_args()
    print(f"machine: {ledger.machine()}; {time.strftime('%Y-%m-%d')}")
    if args.only in (None, "speed"):
        speed_table(max(1, min(args.seeds, 3)))
    if args.only in (None, "example"):
        example_table(args.seeds, args.ledger)
    if args.only in (None, "accuracy"):
        for name in args.plants:
            model, sims = plant_sims(name, args.seeds)
            accuracy_table(f"{name} ({'sequence No. 1' if name == 'dryer' else 'modes from the chain'}, "
                           f"{args.seeds} runs of 1,000 steps)", model, sims, SETTINGS)


if __name__ == "__main__":
    main()
