"""Check jmlgdsl.diagnosis.metrics against the SKAB leaderboard's own figures with trivial detectors.

Reads every labelled SKAB file (valve1/, valve2/, other/; rows 400 on are scored), scores the
all-zero, all-one and perfect-label detectors, and one that alarms on each true change point's row
only, pooled over files, and prints them beside the values the leaderboard's scorer is known to give
(shared/reference/skab-scoring.md) and its Null detector row (the SKAB README).

    python benchmarks/skab/scoring_check.py --data DIR
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from jmlgdsl.diagnosis.metrics import Scores, score

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run import add_data_option, data_folder, files as skab_files  # noqa: E402

FIRST_SCORED = 400  # rows 0-399 are the training stretch of normal operation

# Known values, (F1, FAR %, MAR %) and (NAB standard, LowFP, LowFN, missed CPs, FPs), None where none is
# known: the scorer's check values in skab-scoring.md, and the README leaderboard's Null detector row.
EXPECTED = {
    "all zero (null)": ((0.0, 0.0, 100.0), (0.0, 0.0, 0.0, 127, 0)),
    "all one": ((None, None, None), (-1.47, -2.94, -0.98, 127, 34)),
    "labels (perfect)": ((1.0, 0.0, 0.0), (54.73, 54.03, 56.96, 49, 1)),
    "change-point rows": ((None, None, None), (95.28, 95.28, 95.28, 6, 0)),
}


def read(path: Path):
    """The scored rows of one SKAB file: time stamps (datetime64), anomaly and changepoint labels."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f, delimiter=";"))[FIRST_SCORED:]
    time = np.array([r["datetime"] for r in rows], dtype="datetime64[s]")
    return time, np.array([float(r["anomaly"]) for r in rows]), np.array([float(r["changepoint"]) for r in rows])


def detectors(anomaly, changepoint):
    """The trivial detectors by name, as 0/1 alarm series."""
    return {"all zero (null)": np.zeros_like(anomaly), "all one": np.ones_like(anomaly),
            "labels (perfect)": anomaly, "change-point rows": changepoint}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_data_option(parser)
    args = parser.parse_args(argv)
    data = data_folder(parser, args.data)
    files = skab_files(data)
    per_detector = {name: [] for name in EXPECTED}
    for path in files:
        time, anomaly, changepoint = read(path)
        for name, alarm in detectors(anomaly, changepoint).items():
            per_detector[name].append(score(alarm, anomaly, time, changepoint))
    print(f"{len(files)} files from {data}, rows {FIRST_SCORED} on; ours / known (our unrounded row counts at the end)")
    agree = True
    for name, scores in per_detector.items():
        pooled = Scores.pool(scores)
        s = pooled.summary()
        ours = (round(s["f1"], 2), round(s["far"], 2), round(s["mar"], 2)), \
            (round(s["nab_standard"], 2), round(s["nab_lowfp"], 2), round(s["nab_lowfn"], 2), s["missed_cp"], s["fp"])
        want = EXPECTED[name]
        same = all(w is None or o == w for o_part, w_part in zip(ours, want) for o, w in zip(o_part, w_part))
        agree &= same
        print(f"{name:18} F1 {ours[0][0]} FAR {ours[0][1]} MAR {ours[0][2]} | NAB {ours[1][0]} / {ours[1][1]} / "
              f"{ours[1][2]}, missed {ours[1][3]}, FP {ours[1][4]}   known {want}   "
              f"{'agrees' if same else 'DIFFERS'}   counts {pooled.outlier}")
    print("every known figure reproduced" if agree else "some known figures are NOT reproduced")
    return 0 if agree else 1


if __name__ == "__main__":
    sys.exit(main())
