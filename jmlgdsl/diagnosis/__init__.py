"""The diagnosis of a source of data rows as one library object, and the sinks it feeds.

`Diagnosis` filters rows one at a time (pre-filter, Filter, alarm rule), keeps the summary, the truth
scoring and the scale check, hands each finished row to its sinks, and saves and resumes its whole
state (`checkpoint`, `Diagnosis.resume`). `jmlgdsl run` is this pipeline with a table sink; a live
monitor is the same pipeline fed from a data bus, checkpointing beside the rows it stores.

    >>> import jmlgdsl
    >>> from jmlgdsl.data import iter_rows, open_source
    >>> from jmlgdsl.diagnosis import Diagnosis, Kept, Options
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> kept = Kept()
    >>> diagnosis = Diagnosis(model, Options(algorithm="imm"), sinks=[kept])
    >>> with open_source("examples/dryer_seq1.csv") as source:
    ...     rows = iter_rows(source, model, source.name)
    ...     for row in rows:
    ...         if row.line == 501:   # half way: save, and carry on in a "new process"
    ...             diagnosis = Diagnosis.resume(diagnosis.checkpoint(), model, sinks=[kept])
    ...         done = diagnosis.feed(row)
    >>> done[0].step.t, model.modes[done[0].step.map_mode], done[0].alarm
    (1000, 'fan', 1)
    >>> len(kept.rows), round(diagnosis.summary.diagnosis_error, 2)
    (1000, 1.0)
"""

from .alarms import AlarmRule
from .evidence import Evidence
from .options import Options
from .pipeline import CheckpointError, Diagnosed, Diagnosis, diagnose, fingerprint
from .sinks import Kept, Raised, TableSink
from .truth import Truth, detection_scores

__all__ = ["AlarmRule", "Diagnosis", "Diagnosed", "diagnose", "CheckpointError", "Evidence", "fingerprint", "Kept",
           "Options", "Raised", "TableSink", "Truth", "detection_scores"]
