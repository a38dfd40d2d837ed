"""jmlgdsl: describe a plant's modes in a small language, compile it to a jump Markov linear
Gaussian model, and diagnose which mode the plant is in with particle filters.

    >>> import jmlgdsl
    >>> model = jmlgdsl.load("specs/dryer.jmlg")       # parse, check and compile a spec
    >>> model.modes
    ('normal', 'fan', 'grill', 'fan_grill')
    >>> data = jmlgdsl.read_csv("examples/dryer_seq1.csv", model)   # columns bound by the spec's names
    >>> result = jmlgdsl.filter(model, data.y, data.u)  # IMM; algorithm="la-rbpf", particles=..., seed=...
    >>> result.mode_posterior.shape, round(result.diagnosis_error(data.modes), 2)
    ((1000, 4), 1.0)
    >>> sim = jmlgdsl.simulate(model, 100, seed=1, modes="1-50:normal,51-100:fan")
    >>> [model.modes[k] for k in jmlgdsl.smooth(model, sim.y, sim.u, lag=5).map_modes[[0, 99]]]
    ['normal', 'fan']
    >>> from jmlgdsl.data import iter_rows, open_source
    >>> with open_source("examples/dryer_seq1.csv") as source:  # rows as they come: a file, a pipe, a bus
    ...     done = jmlgdsl.diagnose(model, iter_rows(source, model, source.name))  # filter, alarms, summary
    >>> model.modes[done.summary.current], done.alarms.raised, round(done.summary.diagnosis_error, 2)
    ('fan', 3, 1.0)

`diagnose` is `jmlgdsl run` as a call; the diagnosis as one object fed row by row, with sinks and
checkpoints, is `jmlgdsl.diagnosis`; learning a bank from experiments `jmlgdsl.learn`; fitting a
spec's unknowns `jmlgdsl.fit`.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from .errors import DataError, Diagnostic, JmlgError, SpecError, SpecWarning
from .model import Model, ModelError
from .version import VERSION as __version__

# Heavier parts load on first use, so `import jmlgdsl` and `jmlgdsl check` stay quick.
_LAZY = {
    "filter": "jmlgdsl.infer",
    "smooth": "jmlgdsl.infer",
    "Filter": "jmlgdsl.infer",
    "Result": "jmlgdsl.infer",
    "diagnose": "jmlgdsl.diagnosis",
    "simulate": "jmlgdsl.simulation.linear",
    "simulate_nonlinear": "jmlgdsl.simulation.nonlinear",
    "fit": "jmlgdsl.fitting",
    "read_csv": "jmlgdsl.data",
}


def load(path) -> Model:
    """Load a plant: a .jmlg spec is parsed, checked and compiled; a .json/.npz model file is read.

    Raises SpecError (with every located diagnostic) for a bad spec; warnings are issued as SpecWarning.
    A .mat file (written for Matlab) is refused by name rather than read as a spec.
    """
    path = Path(path)
    if path.suffix.lower() == ".mat":
        raise ModelError(f"{path}: .mat cannot be read back; use .json or .npz (jmlgdsl compile SPEC -o FILE.json)")
    if path.suffix.lower() in (".json", ".npz"):
        return Model.read(path)
    from .compile.lower import compile_file

    return compile_file(path)


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'jmlgdsl' has no attribute {name!r}")


__all__ = ["load", "Model", "ModelError", "SpecError", "SpecWarning", "DataError", "JmlgError",
           "Diagnostic", *_LAZY]
