"""Diagnosis-error studies: every filter at every particle count over independent runs.

The unit of work is `run_job(job) -> record`, a plain top-level function of picklable arguments, so a
sweep runs the same in a local process pool or as Ray tasks on a cluster (`jmlgdsl bench --cluster`).
Seeds come from one root seed through `numpy.random.SeedSequence.spawn`, so a sweep reproduces bit
for bit wherever it runs.
Diagnosis error = percentage of steps whose most probable (MAP) mode differs from the true mode.
Naming = percentage of the faulty rows (true mode not healthy) named right: while a row's alarm is up
it is named by its most probable non-healthy mode, as `run --name` names rows; the counts of a
setting's runs are pooled by adding them (`metrics.NamingCounts`), not averaged.
"""

from __future__ import annotations

import csv
import functools
import math
import operator
import os
import zlib
from dataclasses import dataclass

import numpy as np

from ..diagnosis.alarms import AlarmRule
from ..errors import DataError
from ..infer import ALGORITHMS, filter as run_filter, particle_bytes, smooth
from ..diagnosis.metrics import NamingCounts, naming_counts, switch_delays
from ..diagnosis.report import naming_report
from ..diagnosis.truth import detection_scores
from ..model import Model
from ..names import plural
from ..output import check_count
from ..diagnosis.prefilter import moving_average
from ..diagnosis.progress import Progress
from ..simulation.linear import simulate

DEFAULT_PARTICLES = (1, 4, 10, 25, 50, 100, 200, 400, 800, 1600)
DEFAULT_FILTERS = ("pf", "rbpf", "la-rbpf", "fc-rbpf", "imm")
MEASURES = ("error", "delay", "f1", "far", "mar", "nab", "ms_per_step", "loglik")  # averaged over runs in the tables
# each run's naming % as well (the tables pool the runs' counts instead of averaging it)
RECORD_FIELDS = ("data", "filter", "particles", "lag", "run", *MEASURES, "naming")
JOB_BYTES = 4096  # a job, its seeds and its record, to refuse a sweep too large to list


@dataclass(frozen=True)
class LabelledSequence:
    """Data with the true mode at every step: y (T, ny), u (T, nu), modes (T,) indices."""

    name: str
    y: np.ndarray
    u: np.ndarray
    modes: np.ndarray


@dataclass(frozen=True)
class Simulated:
    """Fresh sequences of `steps` steps, one per run, with modes from the chain or a fixed schedule.

    `plant` is what generates them: None for the filters' own model, another Model (the true plant,
    when the filters use a perturbed one), or the path of an ODE spec to simulate its nonlinear
    equations, so that model mismatch is real.
    """

    steps: int | None
    schedule: str | None = None
    name: str = "simulated"
    plant: Model | str | None = None


@dataclass(frozen=True)
class Job:
    """One filter run: a filter at one particle count on one sequence, with its own seeds."""

    model: Model
    source: LabelledSequence | Simulated
    algorithm: str
    particles: int | None
    run: int
    data_seed: np.random.SeedSequence  # draws the simulated sequence (shared by every filter of a run)
    filter_seed: np.random.SeedSequence
    prefilter: int | None = None  # moving-average window applied to the outputs
    lag: int | None = 0  # smoothing lag (0: filtering, None: off-line)
    healthy: tuple[str, ...] | None = None  # the modes that raise no alarm (None: the spec's first mode)


def sequence_of(job: Job) -> LabelledSequence:
    """The data a job filters: the given sequence, or the run's simulated one."""
    if isinstance(job.source, LabelledSequence):
        return job.source
    seed = job.data_seed
    return _simulated(job.source, job.model if job.source.plant is None else job.source.plant, seed.entropy,
                      tuple(seed.spawn_key))


