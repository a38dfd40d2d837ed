"""SKAB against the smoothing lag (docs/realdata.md, docs/studies.md): the strict setting's banks
with the setting cross-validation chose for most files, their alarms from the posterior smoothed
with a lag of L rows, counted L rows late (where they are known), pooled over the 34 files.

    python benchmarks/skab/lag.py --data DIR [--results DIR]

Needs the specs benchmarks/skab/run.py wrote (RESULTS/strict/*.jmlg, with the a priori noise scale
3 and stay 0.99, changed here to the chosen 2 and 0.999; threshold 0.5, persistence 3).
"""

from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

import jmlgdsl
from jmlgdsl.diagnosis.alarms import AlarmRule
from jmlgdsl.data import Columns, read_csv
from jmlgdsl.diagnosis.metrics import Scores, score

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run import SENSORS, TRAIN, data_folder, files, results_parser  # noqa: E402

LAGS = (0, 2, 5, 10, 20)


def main(argv=None) -> int:
    parser = results_parser(__doc__)
    args = parser.parse_args(argv)
    data = data_folder(parser, args.data)
    rule = AlarmRule(("normal",), 0.5, 3)
    pooled = {lag: [] for lag in LAGS}
    for path in files(data):
        stem = f"{path.parent.name}_{path.stem}"
        text = (args.results / "strict" / f"{stem}.jmlg").read_text()
        text = text.replace("noise scale 3 }", "noise scale 2 }").replace("transitions stay 0.99,", "transitions stay 0.999,")
        with tempfile.NamedTemporaryFile("w", suffix=".jmlg", delete=False) as spec:
            spec.write(text)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = jmlgdsl.load(spec.name)
        Path(spec.name).unlink()
        recording = read_csv(path, Columns(outputs=SENSORS))
        scored = slice(TRAIN, None)
        for lag in LAGS:
            posterior = jmlgdsl.smooth(model, recording.y, lag=lag).mode_posterior
            alarm = rule.alarms(posterior, model.modes)
            alarm = np.concatenate([np.zeros(lag, dtype=alarm.dtype), alarm])[:len(alarm)]  # known lag rows late
            pooled[lag].append(score(alarm[scored], recording.anomaly[scored], recording.time[scored],
                                     recording.changepoint[scored]))
        print(stem, file=sys.stderr, flush=True)
    lines = ["| lag (rows) | F1 | FAR % | MAR % | false alarms per hour | mean detection delay, s | NAB (standard) |",
             "|---|---|---|---|---|---|---|"]
    for lag, found in pooled.items():
        s = Scores.pool(found).summary()
        lines.append(f"| {lag} | {s['f1']:.3f} | {s['far']:.2f} | {s['mar']:.2f} | {s['false_alarms_per_hour']:.1f} | "
                     f"{s['mean_delay']:.1f} | {s['nab_standard']:.2f} |")
    table = "\n".join(lines) + "\n"
    (args.results / "strict" / "lag.md").write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
