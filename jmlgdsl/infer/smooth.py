"""Mode and state smoothing for the deterministic algorithms: off-line p(z_t | y_1:T) and fixed-lag
p(z_t | y_1:min(T, t+L)), with the matching mixture moments of x_t.

- `smooth_exact`: every mode history z_0..z_T is carried forward with its own Kalman filter, then
  smoothed backwards along its own Rauch-Tung-Striebel recursion; the ground truth, K^(T+1)
  histories, so only for short sequences.
- `smooth_imm`: an IMM forward pass followed by Kim's backward recursion (Kim 1994), which works
  on mode pairs (z_t, z_t+1) from the stored forward quantities alone. Kim's smoother was chosen
  over the two-filter IMM smoother of Helmick, Blair and Hoffman because it needs no backward
  filter: that one starts from a diffuse prior in information form and runs the dynamics
  backwards, which is awkward with the inputs, singular A and singular noise of compiled specs.
  Kim's pass is a few batched K x K small-matrix operations per step, the fixed-lag form
  batches every window into one pass, and lag 0 is the filter itself. Its approximation takes
  p(z_t | z_t+1, y_1:T) to be p(z_t | z_t+1, y_1:t): what later outputs say, through the state,
  about when a switch happened is lost. On the published plants that costs little (see the
  tests); on plants whose modes differ only in hidden dynamics it can cost much.

Inputs are arrays: y (T, ny) with NaN for unmeasured entries, u (T, nu) already resolved. Row t
(0-based) is time t+1; a missing output is left out of the update, never out of the prediction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import JmlgError
from ..gaussian import symmetrize
from ..names import plural
from . import kalman
from .engine import offsets
from .imm import IMM
from .kalman import transpose

# Exact smoothing keeps every history's Kalman statistics at every step: up to twice this many
# Gaussians in memory, and as many small Rauch-Tung-Striebel steps per smoothed row.
MAX_HISTORIES = 1_000_000
_LOG_FLOOR = np.finfo(float).min  # below every finite log-probability


class SmoothError(JmlgError, ValueError):
    """A smoother asked for something it cannot do (bad lag, too many mode histories, bad shapes)."""


@dataclass(frozen=True, eq=False)
class Smoothed:
    """Per-step smoothed estimates over t = 1..T (row 0 is t = 1)."""

    mode_posterior: np.ndarray  # (T, K) p(z_t = k | y_1:min(T, t+lag))
    state_mean: np.ndarray  # (T, nx) mixture mean of x_t given the same data
    state_cov: np.ndarray  # (T, nx, nx) mixture covariance


# ----------------------------------------------------------------------------- shared pieces
def _check(model, y, u, lag):
    """y and u as float arrays of the model's sizes, and the lag (None or a whole number >= 0)."""
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)
    if y.ndim != 2 or y.shape[1] != model.ny or u.shape != (len(y), model.nu):
        raise SmoothError(f"y must be (T, {model.ny}) and u (T, {model.nu}); got {y.shape} and {u.shape}")
    if not len(y):
        raise SmoothError("there is nothing to smooth: no time steps")
    if lag is not None and (isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 0):
        raise SmoothError(f"the lag must be None (off-line) or a whole number >= 0, got {lag!r}")
    return y, u


def _log_normalize(logw, axis=-1):
    """Log-weights shifted so that their exponentials sum to one along `axis` (logsumexp)."""
    return logw - np.logaddexp.reduce(logw, axis=axis, keepdims=True)


def _mixture(w, means, covs):
    """Moments of Gaussian mixtures: weights (..., n), means (..., n, nx), covs (..., n, nx, nx)."""
    mean = np.einsum("...n,...na->...a", w, means)
    d = means - mean[..., None, :]
    cov = np.einsum("...n,...nab->...ab", w, covs) + np.einsum("...n,...na,...nb->...ab", w, d, d)
    return mean, symmetrize(cov)


def _rts_gain(Sig_f, A, Sig_p):
    """Smoother gain Sig_f A' Sig_p^+ (pseudo-inverse: a noiseless direction makes Sig_p singular)."""
    return Sig_f @ transpose(A) @ np.linalg.pinv(Sig_p, hermitian=True)


# ----------------------------------------------------------------------------- exact
@dataclass(frozen=True)
class _Level:
    """The K^(s+1) mode histories z_0..z_s after step s: history h ends in mode h % K and extends
    history h // K of step s-1. The prediction and gain link each history to that parent."""

    logw: np.ndarray  # (n,) log p(z_0:s, y_1:s)
    mean: np.ndarray  # (n, nx) filtered mean of x_s
    cov: np.ndarray  # (n, nx, nx)
    pred_mean: np.ndarray | None = None  # (n, nx) mean of x_s given y_1:s-1 (None at s = 0)
    pred_cov: np.ndarray | None = None
    gain: np.ndarray | None = None  # (n, nx, nx) Rauch-Tung-Striebel gain from x_s back to x_s-1


