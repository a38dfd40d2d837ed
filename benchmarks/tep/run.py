"""The Tennessee Eastman benchmark: detect and name 18 faults on the Braatz recordings.

    python benchmarks/tep/run.py                      # fetch, learn, run, score; record in the ledger
    python benchmarks/tep/run.py --cache DIR          # the wheel already fetched into DIR

The recordings (Braatz et al.; 52 variables, 3-minute samples) come from the wheel of bibmon 1.2.0
on PyPI (`pip download bibmon==1.2.0 --no-deps`), checked against its sha256 and read out of it,
never copied into the project. Training: d00.dat (normal operation, 500 rows) and dXX.dat (fault
XX, 480 rows); test: dXX_te.dat, 960 rows with the fault from row 161. Faults 3, 9 and 15 are left
out, as the field does (they do not show in the measurements).

jmlgdsl, as a user runs it: `jmlgdsl learn --mode normal=d00.csv --mode faultXX=dXX.csv ...
--output <the 52 names> --dt 180` with nothing else chosen, then `jmlgdsl run SPEC dXX_te.csv
--healthy normal -o TABLE` on every test recording (the learned bank's catch-all makes `run` detect
with normal and the catch-all and name with the fault modes). Scored per test recording: the alarm
(the table's), the detector's P(anomaly) for the curve, and the naming: the fault modes' most
probable mode on every row after the onset, alarm or not (under mmae, the filter `run` names
with). Timed: learn; each run, whole and its diagnosis alone (from the times per step `run`
reports); and one run over the 19 test recordings one after another in one file, a replay of a long
history.

Baselines, written here: PCA T^2 and Q on the standardised normal recording, dynamic PCA (lagged
copies), and a bank of per-fault VAR(1) models fitted by least squares with a covariance floor,
named by a forward filter. Their settings (components, lags, floor, persistence of the mode chain)
are chosen by cross-validation on the training recordings alone: normal rows held out for the
false-alarm thresholds, fault recordings for the detection or naming; the test recordings only
score. Detection rates are read at 0.5, 1 and 5 % false alarms on d00_te (each method's statistic
thresholded at that quantile of its d00_te values: a curve, comparable across methods whatever
their own thresholds).
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: threads only contend (BENCHMARKS.md)

import numpy as np  # noqa: E402
from jmlgdsl.learn.relative import forward as hidden_markov_forward  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import ledger  # noqa: E402  (benchmarks/ledger.py, the results ledger)

WHEEL = "bibmon-1.2.0-py3-none-any.whl"
SHA256 = "a74717f9157c6e414f5d225c850bf68df2b3edc1ee7833cc0e99f2164066f397"
FAULTS = [f for f in range(1, 22) if f not in (3, 9, 15)]
ONSET = 160  # the test recordings' fault starts at row 161
NAMES = [f"xmeas{i}" for i in range(1, 42)] + [f"xmv{i}" for i in range(1, 12)]
RATES = (0.005, 0.01, 0.05)
RESULTS = Path(__file__).resolve().parent / "results"


def fetch(cache: Path) -> dict[str, np.ndarray]:
    """{name: rows} of every recording (d00, d00_te, d01, ...), from the wheel in `cache` (downloaded
    there when missing), its sha256 checked first."""
    wheel = cache / WHEEL
    if not wheel.exists():
        cache.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "pip", "download", "bibmon==1.2.0", "--no-deps", "-d", str(cache)],
                       check=True, stdout=subprocess.DEVNULL)
    digest = hashlib.sha256(wheel.read_bytes()).hexdigest()
    if digest != SHA256:
        raise SystemExit(f"{wheel}: sha256 {digest}, expected {SHA256}; not the published wheel")
    out = {}
    with zipfile.ZipFile(wheel) as z:
        for item in z.namelist():
            if item.startswith("bibmon/tennessee_eastman/") and item.endswith(".dat"):
                rows = np.loadtxt(io.BytesIO(z.read(item)))
                out[Path(item).stem] = rows.T if rows.shape[0] == 52 else rows  # d00.dat is stored transposed
    return out


def standardise(train: np.ndarray):
    mu, sd = train.mean(0), train.std(0)
    sd = np.where(sd > 0, sd, 1.0)
    return lambda a: (a - mu) / sd


# ---------------------------------------------------------------- baselines

def pca_stats(train, k):
    """T^2 and Q of rows against a PCA of `train` (standardised rows) with k components."""
    _, s, Vt = np.linalg.svd(train - train.mean(0), full_matrices=False)
    P, lam = Vt[:k].T, s[:k] ** 2 / (len(train) - 1)
    mean = train.mean(0)

    def stats(rows):
        x = rows - mean
        t = x @ P
        return (t ** 2 / lam).sum(1), ((x - t @ P.T) ** 2).sum(1)
    return stats


def lagged(rows, lags):
    """Rows with their `lags` previous rows beside them (the first `lags` rows repeat the first)."""
    if not lags:
        return rows
    padded = np.vstack([np.repeat(rows[:1], lags, axis=0), rows])
    return np.hstack([padded[lags - i:len(padded) - i] for i in range(lags + 1)])


def blocks(n, folds=5):
    return np.array_split(np.arange(n), folds)


def cv_detection(normal, faults, make, statistic):
    """Mean detection over the training fault recordings at a 1 % false-alarm threshold set on the
    normal rows held out (5 contiguous blocks, each scored by a model of the others)."""
    held = []
    for b in blocks(len(normal)):
        keep = np.ones(len(normal), bool)
        keep[b] = False
        held.append(statistic(make(normal[keep]), normal[b]))
    threshold = np.quantile(np.concatenate(held), 0.99)
    model = make(normal)
    return float(np.mean([(statistic(model, f) > threshold).mean() for f in faults]))


def pca_baselines(z, data):
    """{name: (statistic of a standardised test recording, chosen settings)} for PCA T^2 and Q and
    dynamic PCA T^2 and Q (1 or 2 lags), components and lags chosen by `cv_detection` on the
    training recordings."""
    normal = z(data["d00"])
    faults = [z(data[f"d{f:02d}"]) for f in FAULTS]
    found = {}
    for lags in (0, 1, 2):
        for which, label in ((0, "T2"), (1, "Q")):
            name = f"{'dynamic ' if lags else ''}PCA {label}"
            for k in (5, 10, 15, 20, 25, 30, 35):
                score = cv_detection(lagged(normal, lags), [lagged(f, lags) for f in faults],
                                     lambda t, k=k: pca_stats(t, k), lambda s, rows, w=which: s(rows)[w])
                if name not in found or score > found[name][0]:
                    found[name] = (score, k, lags, which)
    out = {}
    for name, (_, k, lags, which) in found.items():
        stats = pca_stats(lagged(normal, lags), k)
        out[name] = (lambda rows, s=stats, w=which, n=lags: s(lagged(rows, n))[w],
                     f"{k} components" + (f", {lags} lags" if lags else ""))
    return out


def var_fit(rows, floor):
    X = np.hstack([rows[:-1], np.ones((len(rows) - 1, 1))])
    W, *_ = np.linalg.lstsq(X, rows[1:], rcond=None)
    E = rows[1:] - X @ W
    return W, np.linalg.cholesky(E.T @ E / len(E) + floor * np.eye(rows.shape[1]))


def var_loglik(bank, rows):
    """(T - 1, K) one-step log-densities of rows under each VAR(1) of the bank."""
    X = np.hstack([rows[:-1], np.ones((len(rows) - 1, 1))])
    out = []
    for W, L in bank:
        r = np.linalg.solve(L, (rows[1:] - X @ W).T)
        out.append(-0.5 * (r ** 2).sum(0) - np.log(np.diag(L)).sum())
    return np.array(out).T


def forward(loglik, stay):
    """The filtered log-probabilities of the bank's modes (jmlgdsl's forward filter), staying in a mode
    with probability `stay`, the rest shared evenly."""
    K = loglik.shape[1]
    return hidden_markov_forward(loglik, np.log(np.where(np.eye(K, dtype=bool), stay, (1 - stay) / (K - 1))))


def var_bank(z, data):
    """The per-fault VAR(1) namer: (a function from a test recording to each row's named fault index,
    the chosen settings); floor and stay chosen by two-fold cross-validation on the fault recordings
    (each half named by a bank fitted to the other halves)."""
    faults = [z(data[f"d{f:02d}"]) for f in FAULTS]
    best = None
    for floor in (0.001, 0.01, 0.1):
        for stay in (0.99, 0.999):
            score = 0.0
            for half in (0, 1):
                parts = [np.array_split(f, 2) for f in faults]
                bank = [var_fit(p[1 - half], floor) for p in parts]
                score += np.mean([(forward(var_loglik(bank, p[half]), stay).argmax(1) == i).mean()
                                  for i, p in enumerate(parts)])
            if best is None or score > best[0]:
                best = (score, floor, stay)
    _, floor, stay = best
    bank = [var_fit(f, floor) for f in faults]
    return (lambda rows: np.r_[0, forward(var_loglik(bank, z(rows)), stay).argmax(1)],
            f"covariance floor {floor:g}, stay {stay:g}")


# ---------------------------------------------------------------- jmlgdsl

def jmlgdsl_cli(*argv) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "jmlgdsl", *argv], capture_output=True, text=True, check=True)


def write_csv(path: Path, rows: np.ndarray, modes=None):
    header = ",".join(NAMES + (["mode"] if modes is not None else []))
    with open(path, "w") as f:
        f.write(header + "\n")
        for i, row in enumerate(rows):
            f.write(",".join(repr(float(v)) for v in row) + (f",{modes[i]}" if modes is not None else "") + "\n")


def jmlgdsl_rows(data, work: Path):
    """Plain learn, then run on every test recording: per test recording the alarm column, the
    detector's P(anomaly) and the namer's most probable fault (fault index) per row; the learn and
    run times (run's: the whole command's, and its diagnosis's from the times per step it reports);
    the learn command's report."""
    import jmlgdsl
    from jmlgdsl.diagnosis.alarms import sub_bank
    from jmlgdsl.infer.algorithms import NAMER_ALGORITHM

    write_csv(work / "normal.csv", data["d00"])
    argv = ["learn", "--mode", f"normal={work / 'normal.csv'}"]
    for f in FAULTS:
        write_csv(work / f"fault{f}.csv", data[f"d{f:02d}"])
        argv += ["--mode", f"fault{f}={work / f'fault{f}.csv'}"]
    spec = work / "tep.jmlg"
    start = time.perf_counter()
    learned = jmlgdsl_cli(*argv, "--output", ",".join(NAMES), "--dt", "180", "--name", "tep", "-o", str(spec))
    learn_s = time.perf_counter() - start
    model = jmlgdsl.load(spec)
    detector = sub_bank(model, ["normal", "anomaly"])
    namer = sub_bank(model, [f"fault{f}" for f in FAULTS])
    out, run_s, diagnosis_s = {}, [], []
    for k in [0] + FAULTS:
        rows = data[f"d{k:02d}_te"]
        truth = ["normal"] * ONSET + [f"fault{k}" if k else "normal"] * (len(rows) - ONSET)
        test, table = work / f"test{k:02d}.csv", work / f"table{k:02d}.csv"
        write_csv(test, rows, truth)
        start = time.perf_counter()
        ran = jmlgdsl_cli("run", str(spec), str(test), "--healthy", "normal", "-o", str(table))
        run_s.append(time.perf_counter() - start)
        detector_ms = float(re.search(r"time per step: ([0-9.]+) ms", ran.stdout).group(1))
        namer_steps = re.search(r"namer: ([0-9]+) steps around the alarms, ([0-9.]+) ms per step", ran.stdout)
        diagnosis_s.append(1e-3 * (len(rows) * detector_ms + (int(namer_steps.group(1)) * float(namer_steps.group(2))
                                                               if namer_steps else 0.0)))
        with open(table) as f:
            header = f.readline().strip().split(",")
            alarm = np.array([int(line.split(",")[header.index("alarm")]) for line in f])
        p_anomaly = jmlgdsl.filter(detector, rows, np.zeros((len(rows), 0))).mode_posterior[:, 1]
        named = jmlgdsl.filter(namer, rows, np.zeros((len(rows), 0)), algorithm=NAMER_ALGORITHM).mode_posterior.argmax(1)
        out[k] = (alarm, p_anomaly, named)
    # the 19 recordings one after another in one file, as a replay of a long history: the command's
    # start paid once
    replay = work / "replay.csv"
    with open(replay, "w") as f:
        for k in [0] + FAULTS:
            lines = (work / f"test{k:02d}.csv").read_text().splitlines(keepends=True)
            f.writelines(lines if k == 0 else lines[1:])
    start = time.perf_counter()
    jmlgdsl_cli("run", str(spec), str(replay), "--healthy", "normal", "-o", str(work / "replay-table.csv"))
    replay_s = time.perf_counter() - start
    return out, learn_s, (run_s, diagnosis_s, replay_s), learned.stdout, learned.stderr


def catch_all_detector(data):
    """The detector of a bank of normal operation alone, as docs/realdata.md builds it for SKAB: the
    normal mode by EM (`learn --relative-to none`) and `like normal { noise scale 3 }`, the alarm at
    3 rows in a row: (its P(anomaly) on a test recording, the alarm of P(anomaly) > 0.5 at 3 rows in
    a row)."""
    import jmlgdsl
    from jmlgdsl.learn import learn
    from jmlgdsl.learn.bank import Experiment

    bank = learn({"normal": Experiment(data["d00"], np.zeros((len(data["d00"]), 0)), "d00")}, outputs=NAMES,
                 dt=180, relative_to=None, catch_all=("anomaly", 3.0)).model

    def p_anomaly(rows):
        return jmlgdsl.filter(bank, rows, np.zeros((len(rows), 0))).mode_posterior[:, 1]

    def alarm(rows, persistence=3):
        up = p_anomaly(rows) > 0.5
        run = np.convolve(up, np.ones(persistence), mode="full")[:len(up)]
        return run >= persistence
    return p_anomaly, alarm


# ---------------------------------------------------------------- scoring

def curve(score_of, data):
    """Detection rate (mean over the faults, post-onset rows) at each of RATES false alarms on d00_te."""
    normal = score_of(data["d00_te"])
    scores = {f: score_of(data[f"d{f:02d}_te"])[ONSET:] for f in FAULTS}
    return {rate: float(np.mean([(s > np.quantile(normal, 1 - rate)).mean() for s in scores.values()]))
            for rate in RATES}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "jmlgdsl-tep",
                   help="where the bibmon wheel is kept (downloaded when missing)")
    ledger.ledger_argument(p)
    args = p.parse_args(argv)
    data = fetch(args.cache)
    z = standardise(data["d00"])
    figures, table = {}, {}

    for name, (statistic, how) in pca_baselines(z, data).items():
        c = curve(lambda rows, s=statistic: s(z(rows)), data)
        table[name] = {"settings": how, **{f"detected at {r:.1%}": v for r, v in c.items()}}
        figures.update({f"{name.replace(' ', '_').lower()}_detected_{r:g}": round(v, 3) for r, v in c.items()})

    name_var, how = var_bank(z, data)
    var_named = [(name_var(data[f"d{f:02d}_te"])[ONSET:] == i).mean() for i, f in enumerate(FAULTS)]
    table["VAR(1) bank"] = {"settings": how, "naming": float(np.mean(var_named)),
                            "naming per fault": dict(zip(map(str, FAULTS), map(float, var_named)))}
    figures["var_bank_naming"] = round(float(np.mean(var_named)), 3)

    p_anomaly, alarm = catch_all_detector(data)
    c = curve(p_anomaly, data)
    up = float(np.mean([alarm(data[f"d{f:02d}_te"])[ONSET:].mean() for f in FAULTS]))
    quiet = float(alarm(data["d00_te"]).mean())
    table["EM normal + catch-all x3, persistence 3"] = {
        "settings": "fixed: scale 3, alarm at 3 rows in a row", "detected at the alarm": up, "alarm on d00_te": quiet,
        **{f"detected at {r:.1%}": v for r, v in c.items()}}
    figures.update({f"catch_all_detected_{r:g}": round(v, 3) for r, v in c.items()})
    figures.update({"catch_all_alarm_d00": round(quiet, 4), "catch_all_detected_alarm": round(up, 3)})

    with tempfile.TemporaryDirectory() as work:
        rows, learn_s, (run_s, diagnosis_s, replay_s), report, said = jmlgdsl_rows(data, Path(work))
    choices = "\n".join(line for line in said.splitlines()
                        if line.startswith(("the modes relative", "the other modes", "catch-all noise scale")))
    normal_p = rows[0][1]
    detected = {rate: float(np.mean([(rows[f][1][ONSET:] > np.quantile(normal_p, 1 - rate)).mean() for f in FAULTS]))
                for rate in RATES}
    named = [(rows[f][2][ONSET:] == i).mean() for i, f in enumerate(FAULTS)]
    confusion = np.array([np.bincount(rows[f][2][ONSET:], minlength=len(FAULTS)) for f in FAULTS])
    alarm_normal = float(rows[0][0].mean())
    alarm_detected = float(np.mean([rows[f][0][ONSET:].mean() for f in FAULTS]))
    delays = [int(np.argmax(rows[f][0][ONSET:])) for f in FAULTS if rows[f][0][ONSET:].any()]
    table["jmlgdsl learn + run"] = {
        "detected at the alarm": alarm_detected, "alarm on d00_te": alarm_normal,
        **{f"detected at {r:.1%}": v for r, v in detected.items()},
        "delay, samples (mean over detected faults)": float(np.mean(delays)), "faults detected": len(delays),
        "naming": float(np.mean(named)), "naming per fault": dict(zip(map(str, FAULTS), map(float, named))),
        "learn seconds": learn_s, "run rows per second": 960 * len(run_s) / sum(run_s),
        "run diagnosis rows per second": 960 * len(run_s) / sum(diagnosis_s),
        "run rows per second, the 19 recordings in one file": 960 * len(run_s) / replay_s}
    figures.update({"jmlgdsl_naming": round(float(np.mean(named)), 3), "jmlgdsl_alarm_d00": round(alarm_normal, 4),
                    "jmlgdsl_detected_alarm": round(alarm_detected, 3),
                    **{f"jmlgdsl_detected_{r:g}": round(v, 3) for r, v in detected.items()},
                    "jmlgdsl_delay_samples": round(float(np.mean(delays)), 1), "jmlgdsl_faults_detected": len(delays),
                    "learn_choices": choices,
                    **{f"jmlgdsl_naming_{f}": round(float(v), 3) for f, v in zip(FAULTS, named)},
                    **{f"jmlgdsl_detected_alarm_{f}": round(float(rows[f][0][ONSET:].mean()), 3) for f in FAULTS}})
    def cell(row, key):
        return f"{row[key]:.3f}" if key in row else "–"
    figures["detection_table"] = "\n".join(
        ["| method | settings | " + " | ".join(f"detected at {r:.1%} FA" for r in RATES) + " | named right |",
         "|---|---|" + "---:|" * (len(RATES) + 1)]
        + [f"| {name} | {row.get('settings', 'none: plain learn, then run')} | "
           + " | ".join(cell(row, f"detected at {r:.1%}") for r in RATES) + f" | {cell(row, 'naming')} |"
           for name, row in table.items()])
    figures["naming_table"] = "\n".join(
        ["| fault | jmlgdsl learn + run | VAR(1) bank |", "|---|---:|---:|"]
        + [f"| {f} | {a:.3f} | {b:.3f} |" for f, a, b in zip(FAULTS, named, var_named)]
        + [f"| mean | {np.mean(named):.3f} | {np.mean(var_named):.3f} |"])
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "summary.json").write_text(json.dumps(table, indent=1) + "\n")
    (RESULTS / "confusion.csv").write_text(
        "true\\named," + ",".join(f"fault{f}" for f in FAULTS) + "\n"
        + "".join(f"fault{f}," + ",".join(map(str, row)) + "\n" for f, row in zip(FAULTS, confusion)))
    (RESULTS / "learn.txt").write_text(report)
    tolerance = {key: (0.002 if "alarm_d00" in key else 0.01) for key in figures if not isinstance(figures[key], str)}
    tolerance["jmlgdsl_delay_samples"] = 1.0
    tolerance["jmlgdsl_faults_detected"] = 0
    ledger.record("tep/default", figures, "python benchmarks/tep/run.py", tolerance,
                  {"learn_seconds": round(learn_s, 1), "run_rows_per_second": round(960 * len(run_s) / sum(run_s)),
                   "run_diagnosis_rows_per_second": round(960 * len(run_s) / sum(diagnosis_s)),
                   "run_replay_rows_per_second": round(960 * len(run_s) / replay_s)},
                  path=args.ledger)
    print(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