@functools.lru_cache(maxsize=8)
def _simulated(source, plant, entropy, spawn_key) -> LabelledSequence:
    """One run's simulated sequence, kept while a worker's consecutive jobs filter the same run."""
    seed = np.random.SeedSequence(entropy, spawn_key=spawn_key)
    if isinstance(plant, str):
        from ..simulation.nonlinear import simulate_nonlinear

        sim = simulate_nonlinear(nonlinear_plant(plant), source.steps, seed=seed, modes=source.schedule)
    else:
        sim = simulate(plant, source.steps, seed=seed, modes=source.schedule)
    return LabelledSequence(source.name, sim.y, sim.u, sim.modes)


@functools.lru_cache(maxsize=4)
def nonlinear_plant(path):
    """An ODE plant, compiled once per process."""
    from ..simulation.nonlinear import load_nonlinear

    return load_nonlinear(path)


def filter_job(job: Job):
    """(the job's data, the filter's Result on it): the outputs through the job's pre-filter, the
    filter drawing from the job's own seed, so one run of a sweep can be replayed and drawn."""
    data = sequence_of(job)
    y = data.y if job.prefilter is None else moving_average(data.y, job.prefilter)
    if job.lag == 0:
        return data, run_filter(job.model, y, data.u, algorithm=job.algorithm, particles=job.particles,
                                seed=job.filter_seed)
    return data, smooth(job.model, y, data.u, algorithm=job.algorithm, particles=job.particles,
                        seed=job.filter_seed, lag=job.lag)


def run_job(job: Job) -> dict:
    """Filter (or smooth) one sequence and measure it: diagnosis error %, mean detection delay of the
    mode switches in steps (the lag included), the alarms' F1, FAR %, MAR % and NAB (standard) with
    the job's healthy modes, milliseconds per step, log-likelihood, and the naming of the faulty
    rows: its % (`naming`) and its confusion counts as nested lists (`naming_confusion`, plain data
    like the rest of the record)."""
    data, result = filter_job(job)
    delays = switch_delays(result.map_modes, data.modes, job.lag)
    rule = AlarmRule(job.healthy or job.model.modes[:1])
    alarm = rule.alarms(result.mode_posterior, job.model.modes)
    names = naming(rule.faulty_modes(job.model.modes), result.mode_posterior, alarm, data.modes)
    return {"data": data.name, "filter": job.algorithm, "particles": job.particles, "lag": job.lag, "run": job.run,
            "error": result.diagnosis_error(data.modes), "delay": float(delays.mean()) if len(delays) else math.nan,
            **alarm_scores(job.model, rule, alarm, data.modes, job.lag), "ms_per_step": 1e3 * result.seconds / result.T,
            "loglik": result.loglik, "naming": names.overall, "naming_confusion": names.confusion.tolist()}


def alarm_scores(model: Model, rule: AlarmRule, alarm, true_modes, lag) -> dict:
    """F1, FAR, MAR and NAB (standard) of the rule's alarms (threshold 0.5) against the true modes; a
    smoothed row's alarm counts where it is known, `lag` rows later."""
    if lag:
        alarm = np.concatenate([np.zeros(lag, dtype=alarm.dtype), alarm])[:len(alarm)]
    summary = detection_scores(alarm, rule.truth(true_modes, model.modes), model.dt).summary()
    return {"f1": summary["f1"], "far": summary["far"], "mar": summary["mar"], "nab": summary["nab_standard"]}


def naming(faulty, posterior, alarm, true_modes) -> NamingCounts:
    """How the faulty rows were named, fault i being the i-th non-healthy mode (`faulty`, (K,) bool):
    a row whose alarm is up is named by its most probable non-healthy mode, any other row is not named.
    A smoothed row is named from its own smoothed posterior and alarm."""
    fault_of = np.where(faulty, np.cumsum(faulty) - 1, -1)  # mode index -> fault index (-1: healthy)
    named = np.where(alarm == 1, np.argmax(np.asarray(posterior)[:, faulty], axis=1), -1)
    return naming_counts(fault_of[np.asarray(true_modes, dtype=int)], named, int(faulty.sum()))


