"""Learning a mode bank from experiments: PRBS design (prbs), step-test FOPDT fits (steptest), ARX
least squares for any number of outputs (arx), EM for the state-space model (em), the state basis
every mode of a bank shares and EM inside it (basis), validation (validate), the per-mode pipeline
and bank assembly (bank), the spec writer (writer) and figures (figures). `learn` runs them all,
from experiment files to a spec, as `jmlgdsl learn` does (learned):

    >>> import jmlgdsl
    >>> from jmlgdsl.learn import learn
    >>> modes = ("normal", "fan", "grill", "fan_grill")
    >>> bank = learn({m: f"examples/learning/{m}.csv" for m in modes}, jmlgdsl.load("specs/dryer.jmlg"),
    ...              order=1, max_iter=5)
    >>> bank.model.modes, bank.model.states
    (('normal', 'fan', 'grill', 'fan_grill'), ('temp_lag1',))
    >>> for line in bank.report().splitlines():
    ...     print(line.split("; measurement")[0])  # doctest: +NORMALIZE_WHITESPACE
    normal: ARX(1,1,0), EM 5 iterations (not converged: last gain 0.313, tolerance 0.0262, about 0.179
        more to come, 0.036 per free parameter), log-lik 1100.98; poles 0.9682; gain 1.959
    fan: ARX(1,1,0), EM 5 iterations (not converged: last gain 0.253, tolerance 0.0241, about 0.128 more
        to come, 0.026 per free parameter), log-lik 1111.18; poles 0.9613; gain 1.447
    grill: ARX(1,1,0), EM 5 iterations (not converged: last gain 0.219, tolerance 0.0266, about 0.107
        more to come, 0.021 per free parameter), log-lik 1115.63; poles 0.976; gain 2.301
    fan_grill: ARX(1,1,0), EM 5 iterations (not converged: last gain 0.218, tolerance 0.0239, about
        0.0993 more to come, 0.02 per free parameter), log-lik 1112.48; poles 0.9699; gain 1.598
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "dryer_learned.jmlg")
    >>> bank.write(path)  # whole or not at all; bank.write_figures(folder) draws each mode's checks
    >>> jmlgdsl.load(path).modes == bank.model.modes
    True
"""

__all__ = ["learn", "LearnedBank", "experiments_of", "mode_files"]


def __getattr__(name):
    """The names of `learned`, imported when first used: `jmlgdsl prbs` needs none of the fitting."""
    if name in __all__:
        from . import learned

        return getattr(learned, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
