"""Units with their own numbers: `jmlgdsl fit SPEC u1.csv u2.csv ... -o DIR/` fits each unit's spec
from its own recording, and `run ... --unit-specs DIR/` and `monitor --units ... --unit-specs DIR/`
diagnose each unit under its own spec.

- Three dryers of examples/fit/dryer_unit.jmlg whose settled temperatures sit at their own offsets
  (+1.5, -2, +0.5 degC): each unit's fit lands within 3 standard errors of its offset, DIR/UNIT.jmlg
  is a spec that loads and holds `# fitted offset = ...`, and DIR/units.csv lays the units' values and
  standard errors side by side. Fitted one process at a time or in parallel, the values are the same.
- `run` on the units' files with --unit-specs gives each unit, byte for byte, the table `run` writes
  for its file under its own spec alone; a unit without a spec in DIR takes SPEC and the command says
  so; a unit spec of another plant, a missing folder and one data file are refused by their messages.
- `monitor --units` with --unit-specs stores for each unit the table `run` writes under its spec, and
  its run records that spec; started again with other unit specs it is refused.
- Refusals of the per-unit fit: two files of one name, --jobs 0 (with a folder and without).
"""

import csv
import re
import sqlite3
from pathlib import Path

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.data import write_columns
from jmlgdsl.fitting import Family
from jmlgdsl.lang.parse import parse_file

TEMPLATE = "examples/fit/dryer_unit.jmlg"
OFFSETS = {"u1": 1.5, "u2": -2.0, "u3": 0.5}
SCHEDULE = "1-150:normal,151-260:fan,261-400:normal"


def unit_spec(offset) -> str:
    """The template with the unit's true offset written in."""
    return Path(TEMPLATE).read_text().replace("param offset ~ Normal(0, 3)", f"param offset = {offset!r}")


@pytest.fixture(scope="module")
def units(tmp_path_factory):
    """Each unit's labelled recording (data/UNIT.csv) and true spec (truth/UNIT.jmlg), and the per-unit
    fit of the template to the recordings (fitted/, fitted in parallel)."""
    root = tmp_path_factory.mktemp("units")
    family = Family(parse_file(TEMPLATE))
    for folder in ("data", "truth"):
        (root / folder).mkdir()
    for k, (unit, offset) in enumerate(OFFSETS.items()):
        model = family.model(np.array([offset]))
        sim = jmlgdsl.simulate(model, modes=SCHEDULE, seed=k)
        write_columns(root / "data" / f"{unit}.csv", {"time": np.arange(len(sim.y)), "temp": sim.y[:, 0],
                                                       "mode": [model.modes[z] for z in sim.modes]})
        (root / "truth" / f"{unit}.jmlg").write_text(unit_spec(offset))
    files = [str(root / "data" / f"{unit}.csv") for unit in OFFSETS]
    assert main(["fit", TEMPLATE, *files, "-o", f"{root / 'fitted'}/", "-q", "--jobs", "2"]) == 0
    return root, files


def test_each_unit_is_fitted_its_own_numbers(units, capsys):
    root, files = units
    with open(root / "fitted" / "units.csv") as stream:
        rows = {row["unit"]: row for row in csv.DictReader(stream)}
    assert list(rows) == list(OFFSETS)
    assert list(next(iter(rows.values()))) == ["unit", "offset", "offset_se", "loglik", "warnings"]
    for unit, offset in OFFSETS.items():
        estimate, se = float(rows[unit]["offset"]), float(rows[unit]["offset_se"])
        assert 0 < se < 0.2 and abs(estimate - offset) < 3 * se, unit
        assert rows[unit]["warnings"] == ""
        text = (root / "fitted" / f"{unit}.jmlg").read_text()
        assert f"# fitted offset = {estimate:.4g} ± {se:.2g}, prior Normal(0, 3)" in text
        assert jmlgdsl.load(root / "fitted" / f"{unit}.jmlg").modes == ("normal", "fan", "grill", "fan_grill")
    # one process at a time: the same values
    assert main(["fit", TEMPLATE, *files, "-o", f"{root / 'serial'}/", "-q", "--jobs", "1"]) == 0
    assert (root / "serial" / "units.csv").read_text() == (root / "fitted" / "units.csv").read_text()
    capsys.readouterr()


def run_table(spec, data, out):
    assert main(["run", str(spec), str(data), "-o", str(out)]) == 0
    return out.read_bytes()


