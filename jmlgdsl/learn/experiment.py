"""One identification experiment: the outputs and inputs recorded in one mode, read from a CSV file
whose header names the columns (extra columns such as time are ignored)."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError


@dataclass(frozen=True)
class Experiment:
    """Outputs y (T, ny) with NaN where not measured, inputs u (T, nu), and where they came from."""

    y: np.ndarray
    u: np.ndarray
    source: str = "<data>"


def read_experiment(path, inputs, outputs, input_defaults=None) -> Experiment:
    """Read the named columns; an absent input column takes its default, an empty output cell is NaN."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise DataError(f"{path}: cannot read: {exc.strerror}") from None
    if not rows:
        raise DataError(f"{path}: empty file")
    header = [h.strip() for h in rows[0]]
    defaults = np.full(len(inputs), np.nan) if input_defaults is None else np.asarray(input_defaults, float)
    for name in outputs:
        if name not in header:
            raise DataError(f"{path}:1: no column {name!r} for output {name}; columns are {', '.join(header)}")
    for name, d in zip(inputs, defaults):
        if name not in header and np.isnan(d):
            raise DataError(f"{path}:1: no column {name!r} for input {name} and it has no default")
    body = rows[1:]
    y = np.array([[_cell(path, i + 2, row, header, name, missing_ok=True) for name in outputs]
                  for i, row in enumerate(body)]).reshape(len(body), len(outputs))
    u = np.array([[_cell(path, i + 2, row, header, name, missing_ok=False) if name in header else d
                   for name, d in zip(inputs, defaults)] for i, row in enumerate(body)]).reshape(len(body), len(inputs))
    if len(body) < 2:
        raise DataError(f"{path}: an experiment needs at least two rows of data")
    return Experiment(y=y, u=u, source=str(path))


def _cell(path, line, row, header, name, missing_ok):
    j = header.index(name)
    text = row[j].strip() if j < len(row) else ""
    if text == "" or text.lower() == "nan":
        if missing_ok:
            return np.nan
        raise DataError(f"{path}:{line}: input {name} has no value")
    try:
        return float(text)
    except ValueError:
        raise DataError(f"{path}:{line}: {name} is not a number: {text!r}") from None
