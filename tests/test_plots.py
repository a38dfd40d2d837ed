"""Figures: study plots from bench records, the diagnosis figure, and `jmlgdsl plot` on a run table."""

import matplotlib.image
import numpy as np
import pytest
from infer_models import dryer

import jmlgdsl
from jmlgdsl import bench, plots
from jmlgdsl.cli import main

RECORDS = [
    {"data": "d", "filter": f, "particles": n, "run": r, "error": 50.0 / n + r, "ms_per_step": 0.1 * n,
     "loglik": -1.0} for f in ("pf", "la-rbpf") for n in (1, 10, 100) for r in range(3)
] + [{"data": "d", "filter": "imm", "particles": None, "run": r, "error": 2.0, "ms_per_step": 0.3, "loglik": -1.0}
     for r in range(3)]


def _pixels(path):
    """(height, width) of a PNG file."""
    return matplotlib.image.imread(path).shape[:2]


def test_study_figures_are_pngs_of_the_chosen_size(tmp_path):
    summary = bench.summarise(RECORDS)
    plots.error_vs_particles(summary, tmp_path / "p.png", reference={"la-rbpf": [(1, 26.0, 7.8), (10, 13.6, 5.6)]})
    plots.error_vs_time(summary, tmp_path / "t.png", sample_time=0.1)
    plots.error_boxplots(RECORDS, tmp_path / "b.png")
    assert _pixels(tmp_path / "p.png") == (450, 850)
    assert _pixels(tmp_path / "t.png") == (450, 800)
    assert _pixels(tmp_path / "b.png") == (420, 720)  # two particle filters, one panel each


def test_box_plots_need_particle_filter_runs(tmp_path):
    with pytest.raises(ValueError, match="no particle-filter runs"):
        plots.error_boxplots([r for r in RECORDS if r["filter"] == "imm"], tmp_path / "b.png")


def test_the_diagnosis_figure_grows_with_modes_and_outputs(tmp_path):
    T = 50
    time = 0.5 * np.arange(1, T + 1)
    few, many = np.full((T, 4), 0.25), np.full((T, 10), 0.1)
    plots.diagnosis_figure(tmp_path / "few.png", list("abcd"), few, time, np.zeros(T), np.zeros(T), ["y"])
    plots.diagnosis_figure(tmp_path / "many.png", [f"mode{k}" for k in range(10)], many, time, np.zeros((T, 3)),
                           np.zeros((T, 3)), ["y1", "y2", "y3"], true_modes=np.arange(T) % 10)
    assert _pixels(tmp_path / "many.png")[0] > _pixels(tmp_path / "few.png")[0]


def test_result_figure_draws_the_filtered_outputs_on_the_model_clock(monkeypatch, tmp_path):
    model = dryer()
    y = np.array([[50.5], [np.nan], [50.4], [50.6]])
    result = jmlgdsl.filter(model, y, algorithm="imm")
    seen = {}
    monkeypatch.setattr(plots, "diagnosis_figure", lambda path, *args, **kw: seen.update(args=args, kw=kw))
    plots.result_figure(result, tmp_path / "r.png", true_modes=[0, 0, 0, 0])
    modes, posterior, time, drawn, y_pred, outputs = seen["args"]
    np.testing.assert_allclose(drawn, y)  # NaN where nothing was measured
    np.testing.assert_array_equal(time, [1.0, 2.0, 3.0, 4.0])
    assert seen["kw"]["title"] == "dryer: mode diagnosis (imm)"


@pytest.fixture(scope="module")
def run_table(tmp_path_factory):
    d = tmp_path_factory.mktemp("plot")
    spec = d / "dryer.json"
    dryer().save(spec)
    data, table = d / "seq.csv", d / "run.csv"
    assert main(["simulate", str(spec), "--modes", "1-30:normal,31-60:fan", "--seed", "2", "-o", str(data)]) == 0
    assert main(["run", str(spec), str(data), "--filter", "la-rbpf", "--particles", "5", "--seed", "1",
                 "-o", str(table)]) == 0
    return data, table


def test_plot_command_draws_what_the_run_table_holds(run_table, tmp_path, monkeypatch, capsys):
    data, table = run_table
    seen = {}
    monkeypatch.setattr(plots, "diagnosis_figure", lambda path, *args, **kw: seen.update(args=args, kw=kw))
    assert main(["plot", str(table), "--truth", str(data), "-o", str(tmp_path / "f.png")]) == 0
    modes, posterior, time, y, y_pred, outputs = seen["args"]
    assert modes == ["normal", "fan", "grill", "fan_grill"] and outputs == ["temp"]
    assert posterior.shape == (60, 4)
    np.testing.assert_allclose(posterior.sum(axis=1), 1.0, atol=1e-8)
    measured = np.loadtxt(data, delimiter=",", skiprows=1, usecols=2)  # time,one,temp,...
    np.testing.assert_allclose(y[:, 0], measured, rtol=1e-9)  # predicted + residual gives the data back
    np.testing.assert_array_equal(seen["kw"]["true_modes"], [0] * 30 + [1] * 30)
    np.testing.assert_allclose(time, np.arange(1, 61))


def test_plot_command_writes_a_png(run_table, tmp_path, capsys):
    data, table = run_table
    assert main(["plot", str(table), "--truth", str(data), "-o", str(tmp_path / "f.png")]) == 0
    assert _pixels(tmp_path / "f.png")[1] == 900
    assert f"wrote {tmp_path / 'f.png'}" in capsys.readouterr().out


def test_plot_command_user_errors(run_table, tmp_path, capsys):
    data, table = run_table
    out = str(tmp_path / "f.png")
    assert main(["plot", str(data), "-o", out]) == 2
    assert "no map_mode, p_<mode> or <output>_resid columns" in capsys.readouterr().err
    short = tmp_path / "short.csv"
    short.write_text("\n".join(data.read_text().splitlines()[:11]) + "\n")
    assert main(["plot", str(table), "--truth", str(short), "-o", out]) == 2
    assert "short.csv has 10 rows but the run has 60 steps" in capsys.readouterr().err
    wrong = tmp_path / "wrong.csv"
    wrong.write_text(data.read_text().replace(",fan,", ",broken,", 1))
    assert main(["plot", str(table), "--truth", str(wrong), "-o", out]) == 2
    assert "unknown mode 'broken'" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    lines = table.read_text().splitlines()
    cells = lines[3].split(",")
    cells[3] = "x"
    lines[3] = ",".join(cells)
    bad.write_text("\n".join(lines) + "\n")
    assert main(["plot", str(bad), "-o", out]) == 2
    assert "bad.csv:4: column 'p_normal': 'x' is not a number" in capsys.readouterr().err
