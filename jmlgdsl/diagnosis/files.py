"""`diagnose_file`: one data file (or a stream) diagnosed as `jmlgdsl run SPEC DATA` does it, its
result table written as its rows are finished; several files as the units of a fleet are
`jmlgdsl.diagnosis.fleet.diagnose_files`.

    >>> import jmlgdsl
    >>> from jmlgdsl.diagnosis.files import diagnose_file
    >>> ran = diagnose_file(jmlgdsl.load("specs/dryer.jmlg"), "examples/dryer_seq1.csv")
    >>> ran.diagnosis.summary.T, ran.diagnosis.alarms.raised
    (1000, 3)
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

from ..data import iter_rows, open_source, open_target
from ..errors import DataError, JmlgError
from ..model import Model
from ..names import plural
from .progress import Progress
from .alarms import DetectThenName, catch_alls
from .options import Options
from .pipeline import Diagnosis
from .report import evidence_report, naming_report
from .sinks import Kept, Raised, TableSink


@dataclass
class Ran:
    """A data file diagnosed: its Diagnosis, and what the report and the figure need of the run (the
    detect-then-name split, None without one, and whether it was asked for or chosen by itself; the
    alarms' evidence with explain; every row, when a figure is to be drawn)."""

    diagnosis: Diagnosis
    naming: DetectThenName | None
    asked: bool
    raised: Raised | None
    kept: Kept | None

    def report(self) -> str:
        """The terminal report: the split chosen (when it was not asked for), the diagnosis's report,
        the naming scores and the evidence behind each alarm."""
        lines = []
        naming = self.naming
        if naming is not None and not self.asked:
            lines.append(f"detect, then name: the alarm from {', '.join(naming.detector.modes)} (a healthy mode and "
                         f"its catch-all), the fault named by {', '.join(naming.namer.modes)}; --detect with every "
                         "mode gives the whole bank's alarm")
        lines.append(self.diagnosis.report())
        if naming is not None:
            lines.append(f"namer: {plural(naming.steps, 'step')} around the alarms"
                         + (f", {1e3 * naming.seconds / naming.steps:.3f} ms per step" if naming.steps else ""))
        counts = None if naming is None else naming.counts()
        if counts is not None:
            lines.append("\n".join(naming_report(naming.namer.modes, counts)))
        if self.raised is not None:
            lines.append("\n".join(evidence_report(self.diagnosis.model, self.raised)))
        return "\n".join(lines)

    def draw(self, path):
        """The figure of the run (mode posterior, outputs, residuals), kept=True having kept its rows."""
        self.kept.draw(self.diagnosis, path)


def diagnose_file(model: Model, path, options: Options = Options(), *, output=None, kept: bool = False,
                  detect=None, name=None, progress=None) -> Ran:
    """Diagnose the data file `path` ('-': standard input, its rows diagnosed as they arrive) as
    `options` say; with `output` its result table goes there ('-': standard output, every row flushed
    at once when the data are a stream), whole when the run ends or not at all. `kept` keeps every row
    for a figure; `progress` (a stream, or None) shows the rows counted on a terminal.

    `detect` and `name` split the bank (jmlgdsl.diagnosis.alarms.DetectThenName): the alarm from the
    `detect` modes, each alarmed row named by the most probable of the `name` modes. Without them, a
    bank with fault modes and a catch-all of its healthy modes (`catch_alls`) is split by itself, the
    healthy modes and the catch-all detecting, unless the options pre-filter or explain."""
    healthy = list(options.healthy or model.modes[:1])
    asked = bool(detect or name)
    if not (asked or options.prefilter or options.explain) and set(healthy) <= set(model.modes):
        found = catch_alls(model, healthy)
        if found and len(model.modes) > len(healthy) + len(found):
            detect = healthy + found
    naming = None
    if detect or name:
        for given, option in ((options.prefilter, "--prefilter"), (options.explain or None, "--explain")):
            if given is not None:
                raise JmlgError(f"--detect and --name take no {option}: the namer filters the rows as they are")
        naming = DetectThenName(model, detect, name, options)
    bank = model if naming is None else naming.detector
    rows_kept, raised = Kept() if kept else None, Raised() if options.explain else None
    ticker = Progress(None, progress, "rows")
    diagnosis = Diagnosis(bank, options, sinks=[ticker])
    with contextlib.ExitStack() as stack, open_source(path) as source:
        stack.callback(ticker.close)
        if output is not None:
            out = stack.enter_context(open_target(output))
            diagnosis.sinks.append(TableSink(out, bank, options.lag, flush=path == "-", explain=options.explain))
        diagnosis.sinks += [sink for sink in (rows_kept, raised, naming) if sink is not None]
        rows = iter_rows(source, model, source.name)
        diagnosis.run(rows if naming is None else naming.rows(rows))
        if not diagnosis.summary.T:
            raise DataError(f"{source.name}: no data rows")
    return Ran(diagnosis, naming, asked, raised, rows_kept)
