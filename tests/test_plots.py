"""Figures: study plots from bench records, the diagnosis figure, and `jmlgdsl plot` on a run table."""

import sqlite3

import matplotlib.image
import numpy as np
import pytest
from conftest import ROOT
from infer_models import dryer

import jmlgdsl
from jmlgdsl.diagnosis import figure as run_figure
from jmlgdsl.studies import figures, sweep
from jmlgdsl.cli import main
from jmlgdsl.monitor.store.databases import SQLite

RECORDS = [
    {"data": "d", "filter": f, "particles": n, "run": r, "error": 50.0 / n + r, "ms_per_step": 0.1 * n,
     "loglik": -1.0} for f in ("pf", "la-rbpf") for n in (1, 10, 100) for r in range(3)
] + [{"data": "d", "filter": "imm", "particles": None, "run": r, "error": 2.0, "ms_per_step": 0.3, "loglik": -1.0}
     for r in range(3)]


def _legend(ax):
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_error_against_particles_draws_each_filter_and_the_published_points(tmp_path):
    summary = sweep.summarise(RECORDS)
    fig = figures.error_vs_particles(summary, tmp_path / "p.png", reference={"la-rbpf": [(1, 26.0, 7.8), (10, 13.6, 5.6)]})
    (ax,) = fig.axes
    assert _legend(ax) == ["imm (no particles)", "pf", "la-rbpf", "la-rbpf, published (real data)"]
    assert list(ax.get_xticks()) == [1, 10, 100] and ax.get_xscale() == "log"
    assert ax.get_ylabel() == "diagnosis error (% of steps)"
    imm = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert [line.get_ydata()[0] for line in imm] == [2.0]  # imm's mean error, as a horizontal line
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_error_against_time_marks_the_sample_time_among_the_times(tmp_path):
    fig = figures.error_vs_time(sweep.summarise(RECORDS), tmp_path / "t.png", sample_time=0.005)
    (ax,) = fig.axes
    vertical = [line for line in ax.get_lines() if list(line.get_xdata()) == [5.0, 5.0]]
    assert len(vertical) == 1  # 0.005 s = 5 ms, the real-time limit, between 0.1 and 10 ms a step
    assert "0.005 s" not in ax.texts[0].get_text() and "5 ms" in ax.texts[0].get_text()
    assert _legend(ax) == ["pf", "la-rbpf", "imm"]


def test_a_sample_time_beyond_every_filter_is_a_note_not_the_axis_range(tmp_path):
    """Filters at 0.1-10 ms a step and a 100 ms sample time: the axis ends near 10 ms (an axis out to
    100 ms squeezed every point into its left part) and the sample time is a note at the edge."""
    fig = figures.error_vs_time(sweep.summarise(RECORDS), tmp_path / "t.png", sample_time=0.1)
    (ax,) = fig.axes
    assert ax.get_xlim()[1] < 20
    assert not [line for line in ax.get_lines() if list(line.get_xdata()) == [100.0, 100.0]]
    (note,) = ax.texts
    assert "sample time 100 ms (real-time limit), off the axis" in note.get_text()
    assert "the slowest setting takes 10 ms a step" in note.get_text()


def test_box_plots_have_one_panel_per_particle_filter(tmp_path):
    fig = figures.error_boxplots(RECORDS, tmp_path / "b.png")
    assert [ax.get_title() for ax in fig.axes] == ["pf", "la-rbpf"]
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["1", "10", "100"]


def test_box_plots_need_particle_filter_runs(tmp_path):
    with pytest.raises(ValueError, match="no particle-filter runs"):
        figures.error_boxplots([r for r in RECORDS if r["filter"] == "imm"], tmp_path / "b.png")


def test_the_diagnosis_figure_has_a_row_per_mode_and_a_panel_per_output(tmp_path):
    T = 50
    time = 0.5 * np.arange(1, T + 1)
    names = [f"mode{k}" for k in range(10)]
    fig = run_figure.diagnosis_figure(tmp_path / "many.png", names, np.full((T, 10), 0.1), time, np.zeros((T, 3)),
                                 np.zeros((T, 3)), ["y1", "y2", "y3"], true_modes=np.arange(T) % 10)
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert len(panels) == 2 + 3 + 1  # MAP mode, posterior map, three outputs, residuals
    for ax in panels[:2]:
        assert [t.get_text() for t in ax.get_yticklabels()] == names
    assert [ax.get_ylabel() for ax in panels[2:5]] == ["y1", "y2", "y3"]
    assert panels[0].get_title(loc="right") == "diagnosis error 90.0 % of steps"  # MAP is mode0 everywhere
    assert panels[-1].get_xlabel() == "time (s)"


