"""Model -> .jmlg text in the language's matrix form, with every number written repr-exact so that
writing a model and loading the text gives back the same arrays."""

from __future__ import annotations

import numpy as np

from ..lang.probabilities import otherwise_uniform
from ..model import Model, ModelError


def number(x) -> str:
    """Shortest text that reads back as exactly the float x (whole numbers without a decimal point)."""
    x = float(x)
    if x == 0:
        return "0"
    if x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


def matrix(M) -> str:
    """A matrix literal: entries separated by spaces, rows by '; ' (a vector is written as a column)."""
    M = np.asarray(M, float)
    if M.ndim == 1:
        M = M[:, None]
    return "[" + "; ".join(" ".join(number(v) for v in row) for row in M) + "]"


def _declaration(keyword, names, engineering_units, values=None) -> str:
    """An input/output declaration line: names with their [unit] and constant default where known."""
    items = []
    for i, name in enumerate(names):
        item = name + (f" [{engineering_units[name]}]" if name in engineering_units else "")
        if values is not None and not np.isnan(values[i]):
            item += f" = {number(values[i])}"
        items.append(item)
    return f"{keyword} " + ", ".join(items)


def _quoted(text: str) -> str:
    """A mode description as a one-line string literal (the language has no escapes)."""
    return '"' + " ".join(str(text).replace('"', "'").split()) + '"'


def _rest_uniform(values, keep) -> bool:
    """Whether `values` is exactly what "NAME values[keep], otherwise uniform" reads as."""
    given = np.where(np.arange(len(values)) == keep, values, np.nan)
    return len(values) > 1 and np.array_equal(otherwise_uniform(given), values)


def _initial(model: Model) -> str:
    """The prior: `NAME p, otherwise uniform` when it is exactly that, else a vector."""
    k = int(np.argmax(model.p0))
    if _rest_uniform(model.p0, k):
        return f"initial     {model.modes[k]} {number(model.p0[k])}, otherwise uniform"
    return f"initial     {matrix(model.p0[None])}"


def _transitions(model: Model) -> str:
    """The chain: `stay p, otherwise uniform` when it is exactly that, else the matrix."""
    stay = model.P[0, 0]
    if np.all(np.diag(model.P) == stay) and all(_rest_uniform(row, k) for k, row in enumerate(model.P)):
        return f"transitions stay {number(stay)}, otherwise uniform"
    return f"transitions {matrix(model.P)}"


def _mode_block(model: Model, k: int) -> list[str]:
    """Lines of mode k's matrix block; zero offsets and feedthrough are left out."""
    lines = [f"mode {model.modes[k]} {{", f"  A = {matrix(model.A[k])}"]
    if model.nu:
        lines.append(f"  F = {matrix(model.F[k])}")
    if model.f[k].any():
        lines.append(f"  f = {matrix(model.f[k])}")
    lines.append(f"  C = {matrix(model.C[k])}")
    if model.nu and model.G[k].any():
        lines.append(f"  G = {matrix(model.G[k])}")
    if model.g[k].any():
        lines.append(f"  g = {matrix(model.g[k])}")
    lines += [f"  B = {matrix(model.B[k])}", f"  D = {matrix(model.D[k])}", f"  x0 = {matrix(model.mu0[k])}", "}"]
    return lines


def write_spec(model: Model, header: str = "") -> str:
    """The .jmlg text of a model; `header` lines become comments at the top.

    The language gives each state an independent initial spread, so Sigma0 must be diagonal.
    """
    if np.count_nonzero(model.Sigma0 - np.diag(np.diag(model.Sigma0))):
        raise ModelError("the .jmlg language gives each state its own initial sd: Sigma0 must be diagonal")
    sd0 = np.sqrt(np.diag(model.Sigma0))
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines += [f"plant {model.name}", f"sample {number(model.dt)} s"]
    if model.nu:
        lines.append(_declaration("input ", model.inputs, model.engineering_units, model.input_defaults))
    lines.append(_declaration("output", model.outputs, model.engineering_units))
    lines.append("state  " + ", ".join(f"{s} sd {number(sd)}" for s, sd in zip(model.states, sd0)))
    lines.append("modes")
    for name in model.modes:
        text = model.descriptions.get(name)
        lines.append(f"  {name}" + (f"  {_quoted(text)}" if text else ""))
    lines += [_initial(model), _transitions(model)]
    for k in range(model.K):
        lines += [""] + _mode_block(model, k)
    return "\n".join(lines) + "\n"