def make_jobs(model, sources, filters=DEFAULT_FILTERS, particles=DEFAULT_PARTICLES, runs=25, seed=0,
              prefilter=None, lags=(0,), healthy=None) -> list[Job]:
    """Every (source, filter, particle count, run) with seeds derived from `seed`.

    Run r draws its data from the same seed for every filter (paired comparisons); each filter and
    particle count gets its own stream, keyed by (run, filter name, particle count), so adding a
    filter or a count to a sweep leaves every other setting's draws as they were. Deterministic
    filters (imm, exact) run once per run. Each smoothing lag in `lags` (0: the filter, None:
    off-line) is a job of its own with the same seeds as the filter's. `healthy` names the modes
    that raise no alarm (default: the spec's first mode); at least one other mode must remain.
    """
    if not filters:
        raise DataError(f"no filter to run; choose from {', '.join(ALGORITHMS)}")
    for name in filters:
        if name not in ALGORITHMS:
            raise DataError(f"unknown filter {name!r}; choose from {', '.join(ALGORITHMS)}")
    with_particles = any(ALGORITHMS[name].uses_particles for name in filters)
    if not particles and with_particles:
        raise DataError("the particle filters need at least one particle count")
    if runs < 1:
        raise DataError(f"the number of runs must be at least 1, got {runs}")
    if healthy is not None and not AlarmRule(healthy).faulty_modes(model.modes).any():
        raise DataError("--healthy names every mode; leave at least one fault mode")
    bad = [n for n in particles if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1]
    if bad:
        raise DataError(f"particle counts must be positive whole numbers, got {bad[0]!r}")
    if with_particles:
        check_count("particle count", max(particles, default=1), particle_bytes(model))
    cells = [(f, n) for f in filters for n in (particles if ALGORITHMS[f].uses_particles else (None,))]
    cells = list(dict.fromkeys(cells))  # a filter named twice runs once
    check_count("--runs", runs, JOB_BYTES * len(cells) * len(sources))
    jobs = []
    for run in range(runs):
        data_seed = np.random.SeedSequence(seed, spawn_key=(run, 0))
        for algorithm, n in cells:
            filter_seed = np.random.SeedSequence(seed, spawn_key=(run, 1, zlib.crc32(algorithm.encode()), n or 0))
            jobs += [Job(model, source, algorithm, n, run, data_seed, filter_seed, prefilter, lag,
                         None if healthy is None else tuple(healthy))
                     for lag in lags for source in sources]
    return jobs


def execute(jobs, workers=None, cluster=None, progress=None) -> list[dict]:
    """Run every job (in order of the list): serially for workers=1, in a process pool over
    `workers` processes (default: every core), or each job a Ray task on the cluster at `cluster`
    ('auto' or HOST:PORT, as `jmlgdsl.diagnosis.cluster.connect` takes it; the process stays joined).
    A failed run stops the sweep with its error."""
    if workers is not None and workers < 1:
        raise DataError(f"the number of worker processes must be at least 1, got {workers}")
    if workers is not None and cluster is not None:
        raise DataError("--workers counts processes on this machine and --cluster runs on the cluster's CPUs: "
                        "give one or the other")
    bar = Progress(len(jobs), progress) if progress is not None else None
    records = [None] * len(jobs)

    def collect(done):
        """Store each (index, record) at its job's place as it arrives."""
        for i, record in done:
            records[i] = record
            if bar:
                bar.update()

    if cluster is not None:
        from ..diagnosis.cluster import completed, connect

        ray = connect(cluster)
        task = ray.remote(num_cpus=1)(run_job)
        collect(completed(ray, [task.remote(job) for job in jobs]))
    elif (workers or os.cpu_count() or 1) == 1:
        collect(enumerate(map(run_job, jobs)))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        pool = ProcessPoolExecutor(max_workers=workers)
        try:
            index = {pool.submit(run_job, job): i for i, job in enumerate(jobs)}
            collect((index[future], future.result()) for future in as_completed(index))
        finally:
            pool.shutdown(cancel_futures=True)  # a failed run stops the sweep without waiting for the rest
    return records


