"""What the recordings can resolve: each sensor's resolution, the noise floor it implies, and the
outputs of a mode's data that move by less than it.

A recorded value is the true one rounded to the sensor's resolution r, so it carries at least the
rounding error, uniform over one step: variance r^2 / 12. A sensor that is constant in one mode's
recording (a stuck valve or sensor) or two sensors that move together exactly (a proportional control
loop) are facts about the plant, not errors; what they cannot have is a noise covariance below that
rounding. Learning therefore floors every mode's measurement noise covariance at diag(r^2 / 12) and
leaves out, in least squares, the directions of the regressors that move no more than rounding.

The resolution of a sensor is read from all its recordings, every mode's: the smallest step between
two distinct values it took (a column rounded to 0.1 shows steps of 0.1), but no finer than
RELATIVE of its spread, since the smallest step between continuous values only says how many
samples there are.
"""

from __future__ import annotations

import numpy as np

#: No sensor is taken to resolve finer than this fraction of its standard deviation over all its
#: recordings (a 12-bit converter over four standard deviations). The noise floor it gives, a
#: variance of 1e-7 / 12 of the sensor's own, is far below any noise a fit of a few thousand samples
#: can tell from zero, and keeps the filters' covariances well conditioned.
RELATIVE = 1e-3

#: The variance of rounding, in steps^2: a direction that moves less is not resolved by the data.
ROUNDING = 1 / 12


def resolution(x) -> np.ndarray:
    """Per column of x (T, n), or of several such arrays stacked, NaN where not measured: the
    smallest step between distinct values, at least RELATIVE of the column's standard deviation
    (of its magnitude when it never moves; RELATIVE itself when it is always zero)."""
    x = np.vstack(x) if isinstance(x, (list, tuple)) else np.asarray(x, float)
    out = np.empty(x.shape[1])
    for j, column in enumerate(x.T):
        seen = column[np.isfinite(column)]
        values = np.unique(seen)
        if len(values) > 1:
            out[j] = max(np.diff(values).min(), RELATIVE * seen.std())
        else:
            out[j] = RELATIVE * (abs(values[0]) if len(values) and values[0] else 1.0)
    return out


def noise_floor(r) -> np.ndarray:
    """The variance of rounding to resolution r: r^2 / 12 (uniform over one step)."""
    return ROUNDING * np.asarray(r, float) ** 2


def at_least(S, floor) -> np.ndarray:
    """The symmetric matrix S raised to at least diag(floor) in every direction: the eigenvalues of
    S scaled by the floor's square root (D^-1/2 S D^-1/2) raised to 1. Directions where S already
    exceeds the floor are untouched; a singular S (a constant output, collinear outputs) becomes
    positive definite by exactly the rounding the data cannot resolve."""
    d = np.sqrt(np.asarray(floor, float))
    scaled = np.asarray(S, float) / np.outer(d, d)
    w, V = np.linalg.eigh(0.5 * (scaled + scaled.T))
    raised = (V * np.maximum(w, 1.0)) @ V.T * np.outer(d, d)
    return 0.5 * (raised + raised.T)


def unresolved(runs, r) -> list[tuple[int, ...]]:
    """Groups of outputs whose joint movement in a mode's runs [y (T, ny), ...] is no more than
    rounding to their resolution r (ny,) would give: a single output (constant: a stuck sensor or
    valve) or outputs that some combination of them holds fixed (collinear sensors).

    Each run is centred on its own (runs may sit at different levels) and every output measured in
    its resolution's steps; a direction of the covariance with variance below ROUNDING is
    unresolved, and outputs belong to one group when the projection onto those directions links
    them (|P_ij| >= 0.01; an output with P_jj < 0.01 takes no real part in them).
    """
    rows = [y[np.isfinite(y).all(axis=1)] for y in runs]
    z = np.vstack([(y - y.mean(axis=0)) / r for y in rows if len(y)])
    w, V = np.linalg.eigh(z.T @ z / max(len(z), 1))
    null = V[:, w < ROUNDING]
    linked = np.abs(null @ null.T) >= 0.01
    groups, seen = [], set()
    for j in range(len(r)):
        if j in seen or not linked[j, j]:
            continue
        group, todo = set(), [j]
        while todo:
            i = todo.pop()
            if i not in group:
                group.add(i)
                todo.extend(np.flatnonzero(linked[i]))
        seen |= group
        groups.append(tuple(sorted(int(i) for i in group)))
    return groups
