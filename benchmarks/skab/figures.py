"""Figures of a few SKAB files for docs/realdata.md: the sensors against the learned bank's one-step
predictions, P(mode) over time, the diagnosed and the true (labelled) mode, and the residuals.

    python benchmarks/skab/figures.py --data DIR [--results DIR] [FOLDER_NAME ...]

Uses the specs benchmarks/skab/run.py wrote (RESULTS/strict/<folder>_<name>.jmlg, with the a priori
noise scale 3 and stay 0.99) changed to the setting cross-validation chose for the file
(summary.json), and writes docs/figures/skab-<folder>_<name>.png.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import jmlgdsl
from jmlgdsl.diagnosis import figure as run_figure
from jmlgdsl.data import Columns, read_csv

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run import REPO, SENSORS, data_folder, results_parser  # noqa: E402

FIGURES = REPO / "docs" / "figures"


def main(argv=None) -> int:
    parser = results_parser(__doc__)
    parser.add_argument("files", nargs="*", default=["valve1_3", "valve2_1", "other_11"])
    args = parser.parse_args(argv)
    data = data_folder(parser, args.data)
    chosen = json.loads((args.results / "strict" / "summary.json").read_text())["chosen"]
    for stem in args.files:
        folder, name = stem.split("_", 1)
        recording = read_csv(data / folder / f"{name}.csv", Columns(outputs=SENSORS))
        setting = chosen[stem]
        text = (args.results / "strict" / f"{stem}.jmlg").read_text()
        text = text.replace("noise scale 3 }", f"noise scale {setting['scale']:g} }}")  # the a priori values
        text = text.replace("transitions stay 0.99,", f"transitions stay {setting['stay']:g},")
        with tempfile.NamedTemporaryFile("w", suffix=".jmlg", delete=False) as spec:
            spec.write(text)
        model = jmlgdsl.load(spec.name)
        Path(spec.name).unlink()
        result = jmlgdsl.filter(model, recording.y)
        path = FIGURES / f"skab-{stem}.png"
        run_figure.result_figure(result, path, true_modes=recording.anomaly,
                            title=f"SKAB {folder}/{name}.csv (true mode: the anomaly labels)")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
