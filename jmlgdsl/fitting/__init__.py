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
"""

from __future__ import annotations

from pathlib import Path

from ..data import Data, read_csv
from ..infer.algorithms import ALGORITHMS
from ..infer.engine import FilterError
from ..lang.parse import parse_file
from ..lang.syntax import Spec
from .estimate import Fit, maximise
from .family import Family, FitError
from .rewrite import fitted_text

__all__ = ["fit", "Fit", "Family", "FitError"]


def fit(spec, data, *, algorithm: str = "imm", samples: int = 0, starts: int = 1, seed=None,
        label_rounds: bool = True, progress=None) -> Fit:
    """Fit a spec's unknowns to data.

    spec: a .jmlg path or a parsed Spec. data: a CSV path, a jmlgdsl.data.Data, or a list of them
    (several recordings of the same plant). Rows whose every `mode` cell is filled give an exact
    likelihood; other recordings use the filter's (`algorithm`, IMM by default). `samples` > 0 adds
    posterior draws by random-walk Metropolis; `starts` > 1 also starts the search from starts - 1 draws
    of the priors and keeps the highest peak (both seeded by `seed`). Where some data are unlabelled, each
    start first goes through rounds of labelling them by their most probable modes (`label_rounds`
    False skips them: the search climbs the filter's likelihood from the start itself). The returned Fit has the estimates,
    standard errors, the fitted Model, `warnings` where the fit cannot be trusted (it did not converge,
    or its curvature is noise), and `text`, the spec rewritten with the fitted values and those warnings."""
    if samples < 0 or starts < 1:
        raise FitError(f"samples must be 0 or more and starts 1 or more, got {samples} and {starts}")
    if algorithm not in ALGORITHMS:
        raise FilterError(f"unknown filter {algorithm!r}; choose from {', '.join(ALGORITHMS)}")
    spec = spec if isinstance(spec, Spec) else parse_file(spec)
    family = Family(spec)
    columns = family.model(family.medians())
    recordings = [d if isinstance(d, Data) else read_csv(d, columns)
                  for d in (data if isinstance(data, (list, tuple)) else [data])]
    if not recordings:
        raise FitError("no data to fit to")
    result = maximise(family, recordings, algorithm, samples, seed, progress, starts, label_rounds)
    sources = ", ".join(Path(d.source).name for d in recordings)
    header = "\n".join([f"Fitted by 'jmlgdsl fit' to {sources}: log-likelihood {result.loglik_start:.6g} "
                        f"at the priors' medians, {result.loglik:.6g} fitted."]
                       + [f"warning: {w}" for w in result.warnings])
    result.text = fitted_text(spec, family.unknowns, result.estimate, result.se, header)
    return result
