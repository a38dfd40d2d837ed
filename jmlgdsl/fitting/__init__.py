"""Gray-box identification: fit the unknowns a spec writes with priors (`param U ~ LogNormal(...)`)
to recorded data, by maximum a posteriori over the compiled bank, with Laplace standard errors and
optional Metropolis draws, and write the spec back with the fitted values (docs/fit.md).

    >>> import jmlgdsl
    >>> fitted = jmlgdsl.fit("examples/fit/dryer_physical.jmlg", "examples/dryer_seq1.csv")
    >>> values = fitted.values()
    >>> round(values["T_fan"], 1), round(values["tau_normal"])
    (44.1, 30)
    >>> print(fitted.report().splitlines()[0])
    unknown     prior                   estimate  se     prior median
    >>> "T_fan = 44.08" in fitted.text   # the spec rewritten with the fitted values; fitted.write(path)
    True

The examples show fitted values no finer than the fit settles them: BFGS stops on a gradient
(GTOL), so the last digits of an estimate move with the BLAS kernel a processor gets.

`fit_units` fits one spec to each of many units' recordings on its own (a fleet of one design whose
units each have their own numbers), in parallel, `units_table` lays their values side by side and
`write_units` writes each unit's spec and that table to a folder (`check_units` first);
`jmlgdsl run --unit-specs` then diagnoses each unit under its own fitted spec (docs/fleet.md).
"""

from __future__ import annotations

import csv
import io
import math
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from ..data import Data, open_target, read_csv
from ..infer.algorithms import algorithm_named
from ..lang.parse import parse_file
from ..output import check_folder, file_names
from ..lang.syntax import Spec
from .estimate import Fit, maximise
from .family import Family, FitError
from .rewrite import fitted_text

__all__ = ["fit", "fit_units", "units_table", "check_units", "write_units", "Fit", "Family", "FitError"]


def fit(spec, data, *, algorithm: str = "imm", samples: int = 0, starts: int | None = None, seed=None,
        label_rounds: bool = True, progress=None, jobs: int | None = None) -> Fit:
    """Fit a spec's unknowns to data.

    spec: a .jmlg path or a parsed Spec. data: a CSV path, a jmlgdsl.data.Data, or a list of them
    (several recordings of the same plant). Rows whose every `mode` cell is filled give an exact
    likelihood; other recordings use the filter's (`algorithm`, IMM by default). `samples` > 0 adds
    posterior draws by random-walk Metropolis. The search starts at the priors' medians; for
    unlabelled data also there with every row first taken for the spec's first mode (two starts by
    default: `starts` None); more `starts` add draws of the priors (seeded by `seed`, as the draws of
    `samples` are). The highest peak is kept; up to `jobs` starts search at a time, in processes of
    their own (default: one per core; the same peaks however many). Where some data are unlabelled, each
    start first goes through rounds of labelling them by their most probable modes (`label_rounds`
    False skips them: the search climbs the filter's likelihood from the start itself). The returned Fit has the estimates,
    standard errors, the fitted Model, `warnings` where the fit cannot be trusted (it did not converge,
    or its curvature is noise), and `text`, the spec rewritten with the fitted values and those warnings."""
    if samples < 0 or (starts is not None and starts < 1):
        raise FitError(f"samples must be 0 or more and starts 1 or more, got {samples} and {starts}")
    if jobs is not None and jobs < 1:
        raise FitError(f"jobs must be 1 or more, got {jobs}")
    algorithm_named(algorithm)  # an unknown filter refused before any work
    spec = spec if isinstance(spec, Spec) else parse_file(spec)
    family = Family(spec)
    columns = family.model(family.medians())
    recordings = [d if isinstance(d, Data) else read_csv(d, columns)
                  for d in (data if isinstance(data, (list, tuple)) else [data])]
    if not recordings:
        raise FitError("no data to fit to")
    result = maximise(family, recordings, algorithm, samples, seed, progress, starts, label_rounds, jobs)
    sources = ", ".join(Path(d.source).name for d in recordings)
    header = "\n".join([f"Fitted by 'jmlgdsl fit' to {sources}: log-likelihood {result.loglik_start:.6g} "
                        f"at the priors' medians, {result.loglik:.6g} fitted."]
                       + [f"warning: {w}" for w in result.warnings])
    result.text = fitted_text(spec, family.unknowns, result.estimate, result.se, header)
    return result


def fit_units(spec, paths, *, jobs: int | None = None, done=None, **options) -> list[Fit]:
    """`fit` of the spec to each recording in `paths` on its own (each a unit of the plant with its own
    numbers), with the same options (`seed` too, so a unit's fit is the same whichever others come
    with it), in `jobs` processes (default: every core; each unit's starts then one after the other).
    `done(i, fit)` hears of each unit's fit as it ends. The fits in the order of `paths`; the first that
    fails raises its error, naming its file."""
    spec = spec if isinstance(spec, Spec) else parse_file(spec)
    paths = list(paths)
    if not paths:
        raise FitError("no data to fit to")
    jobs = max(1, min(len(paths), jobs or os.cpu_count() or 1))
    options = dict(options, jobs=1)  # the units side by side, not their starts
    fits = [None] * len(paths)
    if jobs == 1:
        for i, path in enumerate(paths):
            fits[i] = _fit_unit(spec, path, options)
            if done:
                done(i, fits[i])
        return fits
    with ProcessPoolExecutor(jobs) as pool:
        futures = {pool.submit(_fit_unit, spec, path, options): i for i, path in enumerate(paths)}
        for future in as_completed(futures):
            i = futures[future]
            fits[i] = future.result()
            if done:
                done(i, fits[i])
    return fits


def _fit_unit(spec: Spec, path, options: dict) -> Fit:
    """One unit's fit; its errors name its file."""
    try:
        return fit(spec, path, **options)
    except FitError as exc:
        raise FitError(f"{path}: {exc}") from None


def units_table(units, fits) -> str:
    """Every unit's fitted values side by side, as CSV: a row per unit (its name in `units`), each
    unknown's estimate and its standard error (`NAME`, `NAME_se`; empty where there is none), the
    log-likelihood and the fit's warnings (empty: none)."""
    names = fits[0].names
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["unit", *(f"{n}{suffix}" for n in names for suffix in ("", "_se")), "loglik", "warnings"])
    for unit, result in zip(units, fits):
        cells = [c for v, e in zip(result.estimate, result.se) for c in (f"{v:.10g}", f"{e:.4g}" if math.isfinite(e) else "")]
        writer.writerow([unit, *cells, f"{result.loglik:.10g}", "; ".join(result.warnings)])
    return out.getvalue()


def check_units(folder, paths, inputs=()) -> None:
    """Refuse, before any work, recordings that cannot each give a unit spec (`file_names`) or a `folder`
    their specs and units.csv cannot go to: one that cannot be written, or where a file written would be
    one of the recordings or the other `inputs`."""
    check_folder(folder, file_names(paths, ".jmlg", "unit spec") + ["units.csv"], inputs=[*inputs, *paths])


def write_units(folder, paths, fits) -> None:
    """Each unit's fitted spec as FOLDER/NAME.jmlg for its recording NAME.csv in `paths`, and
    FOLDER/units.csv, every unit's values side by side (`units_table`); each file whole or absent."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name, result in zip(file_names(paths, ".jmlg", "unit spec"), fits):
        result.write(folder / name)
    with open_target(folder / "units.csv") as out:
        out.write(units_table([Path(path).stem for path in paths], fits))