def smooth_exact(model, y, u, lag=None) -> Smoothed:
    """Exact smoothed mode posteriors and mixture state moments over all K^(T+1) mode histories.

    `lag=None` conditions every row on all the data; `lag=L` conditions row t on y_1:min(T, t+L)
    (lag 0 is the exact filter). Refused above MAX_HISTORIES histories.
    """
    y, u = _check(model, y, u, lag)
    T, K = len(y), model.K
    levels = _exact_forward(model, y, u)
    ends = np.full(T, T) if lag is None else np.minimum(T, np.arange(1, T + 1) + lag)
    post, mean, cov = np.empty((T, K)), np.empty((T, model.nx)), np.empty((T, model.nx, model.nx))
    for s in np.unique(ends):
        first = int(np.flatnonzero(ends == s)[0]) + 1
        for t, row in _exact_backward(K, levels, int(s), first):
            if ends[t - 1] == s:
                post[t - 1], mean[t - 1], cov[t - 1] = row
    return Smoothed(post, mean, cov)


def _exact_forward(model, y, u) -> list:
    """One _Level per step s = 0..T: every mode history with its Kalman filter."""
    K, T = model.K, len(y)
    if K ** (T + 1) > MAX_HISTORIES:
        raise SmoothError(f"exact smoothing of {plural(T, 'step')} would carry {K}^{T + 1} = {K ** (T + 1)} mode "
                          f"histories, more than the limit of {MAX_HISTORIES}; use imm for longer data")
    b, c = offsets(model, u)
    with np.errstate(divide="ignore"):
        levels = [_Level(np.log(model.p0), model.mu0, np.broadcast_to(model.Sigma0, (K,) + model.Sigma0.shape))]
    for s in range(T):
        levels.append(_exact_step(model, levels[-1], b[s], c[s], y[s]))
    return levels


def _exact_step(model, prev: _Level, b, c, y) -> _Level:
    """Extend every history by every mode: predict, update with the measured outputs, reweight."""
    n, K = len(prev.logw), model.K
    mu, Sig = prev.mean[:, None], prev.cov[:, None]
    mean, cov, ll, _, _ = kalman.step(mu, Sig, model.A, b, model.Q, model.C, c, model.R, y)
    pred_mean, pred_cov = kalman.predict(mu, Sig, model.A, b, model.Q)
    gain = _rts_gain(Sig, model.A, pred_cov)
    logw = prev.logw[:, None] + model.logP[np.arange(n) % K] + ll
    return _Level(*(a.reshape((n * K,) + a.shape[2:]) for a in (logw, mean, cov, pred_mean, pred_cov, gain)))