def sweep(model, sources, filters=DEFAULT_FILTERS, particles=DEFAULT_PARTICLES, runs=25, seed=0,
          prefilter=None, workers=None, cluster=None, progress=None, lags=(0,), healthy=None) -> list[dict]:
    """Per-run records (see RECORD_FIELDS) of every filter at every particle count and lag on every
    source; `workers` and `cluster` as `execute` takes them."""
    jobs = make_jobs(model, sources, filters, particles, runs, seed, prefilter, lags, healthy)
    return execute(jobs, workers, cluster, progress)


def summarise(records) -> list[dict]:
    """Mean and SD over runs for each (data, filter, particles, lag), in order of first appearance,
    and the runs' naming counts added up (`naming_counts`, None without any) with their % (`naming`)."""
    groups = {}
    for r in records:
        groups.setdefault((r["data"], r["filter"], r["particles"], r.get("lag", 0)), []).append(r)
    rows = []
    for (data, name, n, lag), group in groups.items():
        row = {"data": data, "filter": name, "particles": n, "lag": lag, "runs": len(group)}
        for key in MEASURES:
            values = np.array([r.get(key, math.nan) for r in group], dtype=float)
            row[f"{key}_mean"] = float(values.mean())
            row[f"{key}_sd"] = float(values.std(ddof=1)) if len(values) > 1 else math.nan
        counts = [NamingCounts(np.array(c, dtype=int).reshape(len(c), len(c) + 1))  # F faults: (F, F + 1)
                  for c in (r["naming_confusion"] for r in group if "naming_confusion" in r)]
        row["naming_counts"] = functools.reduce(operator.add, counts) if counts else None
        row["naming"] = row["naming_counts"].overall if counts else math.nan
        rows.append(row)
    return rows


def wide(summary):
    """(particle-count rows, filter columns, cell lookup) for one data source; deterministic filters
    (no particle count) share a last row."""
    filters = list(dict.fromkeys(r["filter"] for r in summary))
    counts = sorted({r["particles"] for r in summary if r["particles"] is not None})
    if any(r["particles"] is None for r in summary):
        counts.append(None)
    return counts, filters, {(r["filter"], r["particles"]): r for r in summary}


def mean_sd(row, key, digits) -> str:
    """'mean (SD)' of a measure in a summary row, or the mean alone when one run gives no spread."""
    sd = row[f"{key}_sd"]
    return f"{row[f'{key}_mean']:.{digits}f}" + ("" if math.isnan(sd) else f" ({sd:.{digits}f})")


QUANTITIES = {
    "error": ("Diagnosis error %, mean (SD) over runs", lambda r: mean_sd(r, "error", 2)),
    "delay": ("Detection delay, steps from a switch to the first right row (lag included), mean over runs",
              lambda r: f"{r['delay_mean']:.1f}"),
    "f1": ("Alarms (P(not healthy) > 0.5): F1, FAR %, MAR %, mean over runs",
           lambda r: f"{r['f1_mean']:.3f}, {r['far_mean']:.1f}, {r['mar_mean']:.1f}"),
    "nab": ("Alarms: NAB score (standard profile, 60 s windows), mean over runs", lambda r: f"{r['nab_mean']:.1f}"),
    "naming": ("Naming: % of the faulty rows named right (while the alarm is up, by the most probable "
               "non-healthy mode), pooled over runs", lambda r: f"{r['naming']:.1f}"),
    "ms_per_step": ("Time per step, ms (mean over runs)", lambda r: f"{r['ms_per_step_mean']:.3g}"),
    "loglik": ("Log-likelihood, mean (SD) over runs", lambda r: mean_sd(r, "loglik", 1)),
}


