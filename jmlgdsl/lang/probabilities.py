"""The mode chain: the transition matrix and the initial distribution, from a matrix literal, rules
(`stay p`, `name p`, `otherwise uniform`) or arrow rows, each row checked to be a probability vector."""

from __future__ import annotations

import numpy as np

from ..names import suggest
from . import syntax as S
from .evaluate import EvalError, UnknownName, evaluate_number, finite_numeric
from .diagnostics import Report

ROW_TOLERANCE = 1e-3  # a row further than this from summing to 1 is an error; nearer, it is renormalised


def otherwise_uniform(p: np.ndarray) -> np.ndarray:
    """`otherwise uniform`: the open (NaN) entries of a probability vector share evenly what the given
    ones leave (nothing when they already add up to 1 or more)."""
    rest = np.isnan(p)
    if not rest.any():
        return p
    return np.where(rest, max(1.0 - np.nansum(p), 0.0) / rest.sum(), p)


def _stand_in(shape) -> np.ndarray:
    """Uniform probabilities in place of a vector or matrix that could not be evaluated (reported
    where it is written): zeros or open entries there would add errors about its sums."""
    return np.full(shape, 1.0 / max(shape[-1], 1))


def _probability_value(expr: S.Expr, env, report: Report) -> float:
    """One probability, reported when outside [0, 1]."""
    value = evaluate_number(expr, env, report, what="a probability")
    if value < 0:
        report.error(f"a probability cannot be negative (got {value:g})", expr.pos)
    elif value > 1:
        report.error(f"a probability cannot exceed 1 (got {value:g})", expr.pos)
    return value


def _rule_vector(items, modes: list[str], env, report: Report, stay: int | None):
    """A probability vector from rules: `name p`, `stay p` (the row's own mode) and `otherwise uniform`;
    a uniform stand-in when a value cannot be evaluated (NaN, which otherwise marks an open entry)."""
    K = len(modes)
    p = np.full(K, np.nan)
    otherwise, failed = None, False
    for it in items:
        if it.kind == "otherwise":
            if it.name.text != "uniform":
                report.error(f"'otherwise' takes 'uniform', not {it.name.text!r}", it.name.pos)
            otherwise = it
            continue
        if it.kind == "stay":
            if stay is None:
                report.error("'stay' belongs in 'transitions'; name the mode here", it.pos)
                continue
            k = stay
        else:
            if it.name.text not in modes:
                report.error(f"unknown mode {it.name.text!r}{suggest(it.name.text, modes)}", it.name.pos)
                continue
            k = modes.index(it.name.text)
        if not np.isnan(p[k]):
            by_stay = " ('stay' gives it in its own row)" if stay == k else ""
            report.error(f"probability for {modes[k]!r} given twice{by_stay}", it.pos)
        p[k] = _probability_value(it.value, env, report)
        failed = failed or np.isnan(p[k])
    if failed:
        return _stand_in((K,)), None
    if otherwise is not None:
        return otherwise_uniform(p), otherwise.pos
    return p, None


def _normalise(vec, what: str, pos: S.Pos, report: Report):
    """Check a probability vector; renormalise a sum within 1e-3 of 1 with a warning."""
    total = float(vec.sum())
    if not np.isfinite(total) or (vec < 0).any():
        return vec
    if abs(total - 1.0) > ROW_TOLERANCE:
        hint = "" if total > 1 else "; add 'otherwise uniform' or the missing entries"
        report.error(f"{what} sums to {total:.6g}, not 1{hint}", pos)
        return vec
    if abs(total - 1.0) > 1e-12:
        report.warn(f"{what} sums to {total:.6g}; renormalised to 1", pos)
        vec = vec / total
    return vec


