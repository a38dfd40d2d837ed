"""Diagnosis studies (`jmlgdsl bench`): every filter at every particle count over independent runs
(`sweep`), their tables, and their figures (`figures`).

    >>> import jmlgdsl
    >>> from jmlgdsl.studies import sweep
    >>> model = jmlgdsl.load("specs/dryer.jmlg")
    >>> records = sweep.sweep(model, [sweep.Simulated(200, "1-100:normal,101-200:fan")], filters=("imm", "rbpf"),
    ...                       particles=(10,), runs=2, seed=1, workers=1)
    >>> [(r["filter"], r["particles"], r["run"]) for r in records]
    [('imm', None, 0), ('rbpf', 10, 0), ('imm', None, 1), ('rbpf', 10, 1)]
    >>> print(sweep.markdown_table(sweep.summarise(records)).splitlines()[2])
    | N | imm | rbpf |
"""
