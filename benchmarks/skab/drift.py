"""SKAB with a healthy "drift" mode (docs/realdata.md, "Where it fails"): does a random-walk bias on the
two temperatures, counted as healthy, take the slow normal drifts off the false alarms?

    python benchmarks/skab/drift.py --data DIR [--results DIR]

Needs the specs benchmarks/skab/run.py wrote (RESULTS/strict/*.jmlg). Each file's learned `normal`
mode becomes a bank of `normal`, `drift` (the normal dynamics plus a bias on the chosen sensors that
walks with the given sd a step, held at zero in the other modes) and `anomaly` (every noise sd times
the chosen scale), with the stay, noise scale, threshold and persistence that cross-validation chose for the most files
(RESULTS/strict/summary.json); rows 400 on are scored and pooled, and the table goes to the results
ledger (skab/drift). Without a drift mode this is the lag-0 row of lag.py.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
from scipy.linalg import block_diag

import jmlgdsl
from jmlgdsl import Model
from jmlgdsl.diagnosis.alarms import AlarmRule
from jmlgdsl.data import Columns, read_csv
from jmlgdsl.learn.bank import default_transitions
from jmlgdsl.diagnosis.metrics import Scores, score

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run import SENSORS, TRAIN, chosen, data_folder, files, ledger, results_parser  # noqa: E402

TEMPERATURES = (SENSORS.index("Temperature"), SENSORS.index("Thermocouple"))
# (bias sd a step, sensors): none, then the temperatures at four walk speeds, then every sensor
SETTINGS = [(0.0, ())] + [(sd, TEMPERATURES) for sd in (0.003, 0.01, 0.03, 0.1)] + [(0.01, tuple(range(8)))]


def bank(learned: Model, sd: float, sensors, scale: float, stay: float) -> Model:
    """normal, drift (a bias walking with sd on `sensors`; left out when sd is 0) and anomaly (noise x scale),
    staying in each mode with probability `stay`."""
    A, B, C, D, f = learned.A[0], learned.B[0], learned.C[0], learned.D[0], learned.f[0]
    nb = len(sensors) if sd else 0
    E = np.zeros((learned.ny, nb))
    E[list(sensors), np.arange(nb)] = 1.0

    def mode(walk, noise):
        return (block_diag(A, walk * np.eye(nb)), block_diag(noise * B, walk * sd * np.eye(nb)),
                np.hstack([C, E]), noise * D, np.r_[f, np.zeros(nb)])

    modes = [mode(0.0, 1.0)] + ([mode(1.0, 1.0)] if nb else []) + [mode(0.0, scale)]
    names = ("normal",) + (("drift",) if nb else ()) + ("anomaly",)
    K = len(modes)
    A_, B_, C_, D_, f_ = (np.stack(parts) for parts in zip(*modes))
    return Model.from_arrays(A=A_, B=B_, C=C_, D=D_, f=f_, P=default_transitions(K, stay),
                             p0=np.r_[0.99, np.full(K - 1, 0.01 / (K - 1))], mu0=np.r_[learned.mu0[0], np.zeros(nb)],
                             Sigma0=block_diag(learned.Sigma0, np.zeros((nb, nb))), modes=names,
                             outputs=learned.outputs, outlier_gate=learned.outlier_gate)


def main(argv=None) -> int:
    parser = results_parser(__doc__)
    ledger.ledger_argument(parser)
    args = parser.parse_args(argv)
    data = data_folder(parser, args.data)
    scale, stay, threshold, persistence = chosen(args.results)
    pooled = {s: [] for s in SETTINGS}
    for path in files(data):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the learned banks' instability warnings, as in run.py
            learned = jmlgdsl.load(args.results / "strict" / f"{path.parent.name}_{path.stem}.jmlg")
        rows = read_csv(path, Columns(outputs=SENSORS))
        for sd, sensors in SETTINGS:
            model = bank(learned, sd, sensors, scale, stay)
            posterior = jmlgdsl.filter(model, rows.y, algorithm="imm").mode_posterior
            alarm = AlarmRule(model.modes[:-1], threshold, persistence).alarms(posterior, model.modes)[TRAIN:]
            pooled[sd, sensors].append(score(alarm, rows.anomaly[TRAIN:], rows.time[TRAIN:], rows.changepoint[TRAIN:]))
        print(f"\r{path.parent.name}/{path.name}", end="  ", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    lines = ["| drift mode | F1 | FAR % | MAR % | NAB (standard) | FPs | missed CPs |", "|---|---|---|---|---|---|---|"]
    figures = {}
    for (sd, sensors), scores in pooled.items():
        s = Scores.pool(scores).summary()
        what = ("none" if not sd else f"sd {sd:g} on " + ("every sensor" if len(sensors) == len(SENSORS)
                                                         else ", ".join(SENSORS[i] for i in sensors)))
        lines.append(f"| {what} | {s['f1']:.3f} | {s['far']:.1f} | {s['mar']:.1f} | {s['nab_standard']:.2f} | {s['fp']} | "
                     f"{s['missed_cp']} |")
        key = "none" if not sd else f"sd{sd:g}_{'all' if len(sensors) == len(SENSORS) else 'temperatures'}"
        figures.update({f"{key}_{k}": s[k] for k in ("f1", "far", "mar", "nab_standard", "fp", "missed_cp")})
    figures["table"] = "\n".join(lines)
    print(figures["table"])
    (args.results / "strict" / "drift.md").write_text(
        f"python benchmarks/skab/drift.py (the strict banks of run.py; noise x{scale:g}, stay {stay:g}, threshold "
        f"{threshold:g}, persistence {persistence}; rows 400 on, pooled over the 34 files)\n\n{figures['table']}\n")
    ledger.record("skab/drift", figures, "python benchmarks/skab/drift.py --data DIR", path=args.ledger)
    return 0


if __name__ == "__main__":
    sys.exit(main())
