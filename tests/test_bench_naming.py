"""bench's naming scores: each faulty row named, while its alarm is up, by its most probable
non-healthy mode; the runs' counts pooled by adding them, then reported as `run --name` reports them."""

import csv

import numpy as np
import pytest
from infer_models import dryer

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.data import write_columns
from jmlgdsl.diagnosis.metrics import naming_counts
from jmlgdsl.diagnosis.report import naming_report
from jmlgdsl.simulation.linear import simulate
from jmlgdsl.studies import sweep

EVERY_MODE = "1-15:normal,16-30:fan,31-45:grill,46-60:fan_grill"  # 15 rows of each of the 3 faults


@pytest.fixture(scope="module")
def model():
    return dryer()


def named_by_hand(model, job, healthy):
    """The naming counts of one job, worked out from the filter's posterior without the sweep."""
    data = sweep.sequence_of(job)
    posterior = jmlgdsl.filter(model, data.y, data.u, algorithm=job.algorithm, particles=job.particles,
                               seed=job.filter_seed).mode_posterior
    faults = [k for k, m in enumerate(model.modes) if m not in healthy]
    true = np.array([faults.index(k) if k in faults else -1 for k in data.modes])
    alarm = posterior[:, faults].sum(axis=1) > 0.5
    return naming_counts(true, np.where(alarm, posterior[:, faults].argmax(axis=1), -1), len(faults))


@pytest.mark.parametrize("healthy, rows", [(None, [30, 30, 30]), (("normal", "fan"), [30, 30])])
def test_pooled_naming_counts_are_the_sum_of_each_runs_counts(model, healthy, rows):
    source = sweep.Simulated(None, EVERY_MODE)
    jobs = sweep.make_jobs(model, [source], ("imm", "la-rbpf"), (5,), runs=2, seed=3, healthy=healthy)
    summary = {(r["filter"], r["particles"]): r for r in sweep.summarise([sweep.run_job(j) for j in jobs])}
    for (algorithm, n), row in summary.items():
        mine = [named_by_hand(model, j, healthy or ("normal",)) for j in jobs
                if (j.algorithm, j.particles) == (algorithm, n)]
        np.testing.assert_array_equal(row["naming_counts"].confusion, (mine[0] + mine[1]).confusion)
        assert row["naming_counts"].rows.tolist() == rows
        assert row["naming"] == row["naming_counts"].overall


def test_the_report_gives_the_naming_table_and_the_best_settings_faults(model):
    source = sweep.Simulated(None, EVERY_MODE)
    records = sweep.sweep(model, [source], ("imm", "la-rbpf"), (1,), runs=2, seed=3, workers=1)
    summary = sweep.summarise(records)
    imm, pf = (next(r for r in summary if r["filter"] == f) for f in ("imm", "la-rbpf"))
    np.testing.assert_array_equal(imm["naming_counts"].confusion, [[28, 0, 0, 2], [2, 26, 0, 2], [0, 3, 26, 1]])
    np.testing.assert_array_equal(pf["naming_counts"].confusion, [[28, 0, 0, 2], [2, 14, 0, 14], [6, 4, 13, 7]])
    text = sweep.report(summary, ["fan", "grill", "fan_grill"])
    assert "| 1 |  | 61.1 |\n| — | 88.9 |  |" in text  # 55 and 80 of the 90 faulty rows named right
    assert ("Naming of the best setting (imm), 2 runs pooled:\n\n```\n"
            + "\n".join(naming_report(["fan", "grill", "fan_grill"], imm["naming_counts"])) + "\n```") in text
    assert "naming: 88.9 % of the faulty rows named right (80 of 90 rows)" in text
    assert "Naming" not in sweep.report(sweep.summarise([{**r, "naming_confusion": [[0] * 4] * 3} for r in records]))


def test_bench_command_reports_and_writes_the_naming(model, tmp_path, capsys):
    spec, data, out = tmp_path / "dryer.json", tmp_path / "seq.csv", tmp_path / "out"
    model.save(spec)
    sim = simulate(model, modes=EVERY_MODE, seed=4)
    write_columns(data, sim.columns())
    assert main(["bench", str(spec), str(data), "--filters", "imm", "--runs", "1", "--workers", "1",
                 "--healthy", "normal,fan", "--no-figures", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    counts = named_by_hand(model, sweep.make_jobs(model, [sweep.LabelledSequence("seq", sim.y, sim.u, sim.modes)],
                                                  ("imm",), (), runs=1)[0], ("normal", "fan"))
    assert counts.rows.tolist() == [15, 15]  # fan is healthy here: its rows are not scored
    assert "## dryer, seq: 1 run per setting; healthy: normal, fan" in printed
    assert "\n".join(naming_report(["grill", "fan_grill"], counts)) in printed
    assert (out / "seq-table.md").read_text() in printed
    table = list(csv.DictReader((out / "seq-table.csv").open()))
    assert float(table[0]["imm_naming"]) == pytest.approx(counts.overall, rel=1e-5)
    runs = list(csv.DictReader((out / "runs.csv").open()))
    assert float(runs[0]["naming"]) == pytest.approx(counts.overall)


@pytest.mark.parametrize("healthy, message", [("normal,nope", "unknown healthy mode 'nope'"),
                                              ("normal,fan,grill,fan_grill", "--healthy names every mode")])
def test_bench_command_refuses_a_bad_healthy_list(model, tmp_path, capsys, healthy, message):
    spec = tmp_path / "dryer.json"
    model.save(spec)
    assert main(["bench", str(spec), "--simulate", "10", "--filters", "imm", "--runs", "1", "--workers", "1",
                 "--healthy", healthy, "-o", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err
