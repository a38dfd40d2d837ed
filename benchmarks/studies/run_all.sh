#!/bin/sh
# Every study of docs/studies.md at 25 runs per point (about 35 minutes on 2 quiet cores).
# Figures go to docs/figures/, tables and every run to benchmarks/studies/results/.
set -e
cd "$(dirname "$0")/../.."
python benchmarks/studies/studies.py --runs 25 "$@"
