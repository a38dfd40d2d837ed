"""`jmlgdsl plot RESULT.csv -o FIG.png`: the diagnosis figure of a `jmlgdsl run -o` table."""

from __future__ import annotations


def register(subparsers):
    p = subparsers.add_parser(
        "plot", help="draw the mode posterior, outputs and residuals of a run",
        description="Draw a run's table (written by 'jmlgdsl run ... -o RESULT.csv'): the most probable "
                    "mode over time, the probability of every mode as a heat map, measured vs "
                    "predicted outputs and the residuals. With --truth, the true modes of the data "
                    "file are drawn too.")
    p.add_argument("result", help="CSV written by 'jmlgdsl run -o'")
    p.add_argument("--truth", metavar="DATA.csv", help="the data file with a 'mode' column of true mode names")
    p.add_argument("--title", default="", help="figure title")
    p.add_argument("-o", "--output", required=True, help="PNG file to write")
    p.set_defaults(func=main)


def read_table(path):
    """(header, rows of cells) of a CSV file, with a DataError naming the file if it cannot be read."""
    import csv

    from ..data import open_source
    from ..errors import DataError

    with open_source(path) as stream:
        rows = [row for row in csv.reader(stream) if row]
    if len(rows) < 2:
        raise DataError(f"{path}: no data rows")
    return [h.strip() for h in rows[0]], rows[1:]


def column(path, header, rows, name, number=True):
    """One column by name: floats (empty cell = NaN) or text; DataError with the CSV line if not."""
    import numpy as np

    from ..errors import DataError

    if name not in header:
        raise DataError(f"{path}: missing column {name!r}; is this a table written by 'jmlgdsl run -o'?")
    i = header.index(name)
    cells = [row[i].strip() if i < len(row) else "" for row in rows]
    if not number:
        return cells
    values = []
    for line, text in enumerate(cells, start=2):
        try:
            values.append(float(text) if text else np.nan)
        except ValueError:
            raise DataError(f"{path}:{line}: column {name!r}: {text!r} is not a number") from None
    return np.array(values)


def true_modes(path, modes, steps):
    """Mode indices from the 'mode' column of a data file, checked against the run's modes and length."""
    import numpy as np

    from ..errors import DataError

    header, rows = read_table(path)
    names = column(path, header, rows, "mode", number=False)
    for line, name in enumerate(names, start=2):
        if name not in modes:
            raise DataError(f"{path}:{line}: column 'mode': unknown mode {name!r}; modes are {', '.join(modes)}")
    if len(names) != steps:
        raise DataError(f"{path} has {len(names)} rows but the run has {steps} steps")
    return np.array([modes.index(n) for n in names])


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    import numpy as np

    from ..errors import DataError
    from ..plots import diagnosis_figure

    path = args.result
    header, rows = read_table(path)
    start = header.index("map_mode") + 1 if "map_mode" in header else len(header)
    modes = []
    while start + len(modes) < len(header) and header[start + len(modes)].startswith("p_"):
        modes.append(header[start + len(modes)][2:])
    outputs = [h[:-len("_resid")] for h in header if h.endswith("_resid")]
    if not modes or not outputs:
        raise DataError(f"{path}: no map_mode, p_<mode> or <output>_resid columns; is this a table written by 'jmlgdsl run -o'?")
    posterior = np.column_stack([column(path, header, rows, f"p_{m}") for m in modes])
    y_pred = np.column_stack([column(path, header, rows, f"{o}_pred") for o in outputs])
    y = y_pred + np.column_stack([column(path, header, rows, f"{o}_resid") for o in outputs])
    timed = "time" in header
    time = column(path, header, rows, "time" if timed else "t")
    truth = None if args.truth is None else true_modes(args.truth, modes, len(rows))
    diagnosis_figure(args.output, modes, posterior, time, y, y_pred, outputs, true_modes=truth,
                     time_label="time (as in the data)" if timed else "time step t", title=args.title)
    print(f"wrote {args.output}")
    return 0
