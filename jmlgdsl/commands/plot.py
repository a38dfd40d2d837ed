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
    p.add_argument("-o", "--output", required=True, help="figure to write (.png, .pdf, .svg, .eps or .ps)")
    p.set_defaults(func=main)


def true_modes(path, modes, steps):
    """Mode indices from the 'mode' column of a data file, checked against the run's modes and length."""
    import numpy as np

    from ..data import Columns, read_csv
    from ..names import plural
    from ..errors import DataError

    data = read_csv(path, Columns(modes=tuple(modes)), outputs=False)
    if data.modes is None:
        raise DataError(f"{path}: no 'mode' column with the true mode names")
    if (data.modes < 0).any():
        raise DataError(f"{path}: data row {int(np.argmax(data.modes < 0)) + 1} has no true mode in its 'mode' cell")
    if len(data.modes) != steps:
        raise DataError(f"{path} has {plural(len(data.modes), 'row')} but the run has {plural(steps, 'step')}")
    return data.modes


def main(args) -> int:
    """Run the command on parsed arguments; returns the exit status."""
    import csv

    from ..errors import DataError
    from ..infer.table import read_table
    from ..output import FIGURE, check_file, replacing
    from ..diagnosis.figure import diagnosis_figure

    check_file(args.output, inputs=[args.result, args.truth], suffixes=FIGURE)
    try:
        table = read_table(args.result)
    except csv.Error as exc:  # a cell beyond the csv module's field limit
        raise DataError(f"{args.result}: not a result table ({exc})") from None
    timed = table.time is not None
    truth = None if args.truth is None else true_modes(args.truth, table.modes, table.T)
    with replacing(args.output) as temporary:
        diagnosis_figure(temporary, table.modes, table.mode_posterior, table.time if timed else table.t,
                         table.y_pred + table.residuals, table.y_pred, table.outputs, true_modes=truth,
                         time_label="time (as in the data)" if timed else "time step t", title=args.title,
                     given=table.given)
    print(f"wrote {args.output}")
    return 0
