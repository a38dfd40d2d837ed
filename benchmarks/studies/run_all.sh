#!/bin/sh
# Every study of docs/studies.md. The two with published tables run in full (25 runs, the ten
# particle counts); the others at 10 runs and seven particle counts, to fit a shared 2-core machine.
# Figures go to docs/figures/, tables to benchmarks/studies/results/.
set -e
cd "$(dirname "$0")/../.."
python benchmarks/studies/studies.py --runs 25 dryer-seq1 level-tank4
python benchmarks/studies/studies.py --runs 10 --particles 1,4,10,25,100,400,1600 \
    dryer-seq2 dryer-seq3 dryer-seq4 dryer-transitions level-tank5 heat-exchanger heat-exchanger-transitions \
    robot-smooth robot8-noise1 robot8-noise2 robot8-noise4 robot8-prefilter \
    robot8-prefilter-mismatch cstr4 cstr10
