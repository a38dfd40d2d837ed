"""A whole study as `jmlgdsl bench` runs it: the data sources (files with the true mode, or fresh
simulations), the sweep over them, the tables per source and the files written."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from ..data import read_csv
from ..errors import DataError
from ..model import Model
from ..names import plural
from ..output import check_count, replacing
from ..simulation.linear import step_bytes
from . import figures
from .sweep import (LabelledSequence, Simulated, nonlinear_plant, report, summarise, sweep, write_records_csv,
                    write_table_csv)


def sources(model: Model, data=(), simulate: int | None = None, modes: str | None = None,
            nonlinear: str | None = None) -> list:
    """The data a study runs on: the files `data` (each with a true mode on every row), or one source
    simulated afresh for every run (`simulate` steps, or the schedule `modes`; from the ODE spec at
    path `nonlinear` when given)."""
    if data and (simulate or modes or nonlinear):
        raise DataError("give data files or --simulate, not both")
    if not data:
        if simulate is None and modes is None:
            raise DataError("give data files with a 'mode' column, or --simulate T for simulated sequences")
        if simulate is not None:
            check_count("--simulate", simulate, step_bytes(model), "steps")
        if nonlinear:
            if Path(nonlinear).suffix.lower() != ".jmlg":
                raise DataError("--nonlinear needs a .jmlg spec with an 'ode' block")
            nonlinear_plant(nonlinear)  # a spec without equations fails here, before any run starts
        return [Simulated(simulate, modes, plant=nonlinear)]
    stems = [Path(p).stem for p in data]
    if len(set(stems)) < len(stems):
        raise DataError(f"data files need different names (their tables are named after them): {', '.join(data)}")
    found = []
    for path in data:
        read = read_csv(path, model)
        if read.modes is None:
            raise DataError(f"{path}: no 'mode' column, so the diagnosis error cannot be measured")
        if (read.modes < 0).any():
            raise DataError(f"{path}: data row {int((read.modes < 0).argmax()) + 1} has no true mode, so "
                            "the diagnosis error cannot be measured on it")
        found.append(LabelledSequence(Path(path).stem, read.y, read.u, read.modes))
    return found


@dataclass(frozen=True)
class Study:
    """The per-run records of a sweep on a model, with their tables per data source; `healthy` names
    the modes that raise no alarm, the others are the faults named."""

    model: Model
    records: list
    runs: int
    healthy: tuple[str, ...]

    @property
    def faults(self) -> list[str]:
        """The non-healthy modes, in the spec's order: the faults the naming scores count."""
        return [m for m in self.model.modes if m not in self.healthy]

    @cached_property
    def by_source(self) -> dict:
        """{source name: (its records, their summary)}, in order of first appearance."""
        names = dict.fromkeys(r["data"] for r in self.records)
        mine = {name: [r for r in self.records if r["data"] == name] for name in names}
        return {name: (rows, summarise(rows)) for name, rows in mine.items()}

    def report(self) -> str:
        """Every source's tables as Markdown, under a heading that names the source and the runs."""
        return "\n".join(f"## {self.model.name}, {name}: {plural(self.runs, 'run')} per setting; healthy: "
                         f"{', '.join(self.healthy)}\n\n{report(summary, self.faults)}"
                         for name, (_, summary) in self.by_source.items())

    def write(self, folder, figures_too=True) -> list[Path]:
        """Every run (runs.csv), each source's tables (Markdown, CSV) and, unless told not to, its
        figures, each file whole or not at all; returns the paths written."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)

        def put(file, write):
            with replacing(folder / file) as temporary:
                write(temporary)
            return folder / file

        model = self.model
        written = [put("runs.csv", lambda path: write_records_csv(path, self.records))]
        for name, (mine, summary) in self.by_source.items():
            written += [put(f"{name}-table.md", lambda path: path.write_text(report(summary, self.faults))),
                        put(f"{name}-table.csv", lambda path: write_table_csv(path, summary))]
            if figures_too:
                first = mine[0].get("lag", 0)  # the study figures of the first lag asked for
                written += figures.study_figures(folder, name, f"{model.name}, {name}", model.dt,
                                                 [r for r in summary if r.get("lag", 0) == first],
                                                 [r for r in mine if r.get("lag", 0) == first])
                if len({r.get("lag", 0) for r in mine}) > 1:
                    written.append(figures.error_vs_lag(summary, folder / f"{name}-error-vs-lag.png",
                                                        f"{model.name}, {name}"))
        return written


def study(model: Model, data_sources, runs: int = 25, healthy=None, **options) -> Study:
    """Sweep every setting over `data_sources` (see `sources`) `runs` times (options as `sweep.sweep`),
    with the modes `healthy` raising no alarm (default: the spec's first mode)."""
    records = sweep(model, data_sources, runs=runs, healthy=healthy, **options)
    return Study(model, records, runs, tuple(healthy or model.modes[:1]))