def test_run_diagnoses_each_unit_under_its_own_spec(units, tmp_path, capsys):
    root, files = units
    assert main(["run", TEMPLATE, *files, "--unit-specs", str(root / "fitted"), "-o", str(tmp_path / "out")]) == 0
    out = capsys.readouterr()
    assert "unit specs: 3 of 3 units from" in out.err
    assert "(the units stepped together)" in out.out
    for unit in OFFSETS:
        alone = run_table(root / "fitted" / f"{unit}.jmlg", root / "data" / f"{unit}.csv", tmp_path / f"{unit}.csv")
        assert (tmp_path / "out" / f"{unit}.csv").read_bytes() == alone, unit
    # the shared spec on the same units: each unit's own spec is better on the units far from the design
    assert main(["run", TEMPLATE, *files]) == 0
    shared = [float(e) for e in re.findall(r"diagnosis error ([0-9.]+) %", capsys.readouterr().out)]
    assert main(["run", TEMPLATE, *files, "--unit-specs", str(root / "fitted")]) == 0
    own = [float(e) for e in re.findall(r"diagnosis error ([0-9.]+) %", capsys.readouterr().out)]
    assert own[1] < shared[1]  # u2, 2 degC below the design


def test_a_unit_without_a_spec_takes_the_plants(units, tmp_path, capsys):
    root, files = units
    partial = tmp_path / "partial"
    partial.mkdir()
    (partial / "u1.jmlg").write_text((root / "fitted" / "u1.jmlg").read_text())
    assert main(["run", TEMPLATE, *files, "--unit-specs", str(partial), "-o", str(tmp_path / "out")]) == 0
    assert f"unit specs: 1 of 3 units from {partial}; u2, u3 with {TEMPLATE}" in capsys.readouterr().err
    assert (tmp_path / "out" / "u2.csv").read_bytes() == run_table(TEMPLATE, files[1], tmp_path / "u2.csv")


def test_unit_specs_refused(units, tmp_path, capsys):
    root, files = units
    other = tmp_path / "other"
    other.mkdir()
    (other / "u2.jmlg").write_text(Path("specs/cstr4.jmlg").read_text())
    assert main(["run", TEMPLATE, *files, "--unit-specs", str(other)]) == 2
    assert f"error: {other / 'u2.jmlg'}: unit u2's spec is not of the plant dryer_unit's shape" in capsys.readouterr().err
    assert main(["run", TEMPLATE, *files, "--unit-specs", str(tmp_path / "nosuch")]) == 2
    assert f"error: {tmp_path / 'nosuch'}: no such folder of unit specs" in capsys.readouterr().err
    assert main(["run", TEMPLATE, files[0], "--unit-specs", str(root / "fitted")]) == 2
    assert "--unit-specs gives each of several data files its unit's spec" in capsys.readouterr().err


def test_fit_units_refusals(units, tmp_path, capsys):
    root, files = units
    twin = tmp_path / "again"
    twin.mkdir()
    (twin / "u1.csv").write_text(Path(files[0]).read_text())
    assert main(["fit", TEMPLATE, files[0], str(twin / "u1.csv"), "-o", f"{tmp_path / 'out'}/"]) == 2
    assert "two data files would write the same unit spec u1.jmlg" in capsys.readouterr().err
    assert main(["fit", TEMPLATE, files[0], "-", "-o", f"{tmp_path / 'out'}/"]) == 2
    assert "standard input (-) has no name to give its unit spec; give files" in capsys.readouterr().err
    assert main(["fit", TEMPLATE, *files, "--jobs", "0", "-o", f"{tmp_path / 'out'}/"]) == 2
    assert "--jobs must be 1 or more, got 0" in capsys.readouterr().err
    assert main(["fit", TEMPLATE, files[0], "--jobs", "0", "-o", str(tmp_path / "one.jmlg")]) == 2
    assert "--jobs must be 1 or more, got 0" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_monitor_diagnoses_each_unit_under_its_own_spec(units, tmp_path, capsys):
    root, files = units
    store = str(tmp_path / "fleet.db")
    source = str(root / "data" / "{unit}.csv")
    command = ["monitor", TEMPLATE, "--source", source, "--units", "u1..u3", "--store", store, "--no-follow"]
    assert main([*command, "--unit-specs", str(root / "fitted")]) == 0
    assert "monitor: unit specs for 3 of 3 units from" in capsys.readouterr().err
    for unit in OFFSETS:
        assert main(["export", store, "--unit", unit, "-o", str(tmp_path / f"{unit}-export.csv")]) == 0
        alone = run_table(root / "fitted" / f"{unit}.jmlg", root / "data" / f"{unit}.csv", tmp_path / f"{unit}.csv")
        assert (tmp_path / f"{unit}-export.csv").read_bytes() == alone, unit
    with sqlite3.connect(store) as db:
        specs = dict(db.execute("SELECT unit, spec FROM run"))
    assert specs["u2"] == (root / "fitted" / "u2.jmlg").read_text()
    capsys.readouterr()
    # again with the true specs: another model for every unit, refused
    assert main([*command, "--unit-specs", str(root / "truth")]) == 2
    assert "holds a run of unit u1 of another model" in capsys.readouterr().err
