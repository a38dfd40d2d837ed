"""What limits SKAB's F1 (docs/realdata.md, "Where it fails"): the strict setting's cross-validated
alarms, as benchmarks/skab/run.py wrote them, taken apart on the leaderboard's protocol (rows 400
to the end, counts pooled over the 34 files); the tables go to RESULTS/strict/limits.md and the
results ledger (skab/limits).

    python benchmarks/skab/limits.py --data DIR [--results DIR]

1. By anomaly kind (the SKAB data README's description of each file): the anomalous rows missed
   and the normal rows alarmed, each as a share of all of them, the missed change points and the
   false-positive change points.
2. The rows F1 counts against us, by where they lie: a missed anomalous row is before the first
   alarm of its labelled episode (the detection delay), after it while the alarm is down (a drop-
   out), or in an episode never alarmed; a false alarm row is the alarm still up after an episode
   ends (overhang) or an alarm raised in normal operation. With F1 had each kind of row been right.
3. The ceiling a causal detector faces: the labels themselves delayed by d rows (a perfect detector
   that needs d rows to see an episode begin and d rows to see it end), scored on the same protocol;
   and how many of the labelled change points lie on an edge of the anomaly labels at all (SKAB
   also marks the ends of the transition phases inside an episode, which only an alarm that falls
   and rises again within the episode can hit).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from jmlgdsl.data import Columns, read_csv
from jmlgdsl.diagnosis.metrics import OutlierCounts, Scores, runs, score

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run import SENSORS, TRAIN, data_folder, files, ledger, results_parser  # noqa: E402

#: Each file's anomaly kind, as the SKAB data README describes the experiments.
KINDS = {"valve1": "valve at the pump's inlet closed", "valve2": "valve at the pump's outlet closed",
         **{f"other_{i}": "fluid leaks and additions" for i in (1, 2, 3, 4)},
         **{f"other_{i}": "rotor imbalance" for i in (5, 6, 7, 8, 9)},
         "other_10": "more water in the circuit", "other_11": "more water in the circuit",
         "other_12": "cavitation", "other_13": "cavitation", "other_14": "hotter water supply"}
#: The delays, in rows (seconds), of the delayed perfect detector.
DELAYS = (0, 5, 10, 20, 30, 45)


def kind(stem: str) -> str:
    return KINDS.get(stem, KINDS.get(stem.split("_")[0]))


def parts(alarm: np.ndarray, anomaly: np.ndarray) -> dict:
    """Row counts of one file: missed anomalous rows before the first alarm of their episode
    (delay), after it (dropout) or in an episode never alarmed (unseen); alarmed normal rows in the
    run of alarm that an episode's end left up (overhang) or elsewhere (normal)."""
    out = dict.fromkeys(("delay", "dropout", "unseen", "overhang", "normal"), 0)
    for start, end in runs(anomaly):
        up = np.flatnonzero(alarm[start:end])
        if not len(up):
            out["unseen"] += end - start
            continue
        out["delay"] += int(up[0])
        out["dropout"] += int((alarm[start + up[0]:end] == 0).sum())
    overhang = np.zeros(len(alarm), bool)
    for start, end in runs(alarm):
        labelled = np.flatnonzero(anomaly[start:end])
        if len(labelled):  # the alarm's rows after the last labelled one it covers
            overhang[start + labelled[-1] + 1:end] = True
    false = (alarm == 1) & (anomaly == 0)
    out["overhang"] = int((false & overhang).sum())
    out["normal"] = int((false & ~overhang).sum())
    return out


def delayed(anomaly: np.ndarray, d: int) -> np.ndarray:
    """The labels as a perfect detector that needs d rows to see each change would alarm."""
    return np.concatenate([np.zeros(d, anomaly.dtype), anomaly])[:len(anomaly)]