def markdown_table(summary, quantity="error", titled=True) -> str:
    """A Markdown table shaped like the published Table 5.5: one row per particle count N, one
    column per filter; deterministic filters fill the row N = '—'. `titled`: the quantity's title
    above it."""
    title, cell = QUANTITIES[quantity]
    counts, filters, cells = wide(summary)
    lines = [f"{title}", ""] if titled else []
    lines += ["| N | " + " | ".join(filters) + " |", "|---|" + "---|" * len(filters)]
    for n in counts:
        row = [cell(cells[f, n]) if (f, n) in cells else "" for f in filters]
        lines.append(f"| {'—' if n is None else n} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def lag_name(lag) -> str:
    """A smoothing lag in words: the filter, a lag of L steps, or off-line."""
    return "filtering" if lag == 0 else "off-line smoothing" if lag is None else f"lag {lag}"


def report(summary, faults=None) -> str:
    """Every quantity's table, as Markdown; with several smoothing lags, a section for each. Naming
    shows only where some run had faulty rows; given the fault names (the non-healthy modes in the
    spec's order), each section ends with the naming per fault of its best setting."""
    lags = list(dict.fromkeys(r.get("lag", 0) for r in summary))
    sections = []
    for lag in lags:
        rows = [r for r in summary if r.get("lag", 0) == lag]
        named = [r for r in rows if r["naming_counts"] is not None and r["naming_counts"].rows.sum()]
        tables = "\n\n".join(markdown_table(rows, q) for q in QUANTITIES if q != "naming" or named)
        if named and faults is not None:
            tables += "\n\n" + best_naming(named, faults)
        sections.append(tables if len(lags) == 1 else f"### {lag_name(lag)}\n\n{tables}")
    return "\n\n".join(sections) + "\n"


def best_naming(rows, faults) -> str:
    """The naming per fault and the confusion among the faults (as `run --name` reports them) of the
    setting that names the most faulty rows right (the first of equals), pooled over its runs."""
    best = max(rows, key=lambda r: r["naming"])
    who = best["filter"] + ("" if best["particles"] is None else f", N = {best['particles']}")
    return (f"Naming of the best setting ({who}), {plural(best['runs'], 'run')} pooled:\n\n```\n"
            + "\n".join(naming_report(faults, best["naming_counts"])) + "\n```")


def write_table_csv(path, summary):
    """The same tables as CSV: one row per smoothing lag and particle count, per filter error mean/SD,
    detection delay, the alarms' scores, naming % (pooled), ms/step and log-likelihood."""
    filters = list(dict.fromkeys(r["filter"] for r in summary))
    keys = ("error_mean", "error_sd", "delay_mean", "f1_mean", "far_mean", "mar_mean", "nab_mean", "naming",
            "ms_per_step_mean", "loglik_mean", "loglik_sd")
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(["lag", "particles"] + [f"{f}_{k}" for f in filters for k in keys])
        for lag in dict.fromkeys(r.get("lag", 0) for r in summary):
            counts, _, cells = wide([r for r in summary if r.get("lag", 0) == lag])
            for n in counts:
                writer.writerow([lag_cell(lag), "" if n is None else n] + [
                    _cell(cells[f, n][k]) if (f, n) in cells else "" for f in filters for k in keys])


def lag_cell(lag) -> str:
    """A smoothing lag in a CSV cell: the number, or 'offline'."""
    return "offline" if lag is None else str(lag)


def _cell(value):
    """A CSV cell: six significant digits, empty for a missing value (None, NaN)."""
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.6g}"


def read_records_csv(path) -> list[dict]:
    """The runs `write_records_csv` wrote, back as records (the naming counts are not in the file):
    to summarise or draw a sweep again without running it."""
    with open(path, newline="") as stream:
        return [{"data": r["data"], "filter": r["filter"], "particles": int(r["particles"]) if r["particles"] else None,
                 "lag": None if r["lag"] == "offline" else int(r["lag"]), "run": int(r["run"]),
                 **{key: float(r[key]) for key in MEASURES}} for r in csv.DictReader(stream)]


def write_records_csv(path, records):
    """Every run as one CSV row (RECORD_FIELDS), for box plots and re-analysis."""
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(RECORD_FIELDS)
        for r in records:
            writer.writerow([r["data"], r["filter"], "" if r["particles"] is None else r["particles"],
                             lag_cell(r.get("lag", 0)), r["run"],
                             *(f"{r.get(k, math.nan):.10g}" for k in RECORD_FIELDS[5:])])
