"""Time per step of this checkout against another one, side by side under the same load
(BENCHMARKS.md): the two are run alternately, and the best of all their runs is kept.

    git worktree add /tmp/before 6bb1d1e
    python benchmarks/bench_against.py /tmp/before [--rounds 2 --runs 3]

Each round runs every setting in a fresh process for each checkout (PYTHONPATH pointing at it), on
the same 1,000-step sequences: the dryer through sequence No. 1, the 10-mode CSTR through its modes.
"""

from __future__ import annotations

import argparse
import ast
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SETTINGS = (("pf", 100), ("rbpf", 100), ("la-rbpf", 10), ("la-rbpf", 1000), ("fc-rbpf", 10), ("imm", None))
PROBE = '''
import sys, warnings
import jmlgdsl
from jmlgdsl.simulation.linear import simulate
warnings.simplefilter("ignore")
specs, runs, settings = sys.argv[1], int(sys.argv[2]), eval(sys.argv[3])
dryer, cstr = jmlgdsl.load(specs + "/dryer.jmlg"), jmlgdsl.load(specs + "/cstr10.jmlg")
seq = "1-70:normal,71-238:fan,239-365:grill,366-513:normal,514-705:grill,706-1000:fan"
cstr_seq = ",".join(f"{100 * i + 1}-{100 * (i + 1)}:{cstr.modes[i]}" for i in range(10))
out = {}
for plant, model, sim in (("dryer", dryer, simulate(dryer, 1000, seed=0, modes=seq)),
                          ("cstr10", cstr, simulate(cstr, 1000, seed=0, modes=cstr_seq))):
    for algorithm, n in settings:
        best = min(jmlgdsl.filter(model, sim.y, sim.u, algorithm=algorithm, particles=n, seed=s).seconds
                   for s in range(runs))
        out[plant, algorithm, n] = 1e3 * best / len(sim.y)
print(repr(out))
'''


def probe(checkout: Path, runs: int) -> dict:
    """{(plant, filter, N): best ms per step} of one checkout, in a fresh process."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    done = subprocess.run([sys.executable, "-c", PROBE, str(ROOT / "specs"), str(runs), repr(SETTINGS)],
                          env=env, capture_output=True, text=True, check=True, cwd=checkout)
    return ast.literal_eval(done.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", type=Path, help="the other checkout (a git worktree of an earlier commit)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    before, after = [], []
    for _ in range(args.rounds):
        after.append(probe(ROOT, args.runs))
        before.append(probe(args.before, args.runs))
    print("| plant | filter | N | before | after | speed-up |\n|---|---|---|---|---|---|")
    for key in after[0]:
        b, a = min(r[key] for r in before), min(r[key] for r in after)
        plant, algorithm, n = key
        print(f"| {plant} | {algorithm} | {n or '-'} | {b:.3f} | {a:.3f} | {b / a:.2f} |")


if __name__ == "__main__":
    main()
