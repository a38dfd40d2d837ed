"""Compile time of the nonlinear plants (BENCHMARKS.md): the 10-mode CSTR must compile in under 3 s.

    python benchmarks/bench_compile.py            # cstr4, cstr10: cold process and warm repeats
    python benchmarks/bench_compile.py --repeats 20

"cold" is a fresh interpreter running `jmlgdsl.load` once (imports of sympy and scipy included), as
`jmlgdsl compile` does; "warm" is the best of the repeats in one process, split into the symbolic
build (sympy Jacobians, lambdify) and the per-mode work (steady states, Jacobians, matrix exponentials).
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

SPECS = Path(__file__).resolve().parent.parent / "specs"
PLANTS = ["cstr4", "cstr10"]


def cold(spec: Path) -> float:
    """Seconds for a fresh interpreter to import jmlgdsl and compile the spec."""
    code = ("import time; t = time.perf_counter(); import jmlgdsl; "
            f"jmlgdsl.load({str(spec)!r}); print(time.perf_counter() - t)")
    return float(subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout)


def warm(spec: Path, repeats: int) -> tuple[int, float, float, float]:
    """The number of modes and the best-of-repeats seconds in one process: (whole compile, symbolic
    build, per-mode linearisation)."""
    from jmlgdsl.compile.lower import compile_file
    from jmlgdsl.compile.ode import linearise, ode_system
    from jmlgdsl.lang.check import check
    from jmlgdsl.lang.parse import parse_file

    modes = compile_file(spec).K  # imports and caches (the grammar) out of the way
    total = build = lower = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        compile_file(spec)
        t1 = time.perf_counter()
        plant, report = check(parse_file(spec))
        t2 = time.perf_counter()
        system = ode_system(plant)
        t3 = time.perf_counter()
        linearise(plant, system, report)
        t4 = time.perf_counter()
        total, build, lower = min(total, t1 - t0), min(build, t3 - t2), min(lower, t4 - t3)
    return modes, total, build, lower


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    print(f"python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} cores")
    print("| plant | modes | cold compile (s) | warm compile (s) | symbolic build (s) | per-mode work (s) |")
    print("|---|---|---|---|---|---|")
    for name in PLANTS:
        spec = SPECS / f"{name}.jmlg"
        modes, total, build, lower = warm(spec, args.repeats)
        print(f"| {name} | {modes} | {cold(spec):.2f} | {total:.3f} | {build:.3f} | {lower:.3f} |")


if __name__ == "__main__":
    main()