def _exact_backward(K, levels, s, first):
    """(t, (mode posterior, mean, cov)) given y_1:s for t = s down to `first`: each history's own
    Rauch-Tung-Striebel pass, mixed with the history weights."""
    top = levels[s]
    w = np.exp(_log_normalize(top.logw))
    h = np.arange(len(w))
    mean, cov = top.mean, top.cov
    for t in range(s, first - 1, -1):
        ancestor = h // K ** (s - t)  # index of each history's prefix z_0:t on level t
        yield t, (np.bincount(ancestor % K, weights=w, minlength=K), *_mixture(w, mean, cov))
        if t > first:
            level, parent = levels[t], levels[t - 1]
            J = level.gain[ancestor]
            mean = parent.mean[ancestor // K] + (J @ (mean - level.pred_mean[ancestor])[..., None])[..., 0]
            cov = symmetrize(parent.cov[ancestor // K] + J @ (cov - level.pred_cov[ancestor]) @ transpose(J))


# ----------------------------------------------------------------------------- imm
@dataclass(frozen=True)
class ModeGaussians:
    """Log mode probabilities and one Gaussian per mode, over any leading axes (steps, windows)."""

    log_w: np.ndarray  # (..., K)
    mean: np.ndarray  # (..., K, nx)
    cov: np.ndarray  # (..., K, nx, nx)

    @classmethod
    def empty(cls, T, model) -> "ModeGaussians":
        """Room for T steps of the model's modes, filled by `record`."""
        return cls(np.empty((T, model.K)), np.empty((T, model.K, model.nx)), np.empty((T, model.K, model.nx, model.nx)))

    def record(self, t, engine):
        """Keep an IMM engine's per-mode output after step t: log p(z_t | y_1:t) and filtered moments."""
        self.log_w[t], self.mean[t], self.cov[t] = engine.log_mu, engine.means, engine.covs

    def take(self, index) -> "ModeGaussians":
        return ModeGaussians(self.log_w[index], self.mean[index], self.cov[index])

    def then(self, later: "ModeGaussians") -> "ModeGaussians":
        """These steps followed by the later ones (along the leading axis)."""
        return ModeGaussians(*(np.concatenate(pair) for pair in
                                zip((self.log_w, self.mean, self.cov), (later.log_w, later.mean, later.cov))))


@dataclass(frozen=True)
class _Pairs:
    """Kim's quantities for the pairs (z_t = i, z_t+1 = j), over steps t = 0..T-2 (leading axis)."""

    log_pred: np.ndarray  # (..., K) log p(z_t+1 = j | y_1:t)
    pred_mean: np.ndarray  # (..., K, K, nx) A_j m_i + F_j u_t+1 + f_j
    gain: np.ndarray  # (..., K, K, nx, nx) Rauch-Tung-Striebel gain of the pair
    rest: np.ndarray  # (..., K, K, nx, nx) Sig_i - J Sig_pred J': the smoothed covariance less J Sig_t+1 J'

    def take(self, index) -> "_Pairs":
        return _Pairs(self.log_pred[index], self.pred_mean[index], self.gain[index], self.rest[index])


def smooth_imm(model, y, u, lag=None) -> Smoothed:
    """IMM filter, then Kim's backward pass: smoothed mode posteriors and mixture state moments.

    `lag=None` is the fixed-interval smoother: O(T K^2) Kalman-sized steps, and O(T K^2 nx^2) memory
    for the mode pairs' gains. `lag=L` runs the backward pass over the window t..min(T, t+L) of every
    row, all windows batched into L numpy steps: O(T L K^2) work. Lag 0 is the IMM filter.
    """
    y, u = _check(model, y, u, lag)
    engine, fwd = IMM(model), ModeGaussians.empty(len(y), model)
    for t in range(len(y)):
        engine.step(y[t], ~np.isnan(y[t]), u[t])
        fwd.record(t, engine)
    return kim_smooth(model, fwd, offsets(model, u)[0], lag)


def kim_smooth(model, fwd: ModeGaussians, b, lag=None) -> Smoothed:
    """Kim's backward pass (off-line, or over every row's window of `lag` rows) over the IMM filter's
    per-mode output `fwd` at every step, whose state offsets F u + f were b (T, K, nx)."""
    T = len(fwd.log_w)
    pairs = _kim_pairs(model, fwd, b)
    # Rows whose window reaches the last step see all the data: one off-line pass over them.
    first = 0 if lag is None else max(0, T - 1 - lag)
    smoothed = _kim_offline(model.logP, fwd, pairs, first)
    if first:  # the earlier rows: every window at once
        smoothed = _kim_windows(model.logP, fwd, pairs, np.arange(first) + lag, lag).then(smoothed)
    post = np.exp(_log_normalize(smoothed.log_w))
    mean, cov = _mixture(post, smoothed.mean, smoothed.cov)
    return Smoothed(post, mean, cov)


class KimPass:
    """How `smooth` smooths a whole record for imm: the filter's per-mode moments recorded at every
    step (`record`), then Kim's backward pass over them (`smoothed`), off-line or with a lag."""

    def __init__(self, model, T: int):
        self.fwd = ModeGaussians.empty(T, model)

    def record(self, t, engine):
        """Keep the engine's per-mode output after step t (0-based)."""
        self.fwd.record(t, engine)

    def smoothed(self, model, y, u, rejected, lag) -> Smoothed:
        """The smoothed rows of the record y (T, ny), u (T, nu) the filter stepped through."""
        return kim_smooth(model, self.fwd, offsets(model, u)[0], lag)


class HistoryPass:
    """How `smooth` smooths a whole record for exact: nothing kept while the filter steps, then every
    mode history smoothed over the readings the filter used (those it rejected as gross errors stay out)."""

    def __init__(self, model, T: int):
        pass

    def record(self, t, engine):
        """Nothing: the histories are carried again by `smooth_exact`."""

    def smoothed(self, model, y, u, rejected, lag) -> Smoothed:
        """The smoothed rows of the record y (T, ny), u (T, nu), rejected (T, ny) the filter stepped through."""
        return smooth_exact(model, np.where(rejected, np.nan, y), u, lag)


def _kim_pairs(model, fwd: ModeGaussians, b) -> _Pairs:
    """Every pair's one-step prediction from the filtered moments of mode i under mode j's dynamics,
    its smoother gain, and the predicted mode probabilities: all steps at once."""
    mu, Sig = fwd.mean[:-1, :, None], fwd.cov[:-1, :, None]
    pred_mean, pred_cov = kalman.predict(mu, Sig, model.A, b[1:, None], model.Q)
    gain = _rts_gain(Sig, model.A, pred_cov)
    rest = symmetrize(Sig - gain @ pred_cov @ transpose(gain))
    log_pred = np.logaddexp.reduce(fwd.log_w[:-1, :, None] + model.logP, axis=1)
    return _Pairs(log_pred, pred_mean, gain, rest)


def _kim_modes(logP, log_filt, log_pred, log_next):
    """Kim's mode recursion, batched over leading axes: log p(z_t | data) from log p(z_t+1 | data),
    and the backward transition p(z_t+1 = j | z_t = i, data) as a (..., K, K) array."""
    log_joint = log_filt[..., :, None] + logP + _log_ratio(log_next, log_pred)[..., None, :]
    log_w = np.logaddexp.reduce(log_joint, axis=-1)
    return log_w, np.exp(_log_ratio(log_joint, log_w[..., None]))


def _log_ratio(log_a, log_b):
    """log(a / b) where b = 0 implies a = 0: an impossible event stays impossible (-inf, not NaN)."""
    return log_a - np.maximum(log_b, _LOG_FLOOR)


def _kim_step(logP, filt: ModeGaussians, pairs: _Pairs, nxt: ModeGaussians) -> ModeGaussians:
    """One backward step of Kim's smoother, batched over leading axes: from the smoothed mode
    probabilities and per-mode moments at t+1 to those at t."""
    log_w, cond = _kim_modes(logP, filt.log_w, pairs.log_pred, nxt.log_w)
    dx = nxt.mean[..., None, :, :] - pairs.pred_mean
    means = filt.mean[..., :, None, :] + (pairs.gain @ dx[..., None])[..., 0]
    covs = pairs.rest + pairs.gain @ nxt.cov[..., None, :, :, :] @ transpose(pairs.gain)
    mean, cov = _mixture(cond, means, covs)
    return ModeGaussians(log_w, mean, cov)


def _kim_offline(logP, fwd: ModeGaussians, pairs: _Pairs, first) -> ModeGaussians:
    """The fixed-interval backward pass from the last step down to step `first` (rows first..T-1).

    Kim's step is affine in the smoothed moments at t+1 once the mode recursion has fixed the
    backward transitions, so the modes are recursed first and everything else is batched over the
    steps, leaving two small products a step in the mean and covariance recursions."""
    filt, pairs = fwd.take(slice(first, None)), pairs.take(slice(first, None))
    n = len(filt.log_w)
    log_w, cond = filt.log_w.copy(), np.empty((n - 1,) + logP.shape)
    for t in range(n - 2, -1, -1):
        log_w[t], cond[t] = _kim_modes(logP, filt.log_w[t], pairs.log_pred[t], log_w[t + 1])
    CJ = cond[..., None, None] * pairs.gain  # (n-1, i, j, nx, nx)
    mean = filt.mean.copy()
    shift = filt.mean[:-1] - np.einsum("tijab,tijb->tia", CJ, pairs.pred_mean)
    for t in range(n - 2, -1, -1):
        mean[t] = shift[t] + np.einsum("ijab,jb->ia", CJ[t], mean[t + 1])
    d = (filt.mean[:-1, :, None] - mean[:-1, :, None]
         + (pairs.gain @ (mean[1:, None] - pairs.pred_mean)[..., None])[..., 0])  # pair mean - mode mean
    base = np.einsum("tij,tijab->tiab", cond, pairs.rest + d[..., :, None] * d[..., None, :])
    cov = filt.cov.copy()
    for t in range(n - 2, -1, -1):
        cov[t] = symmetrize(base[t] + np.einsum("ijab,jbc,ijdc->iad", CJ[t], cov[t + 1], pairs.gain[t]))
    return ModeGaussians(log_w, mean, cov)


def _kim_windows(logP, fwd: ModeGaussians, pairs: _Pairs, ends, lag) -> ModeGaussians:
    """Kim's backward pass over the windows ends-lag..ends, all batched: smoothed at ends - lag."""
    nxt = fwd.take(ends)
    for k in range(1, lag + 1):
        nxt = _kim_step(logP, fwd.take(ends - k), pairs.take(ends - k), nxt)
    return nxt