def transition_matrix(spec: S.Spec, modes: list[str], env, report: Report) -> np.ndarray:
    """The transition matrix (row = from-mode) from a matrix literal, rules or arrow rows; one mode may omit it."""
    K = len(modes)
    if not spec.transitions:
        if K > 1:
            report.error("missing 'transitions' (e.g. 'transitions stay 0.99, otherwise uniform')", S.Pos(1, 1))
        return np.eye(K)
    for extra in spec.transitions[1:]:
        report.error(f"'transitions' is given more than once (first at line {spec.transitions[0].pos.line})",
                     extra.pos)
    t = spec.transitions[0]
    if t.matrix is not None:
        P = _matrix_value(t.matrix, (K, K), "the transition matrix", env, report)
        row_pos = [row[0].pos if row else t.matrix.pos for row in t.matrix.args]
        rows = [(f"transition row {k + 1} ({modes[k]})", row_pos[k] if k < len(row_pos) else t.matrix.pos)
                for k in range(K)]
    elif t.rules:
        P = np.zeros((K, K))
        for k in range(K):
            P[k], _ = _rule_vector(t.rules, modes, env, report, stay=k)
        if np.isnan(P).any():
            report.error("transition rules leave entries open: end with 'otherwise uniform'", t.pos)
            P = np.nan_to_num(P)
        rows = [(f"transition row {k + 1} ({modes[k]})", t.pos) for k in range(K)]
    else:
        P = np.eye(K)
        rows = [(f"transition row {k + 1} ({modes[k]})", t.pos) for k in range(K)]
        seen = {}
        for name, items in t.arrows:
            if name.text not in modes:
                report.error(f"unknown mode {name.text!r}{suggest(name.text, modes)}", name.pos)
                continue
            k = modes.index(name.text)
            if k in seen:
                report.error(f"transitions from {name.text!r} already given at line {seen[k]}", name.pos)
            seen[k] = name.pos.line
            row, otherwise = _rule_vector(items, modes, env, report, stay=k)
            if otherwise is None and np.isnan(row[k]):
                row[k] = 1.0 - np.nansum(row)  # the remaining mass stays in the mode
                if row[k] < -ROW_TOLERANCE:
                    report.error(f"transitions out of {name.text!r} add up to {np.nansum(row[np.arange(K) != k]):.6g} > 1",
                                 name.pos)
                row[k] = max(row[k], 0.0)
            P[k] = np.nan_to_num(row)
            rows[k] = (f"transition row {k + 1} ({name.text})", name.pos)
    if P.shape == (K, K):
        for k in range(K):
            P[k] = _normalise(P[k], rows[k][0], rows[k][1], report)
    return P


def initial_distribution(spec: S.Spec, modes: list[str], env, report: Report) -> np.ndarray:
    """The prior p0 over modes from a vector literal or rules; uniform when not given."""
    uniform = np.full(len(modes), 1.0 / max(len(modes), 1))
    if not spec.initial:
        return uniform
    for extra in spec.initial[1:]:
        report.error(f"'initial' is given more than once (first at line {spec.initial[0].pos.line})", extra.pos)
    t = spec.initial[0]
    if t.matrix is not None:
        p0 = _matrix_value(t.matrix, uniform.shape, "the initial distribution", env, report)
    elif t.arrows:
        report.error("arrows ('a -> b p') belong in 'transitions'; write 'initial a p, otherwise uniform'", t.pos)
        return uniform
    else:
        p0, _ = _rule_vector(t.rules, modes, env, report, stay=None)
        p0 = np.nan_to_num(p0)
    return _normalise(p0, "the initial distribution", t.pos, report)


def _matrix_value(expr: S.Expr, shape, what: str, env, report: Report) -> np.ndarray:
    """A numeric vector/matrix of a required shape (a row or column is accepted for a vector); a
    uniform stand-in when it cannot be evaluated or has another shape."""
    def lookup(node):
        if node.args[0] not in env:
            raise UnknownName(f"unknown name {node.args[0]!r}{suggest(node.args[0], env)}", node)
        return env[node.args[0]]

    try:
        value = np.atleast_2d(np.asarray(finite_numeric(expr, lookup), float))
    except EvalError as exc:
        report.error(str(exc), exc.node.pos)
        return _stand_in(shape)
    if len(shape) == 1 and 1 in value.shape:
        value = value.ravel()
    if value.shape != tuple(shape):
        report.error(f"{what} must be {' x '.join(map(str, shape))} for {shape[0]} modes, "
                     f"got {' x '.join(map(str, value.shape))}", expr.pos)
        return _stand_in(shape)
    for bad in zip(*np.nonzero(value < 0)):
        report.error(f"{what} has a negative entry {value[bad]:g}", expr.pos)
        break
    return value
