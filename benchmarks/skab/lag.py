"""SKAB against the smoothing lag (docs/realdata.md, docs/studies.md): the strict setting's banks
with the setting cross-validation chose for most files, their alarms from the posterior smoothed
with a lag of L rows, counted L rows late (where they are known), pooled over the 34 files; the
table goes to RESULTS/strict/lag.md and the results ledger (skab/lag).

    python benchmarks/skab/lag.py --data DIR [--results DIR]

Needs what benchmarks/skab/run.py wrote: the specs (RESULTS/strict/*.jmlg, with the a priori noise
scale 3 and stay 0.99, changed here to the chosen ones) and the choices (RESULTS/strict/summary.json).
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
from run import SENSORS, TRAIN, chosen, data_folder, files, ledger, results_parser  # noqa: E402

LAGS = (0, 2, 5, 10, 20)


def main(argv=None) -> int:
    parser = results_parser(__doc__)
    ledger.ledger_argument(parser)
    args = parser.parse_args(argv)
    data = data_folder(parser, args.data)
    scale, stay, threshold, persistence = chosen(args.results)
    rule = AlarmRule(("normal",), threshold, persistence)
    pooled = {lag: [] for lag in LAGS}
    for path in files(data):
        stem = f"{path.parent.name}_{path.stem}"
        text = (args.results / "strict" / f"{stem}.jmlg").read_text()
        text = text.replace("noise scale 3 }", f"noise scale {scale:g} }}").replace("transitions stay 0.99,",
                                                                                  f"transitions stay {stay:g},")
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
    figures = {}
    for lag, found in pooled.items():
        s = Scores.pool(found).summary()
        figures.update({f"lag{lag}_{k}": s[k] for k in ("f1", "false_alarms_per_hour", "mean_delay", "nab_standard")})
        lines.append(f"| {lag} | {s['f1']:.3f} | {s['far']:.2f} | {s['mar']:.2f} | {s['false_alarms_per_hour']:.1f} | "
                     f"{s['mean_delay']:.1f} | {s['nab_standard']:.2f} |")
    table = "\n".join(lines) + "\n"
    (args.results / "strict" / "lag.md").write_text(table)
    print(table)
    figures["setting"] = (f"noise scale {scale:g}, stay {stay:g}, threshold {threshold:g}, persistence {persistence}")
    figures["table"] = table
    ledger.record("skab/lag", figures, "python benchmarks/skab/lag.py --data DIR", path=args.ledger)
    return 0


if __name__ == "__main__":
    sys.exit(main())
