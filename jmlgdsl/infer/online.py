"""The filtering front end: `Filter` steps through data on-line; `filter` runs it over a whole array.

Both are one code path: the batch call is a loop of `Filter.step`.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import DataError
from . import kalman
from .engine import FilterError, Resampler, generator
from .imm import IMM
from .pf import BootstrapPF
from .rbpf import RBPF, Exact, FearnheadCliffordRBPF, LookAheadRBPF
from .resample import SCHEMES
from .result import Result, Step

ALGORITHMS = {"pf": BootstrapPF, "rbpf": RBPF, "la-rbpf": LookAheadRBPF, "fc-rbpf": FearnheadCliffordRBPF,
              "imm": IMM, "exact": Exact}
DEFAULT_ALGORITHM = "imm"  # the lowest error per unit of time on every published plant (docs/filters.md)
# Readings this large (or infinite) cannot be measurements: their squares would overflow the
# Kalman arithmetic, so they are treated as not measured.
MAX_READING = 1e100


class Filter:
    """On-line mode and state estimation: feed one observation at a time with `step(y_t, u_t)`.

    `particles=None` takes the algorithm's default; `seed` (or an explicit numpy Generator `rng`)
    makes runs reproducible bit for bit. Resampling happens when the effective sample size falls
    below `ess_threshold` times the particle count (1, the default, resamples at every step).
    """

    def __init__(self, model, algorithm=DEFAULT_ALGORITHM, particles=None, seed=None,
                 resampling="systematic", ess_threshold=1.0, rng=None):
        if algorithm not in ALGORITHMS:
            raise FilterError(f"unknown filter {algorithm!r}; choose from {', '.join(ALGORITHMS)}")
        if resampling not in SCHEMES:
            raise FilterError(f"unknown resampling scheme {resampling!r}; choose from {', '.join(SCHEMES)}")
        engine = ALGORITHMS[algorithm]
        if particles is None or engine.default_particles is None:  # imm and exact have no particles
            particles = engine.default_particles
        elif isinstance(particles, bool) or not isinstance(particles, (int, np.integer)) or particles < 1:
            raise FilterError(f"the number of particles must be a positive whole number, got {particles!r}")
        self.model, self.algorithm, self.particles = model, algorithm, particles
        self.rng = generator(seed, rng)
        resampler = Resampler(SCHEMES[resampling], particles, self.rng, ess_threshold) if particles else None
        self.engine = engine(model, particles, self.rng, resampler)
        self.t = 0
        self.loglik = 0.0

    def step(self, y, u=None) -> Step:
        """Advance one time step with outputs y (ny,) and inputs u (nu,).

        NaN outputs are not measured (as are infinite ones or any beyond MAX_READING in size);
        NaN inputs (all of them with u=None) take the spec's defaults.
        """
        model, t = self.model, self.t + 1
        y = _vector(y, model.outputs, "outputs", t)
        y = np.where(np.abs(y) < MAX_READING, y, np.nan)  # NaN compares False: stays NaN
        u = np.full(model.nu, np.nan) if u is None else _vector(u, model.inputs, "inputs", t)
        u = np.where(np.isnan(u), model.input_defaults, u)
        if not np.isfinite(u).all():
            bad = [n for n, v in zip(model.inputs, u) if not np.isfinite(v)]
            raise DataError(f"t={t}: no value and no default for input {', '.join(bad)}")
        mask = kalman.observed(y)
        est = self.engine.step(y, mask, u)
        self.t = t
        self.loglik += est.loglik
        return Step(self.t, est.mode_posterior, est.state_mean, est.state_cov, est.y_pred,
                    y - est.y_pred, est.loglik, est.ess)


def _vector(values, names, what, t):
    """One step's values as a float vector (len(names),); a DataError naming the columns otherwise."""
    v = np.asarray(values, dtype=float)
    if v.size != len(names):
        raise DataError(f"t={t}: {v.size} {what} given, expected {len(names)} ({', '.join(names)})")
    return v.reshape(len(names))


def filter(model, y, u=None, *, algorithm=DEFAULT_ALGORITHM, particles=None, seed=None,
           resampling="systematic", ess_threshold=1.0, rng=None) -> Result:
    """Filter a whole sequence: y (T, ny) with NaN for unmeasured entries, u (T, nu) or None for defaults."""
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None] if model.ny == 1 else y[None]
    if y.ndim != 2 or y.shape[1] != model.ny:
        raise DataError(f"y must have shape (T, {model.ny}) for outputs {', '.join(model.outputs)}; got {y.shape}")
    T = len(y)
    u = model.resolve_inputs(u, T)
    f = Filter(model, algorithm, particles, seed, resampling, ess_threshold, rng)
    start = time.perf_counter()
    steps = [f.step(y[t], u[t]) for t in range(T)]
    return Result.from_steps(model, algorithm, f.particles, steps, time.perf_counter() - start)
