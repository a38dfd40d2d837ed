"""Learning at scale (issue 11): a bank of 20 modes over 50 sensors must learn in under a minute.

    python benchmarks/bench_learn.py                      # 20 modes, 50 sensors, 1 input, 1000 samples
    python benchmarks/bench_learn.py --max-iter 10        # EM capped at 10 iterations a mode
    python benchmarks/bench_learn.py --modes 4 --sensors 8 --samples 500

Each mode is a first-order multi-sensor plant (a random stable coupling of the sensors, a
different input gain and level per mode, correlated process noise, sensors in units a million
apart) simulated under a PRBS; the bank is learned at order 1 with `bank.learn_modes` (least
squares, then EM in the shared lagged basis with standardised sensors), assembled, written as a
spec and loaded back, and the IMM filter is timed on a switching sequence.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

# Learning multiplies many small matrices; OpenBLAS's thread pool only adds contention on them (a
# 1000 x 52 QR took 0.7 s with it on the shared 2-core machine, milliseconds without). Set before
# numpy loads; an explicit setting in the environment wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import jmlgdsl  # noqa: E402
from jmlgdsl import Model  # noqa: E402
from jmlgdsl.infer import filter as run_filter  # noqa: E402
from jmlgdsl.learn import bank  # noqa: E402
from jmlgdsl.learn.prbs import prbs  # noqa: E402
from jmlgdsl.learn.writer import write_spec  # noqa: E402


def plant(K: int, ny: int, rng: np.random.Generator) -> Model:
    """K first-order modes over ny sensors with one input; sensor i is in units of 10^(6 i / ny)."""
    units = 10.0 ** (6 * np.arange(ny) / ny)
    A, F, f = [], [], []
    for _ in range(K):
        M = rng.standard_normal((ny, ny)) / np.sqrt(ny)
        M = 0.8 * M / np.abs(np.linalg.eigvals(M)).max()
        A.append(units[:, None] * M / units)
        F.append(units[:, None] * rng.uniform(0.2, 1.0, (ny, 1)))
        f.append(units * rng.uniform(-1, 1, ny))
    L = np.linalg.cholesky(0.5 * np.eye(ny) + 0.5 / ny)
    return Model.from_arrays(A=np.array(A), F=np.array(F), f=np.array(f), C=np.eye(ny),
                             B=0.05 * units[:, None] * L, D=0.02 * np.diag(units), P=bank.default_transitions(K, 0.995),
                             p0=np.full(K, 1.0 / K), mu0=np.zeros(ny), Sigma0=np.diag(units ** 2), input_defaults=[0.0])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--modes", type=int, default=20)
    p.add_argument("--sensors", type=int, default=50)
    p.add_argument("--samples", type=int, default=1000)
    p.add_argument("--max-iter", type=int, default=100, help="EM iterations per mode (default 100, as learn's)")
    p.add_argument("--steps", type=int, default=2000, help="length of the switching sequence for IMM")
    args = p.parse_args(argv)
    rng = np.random.default_rng(2024)
    model = plant(args.modes, args.sensors, rng)
    u = prbs(9, clock=3, samples=args.samples)[:, None]
    exps = {name: bank.Experiment(jmlgdsl.simulate(model, modes=[name] * len(u), u=u, seed=k).y, u, name)
            for k, name in enumerate(model.modes)}

    start = time.perf_counter()
    learned = bank.learn_modes(exps, order=(1, 1, 0), max_iter=args.max_iter)
    learn_s = time.perf_counter() - start
    fitted = bank.assemble(learned, P=model.P, p0=model.p0, operating_input=[0.0], name="bench",
                           inputs=model.inputs, outputs=model.outputs, input_defaults=model.input_defaults)
    with tempfile.TemporaryDirectory() as folder:
        spec = Path(folder) / "bench.jmlg"
        spec.write_text(write_spec(fitted))
        start = time.perf_counter()
        loaded = jmlgdsl.load(spec)
        load_s = time.perf_counter() - start

    seq = rng.integers(0, args.modes, args.steps // 100).repeat(100)
    sim = jmlgdsl.simulate(model, modes=seq, u=prbs(9, clock=3, samples=len(seq))[:, None], seed=99)
    errors = {}
    for name, bank_model in (("true", model), ("learned", loaded)):
        result = run_filter(bank_model, sim.y, sim.u, algorithm="imm")
        errors[name] = result.diagnosis_error(sim.modes), len(seq) / result.seconds
    iterations = [lm.em.iterations for lm in learned]
    print(f"{platform.processor() or platform.machine()}, numpy {np.__version__}")
    print(f"{args.modes} modes x {args.sensors} sensors x {args.samples} samples: learned in {learn_s:.1f} s "
          f"(EM iterations {min(iterations)}-{max(iterations)}, {sum(lm.em.converged for lm in learned)} converged); "
          f"spec loads in {load_s:.2f} s")
    for name, (error, rate) in errors.items():
        print(f"IMM on {len(seq)} switching steps, {name} bank: diagnosis error {error:.2f} %, {rate:.0f} steps/s")


if __name__ == "__main__":
    main()