def main(argv=None) -> int:
    parser = results_parser(__doc__)
    ledger.ledger_argument(parser)
    args = parser.parse_args(argv)
    data = data_folder(parser, args.data)
    by_kind, total, ours, perfect = {}, dict.fromkeys(("delay", "dropout", "unseen", "overhang", "normal"), 0), [], \
        {d: [] for d in DELAYS}
    on_edges = 0
    for path in files(data):
        stem = f"{path.parent.name}_{path.stem}"
        recording = read_csv(path, Columns(outputs=SENSORS))
        scored = slice(TRAIN, None)
        anomaly, time, cp = recording.anomaly[scored], recording.time[scored], recording.changepoint[scored]
        alarm = np.loadtxt(args.results / "strict" / f"{stem}.csv", delimiter=",", skiprows=1,
                           usecols=1, dtype=int)
        got = score(alarm, anomaly, time, cp)
        edges = runs(anomaly)
        on_edges += int(np.isin(np.flatnonzero(cp), edges).sum())
        ours.append(got)
        found = parts(alarm, anomaly)
        total = {k: total[k] + v for k, v in found.items()}
        entry = by_kind.setdefault(kind(stem), {"files": 0, "scores": [], "parts": dict.fromkeys(found, 0)})
        entry["files"] += 1
        entry["scores"].append(got)
        entry["parts"] = {k: entry["parts"][k] + v for k, v in found.items()}
        for d in DELAYS:
            perfect[d].append(score(delayed(anomaly, d), anomaly, time, cp))
    pooled = Scores.pool(ours)
    counts = pooled.outlier
    assert counts.fn == total["delay"] + total["dropout"] + total["unseen"]
    assert counts.fp == total["overhang"] + total["normal"]
    figures = {"f1": pooled.summary()["f1"]}

    lines = ["| anomaly kind | files | missed anomalous rows | share of all missed | false-alarm rows | "
             "share of all false alarms | F1 | missed CPs | FP change points |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, entry in sorted(by_kind.items(), key=lambda item: -Scores.pool(item[1]["scores"]).outlier.fn):
        s = Scores.pool(entry["scores"])
        lines.append(f"| {name} | {entry['files']} | {s.outlier.fn} of {s.outlier.fn + s.outlier.tp} | "
                     f"{s.outlier.fn / counts.fn:.0%} | {s.outlier.fp} of {s.outlier.fp + s.outlier.tn} | "
                     f"{s.outlier.fp / counts.fp:.0%} | {s.outlier.f1:.2f} | {s.nab.missed} | {s.nab.fp} |")
    figures["kinds_table"] = "\n".join(lines)

    def f1_if(right: dict) -> float:
        """F1 with these rows counted right (missed rows as found, false alarms as quiet)."""
        fixed_fn = sum(v for k, v in right.items() if k in ("delay", "dropout", "unseen"))
        fixed_fp = sum(v for k, v in right.items() if k in ("overhang", "normal"))
        return OutlierCounts(counts.tp + fixed_fn, counts.fp - fixed_fp, counts.tn + fixed_fp, counts.fn - fixed_fn).f1
    words = {"delay": "missed: before the first alarm of the episode (detection delay)",
             "dropout": "missed: the alarm down again within the episode", "unseen": "missed: an episode never alarmed",
             "overhang": "false alarm: still up after the episode's end", "normal": "false alarm: raised in normal operation"}
    lines = ["| rows | count | share of the rows F1 counts against us | F1 had they been right |", "|---|---:|---:|---:|"]
    for key, text in words.items():
        lines.append(f"| {text} | {total[key]} | {total[key] / (counts.fn + counts.fp):.0%} | {f1_if({key: total[key]}):.3f} |")
        figures[f"{key}_rows"] = total[key]
        figures[f"f1_without_{key}"] = round(f1_if({key: total[key]}), 4)
    figures["parts_table"] = "\n".join(lines)

    lines = ["| detection delay, rows (s) | F1 | NAB (standard) | missed CPs | FPs |", "|---:|---:|---:|---:|---:|"]
    for d, found in perfect.items():
        s = Scores.pool(found).summary()
        lines.append(f"| {d} | {s['f1']:.3f} | {s['nab_standard']:.2f} | {s['missed_cp']} | {s['fp']} |")
        figures[f"perfect_delay{d}_f1"] = round(s["f1"], 4)
        figures[f"perfect_delay{d}_nab"] = round(s["nab_standard"], 2)
    figures["perfect_table"] = "\n".join(lines)
    figures["changepoints"], figures["changepoints_on_label_edges"] = pooled.nab.windows, on_edges
    text = "\n\n".join(figures[k] for k in ("kinds_table", "parts_table", "perfect_table")) + "\n"
    (args.results / "strict" / "limits.md").write_text(text)
    print(text)
    ledger.record("skab/limits", figures, "python benchmarks/skab/limits.py --data DIR", path=args.ledger)
    return 0


if __name__ == "__main__":
    sys.exit(main())
