"""Smoothing while filtering: the estimates of the last rows, revised by the rows that came after.

A `Filter` with a lag holds back its last records and asks its algorithm's window (the `window` of
its row in jmlgdsl.infer.algorithms) for their smoothed values. A window is made with the filter's
model, lag and engine at t = 0, takes the engine and the inputs after every step (`update`) and gives
the smoothed posteriors and state moments of the last rows (`rows`):

- `Genealogies` (particle filters and `exact`): a row's mode posterior is the weighted share of the
  current candidates whose ancestral line was in each mode then (Kitagawa's fixed-lag smoother).
  With a lag only the last `lag` modes of each line are kept; off-line every step's survivors are
  kept and traced back at the end. Resampling makes lines coalesce going back, so a long lag rests
  on few distinct ancestors (path degeneracy): docs/filters.md says how far a lag can go.
- `ImmWindow` (`imm`): Kim's backward pass over the last lag+1 steps of the IMM filter's per-mode
  moments, with smoothed state moments too.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from . import smooth
from .engine import offsets


class Genealogies:
    """Smoothed mode posteriors of a particle engine's last rows from its candidates' ancestral lines."""

    def __init__(self, model, lag: int | None, engine):
        self.K, self.nx, self.lag = model.K, model.nx, lag
        # Modes of each particle's line at t-1, t-2, ... (most recent first); off-line the steps' survivors.
        self.lines = np.repeat(engine.z[:, None], lag, axis=1) if lag is not None else None
        self.steps = []  # off-line: (parent, mode) of each step's survivors
        self.last = None

    def update(self, engine, u):
        """Take the genealogy of the engine's step (the inputs play no part)."""
        g = self.last = engine.genealogy
        if self.lag is None:
            self.steps.append((g.parent[g.kept], g.mode[g.kept]))
        else:
            self.previous = self.lines[g.parent]  # (candidates, lag): each candidate's line before this step
            self.lines = np.concatenate([g.mode[g.kept, None], self.previous[g.kept, :-1]], axis=1)

    def rows(self, n):
        """(posteriors (n, K), means, covariances) of the last n rows, oldest first; the particle
        smoothers give no state moments (NaN)."""
        g, K = self.last, self.K
        if self.lag is None:
            lines, particle = [g.mode], g.parent
            for parent, mode in reversed(self.steps[-n:-1]):  # the survivors of the earlier steps, newest first
                lines.append(mode[particle])
                particle = parent[particle]
            lines = np.stack(lines[::-1], axis=1)  # (candidates, n) oldest first
        else:
            lines = np.concatenate([self.previous[:, :n - 1][:, ::-1], g.mode[:, None]], axis=1)
        counts = np.bincount((np.arange(n) * K + lines).ravel(), weights=np.repeat(g.q, n), minlength=n * K)
        return counts.reshape(n, K), np.full((n, self.nx), np.nan), np.full((n, self.nx, self.nx), np.nan)


class ImmWindow:
    """Kim's smoother over the last lag+1 steps of an IMM engine (all steps off-line)."""

    def __init__(self, model, lag: int | None, engine):
        self.model = model  # (the engine's moments are read at each update: none are needed before)
        self.window = deque(maxlen=None if lag is None else lag + 1)  # (log_mu, means, covs, b) per step

    def update(self, engine, u):
        """Take the engine's per-mode moments after one step under inputs u (nu,), with that step's
        state offsets b (K, nx)."""
        b = offsets(self.model, u)[0]
        self.window.append((engine.log_mu.copy(), engine.means.copy(), engine.covs.copy(), b))

    def rows(self, n):
        """(posteriors (n, K), means (n, nx), covariances (n, nx, nx)) of the last n rows, oldest first."""
        log_w, mean, cov, b = (np.array(part) for part in zip(*list(self.window)[-n:]))
        out = smooth.kim_smooth(self.model, smooth.ModeGaussians(log_w, mean, cov), b)
        return out.mode_posterior, out.state_mean, out.state_cov
