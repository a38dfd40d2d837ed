"""A check on the first rows of a diagnosis: an output whose residuals are orders of magnitude beyond
the model's measurement noise is most often a column in another unit than the spec's."""

from __future__ import annotations

import warnings

import numpy as np

from ..data import DataWarning


class ScaleCheck:
    """Warns, once, about an output whose residuals over the first `rows` steps are typically more
    than `factor` times the model's one-step noise: the measurement noise and the process noise the
    output reads (C Q C' + R, averaged over the modes). A bank learned as regressions puts nearly
    all of it in the process noise and the measurement noise at the sensors' rounding, so the
    measurement noise alone would take every sensor for one in the wrong unit."""

    rows, factor = 50, 100.0

    def __init__(self, model):
        self.model = model
        noise = model.C @ model.Q @ np.swapaxes(model.C, 1, 2) + model.R
        self.sd = np.sqrt(np.diagonal(noise, axis1=1, axis2=2).mean(axis=0))  # (ny,)
        self.seen, self.done = [], False

    def add(self, step):
        """Note one step's residuals in units of the noise; judge once `rows` steps are in."""
        self.add_rows(step.residual[np.newaxis])

    def add_rows(self, residuals):
        """Note the residuals (steps, ny) of steps in turn (a fleet's whole record at once), as `add`
        notes them one step at a time; judge once `rows` steps are in."""
        if not self.done:
            self.seen.extend(np.abs(residuals[:self.rows - len(self.seen)]) / self.sd)
            if len(self.seen) == self.rows:
                self.finish()

    def finish(self):
        """Judge now (also at the end of a record shorter than the check's rows); only once."""
        if self.done or not self.seen:
            return
        self.done = True
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an output never measured: all NaN
            typical = np.nanmedian(np.array(self.seen), axis=0)
        self.seen = []  # judged: a long-running diagnosis (and its checkpoint) need not carry them
        for name, size in zip(self.model.outputs, typical):
            if size > self.factor:
                unit = self.model.engineering_units.get(name)
                warnings.warn(DataWarning(
                    f"output {name!r}: its residuals are about {size:.3g} times the model's noise; "
                    f"is the column in the spec's unit{f' [{unit}]' if unit else ''}?"), stacklevel=2)