def test_result_figure_draws_the_filtered_outputs_on_the_model_clock(monkeypatch, tmp_path):
    model = dryer()
    y = np.array([[50.5], [np.nan], [50.4], [50.6]])
    result = jmlgdsl.filter(model, y, algorithm="imm")
    seen = {}
    monkeypatch.setattr(run_figure, "diagnosis_figure", lambda path, *args, **kw: seen.update(args=args, kw=kw))
    run_figure.result_figure(result, tmp_path / "r.png", true_modes=[0, 0, 0, 0])
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
    monkeypatch.setattr(run_figure, "diagnosis_figure", lambda path, *args, **kw: seen.update(args=args, kw=kw))
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
    image = matplotlib.image.imread(tmp_path / "f.png")
    assert image.std() > 0.05  # something was drawn
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


def test_run_plot_draws_residuals_over_their_predicted_sd_and_the_files_anomaly_labels(tmp_path, monkeypatch):
    """Residuals in raw units put sensors of different scales on one axis (SKAB's Voltage flattened
    the other seven): `run --plot` draws each over its one-step predictive sd, and the file's
    `anomaly` column as bands."""
    data = tmp_path / "labelled.csv"
    lines = (ROOT / "examples" / "dryer_seq1.csv").read_text().splitlines()
    data.write_text("\n".join([lines[0] + ",anomaly"] + [f"{line},{int(line.split(',')[3] != 'normal')}"
                                                          for line in lines[1:]]) + "\n")
    seen = {}
    monkeypatch.setattr(run_figure, "diagnosis_figure", lambda path, *args, **kw: seen.update(args=args, kw=kw))
    assert main(["run", str(ROOT / "specs" / "dryer.jmlg"), str(data), "--plot", str(tmp_path / "f.png")]) == 0
    _, _, _, y, y_pred, _ = seen["args"]
    sd, anomaly = seen["kw"]["y_sd"], seen["kw"]["anomaly"]
    assert sd.shape == y.shape and np.isnan(sd[0]).all() and (sd[1:] > 0).all()
    z = ((y - y_pred) / sd)[1:, 0]
    normal = np.array([line.split(",")[3] == "normal" for line in lines[1:]])[1:]
    assert 0.7 < z[normal].std() < 1.5  # the healthy rows' standardised residuals: unit spread
    np.testing.assert_array_equal(anomaly, [int(line.split(",")[3] != "normal") for line in lines[1:]])
    monkeypatch.undo()
    # the store's y_sd of a monitor over the same rows is the same spread
    store = tmp_path / "dryer.db"
    assert main(["monitor", str(ROOT / "specs" / "dryer.jmlg"), "--source", str(data), "--store", str(store),
                 "--no-follow"]) == 0
    stored = [SQLite.unvector(v, 1)[0] for (v,) in sqlite3.connect(store).execute("SELECT y_sd FROM result ORDER BY t")]
    np.testing.assert_allclose(np.array(stored[1:], float), sd[1:, 0], rtol=1e-9)


def test_the_residual_panel_draws_standardised_residuals_and_anomaly_bands(tmp_path):
    T = 40
    time = np.arange(1.0, T + 1)
    y, y_pred = np.zeros((T, 2)), np.zeros((T, 2))
    y[:, 0], y[:, 1] = 300.0, 0.3  # a volt and a tenth of a bar off: 3 sd each
    sd = np.column_stack([np.full(T, 100.0), np.full(T, 0.1)])
    anomaly = (np.arange(T) >= 20).astype(int)
    fig = run_figure.diagnosis_figure(tmp_path / "z.png", ["a", "b"], np.full((T, 2), 0.5), time, y, y_pred,
                                      ["Voltage", "Pressure"], y_sd=sd, anomaly=anomaly)
    residuals = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"][-1]
    drawn = [line.get_ydata() for line in residuals.get_lines() if line.get_label() in ("Voltage", "Pressure")]
    np.testing.assert_allclose(drawn, 3.0)
    assert residuals.get_ylabel() == "residual / its\npredicted sd"
    bands = [p for p in residuals.patches]
    assert len(bands) == 1 and bands[0].get_label() == "true anomaly"
