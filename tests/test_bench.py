"""Filter sweeps: seeds, the unit of work, summaries and tables, the process pool, a local Ray cluster
(bound to 127.0.0.1) and the CLI."""

import csv
import math
import io

import numpy as np
import pytest
from conftest import dryer_files
from infer_models import dryer

import jmlgdsl
from jmlgdsl.studies import sweep
from jmlgdsl.cli import main
from jmlgdsl.diagnosis.cluster import ClusterError, disconnect
from jmlgdsl.errors import DataError
from jmlgdsl.diagnosis.progress import Progress
from jmlgdsl.simulation.linear import simulate

SHORT = "1-20:normal,21-40:fan,41-60:grill"


@pytest.fixture(scope="module")
def model():
    return dryer()


@pytest.fixture(scope="module")
def sequence(model):
    sim = simulate(model, modes=SHORT, seed=5)
    return sweep.LabelledSequence("short", sim.y, sim.u, sim.modes)


def read_records(path) -> list[dict]:
    """Run records as sweep.write_records_csv writes them, read back with the csv module."""
    with open(path, newline="") as stream:
        rows = list(csv.DictReader(stream))
    return [{"data": r["data"], "filter": r["filter"], "particles": int(r["particles"]) if r["particles"] else None,
             "run": int(r["run"]), **{k: float(r[k]) for k in ("error", "ms_per_step", "loglik")}} for r in rows]


def _without_time(records):
    return [{k: v for k, v in r.items() if k != "ms_per_step"} for r in records]


def test_jobs_cover_every_setting_and_deterministic_filters_once_per_run(model, sequence):
    jobs = sweep.make_jobs(model, [sequence], ("pf", "imm", "la-rbpf"), (1, 10), runs=3, seed=0)
    settings = [(j.algorithm, j.particles, j.run) for j in jobs]
    assert len(settings) == len(set(settings)) == 3 * (2 + 1 + 2)
    assert {(a, n) for a, n, _ in settings} == {("pf", 1), ("pf", 10), ("imm", None), ("la-rbpf", 1), ("la-rbpf", 10)}


def test_each_filter_run_has_its_own_stream_and_each_run_its_own_data(model):
    jobs = sweep.make_jobs(model, [sweep.Simulated(None, SHORT)], ("rbpf", "la-rbpf"), (4,), runs=2, seed=7)
    states = [tuple(j.filter_seed.generate_state(4)) for j in jobs]
    assert len(set(states)) == len(jobs)
    first, second = [[j for j in jobs if j.run == r] for r in (0, 1)]
    np.testing.assert_array_equal(sweep.sequence_of(first[0]).y, sweep.sequence_of(first[1]).y)
    assert not np.array_equal(sweep.sequence_of(first[0]).y, sweep.sequence_of(second[0]).y)
    np.testing.assert_array_equal(sweep.sequence_of(first[0]).modes, simulate(model, modes=SHORT).modes)


def test_adding_a_filter_or_a_count_to_a_sweep_leaves_the_other_settings_draws_alone(model, sequence):
    small = sweep.make_jobs(model, [sequence], ("la-rbpf",), (3,), runs=2, seed=1)
    large = sweep.make_jobs(model, [sequence], ("pf", "la-rbpf", "rbpf"), (1, 3, 7), runs=2, seed=1)
    seeds = {(j.algorithm, j.particles, j.run): j.filter_seed.generate_state(4).tolist() for j in large}
    for job in small:
        assert job.filter_seed.generate_state(4).tolist() == seeds[job.algorithm, job.particles, job.run]
    assert sweep.run_job(small[0]) | {"ms_per_step": 0} == sweep.run_job(
        [j for j in large if (j.algorithm, j.particles, j.run) == ("la-rbpf", 3, 0)][0]) | {"ms_per_step": 0}


def test_data_can_come_from_another_plant_than_the_filters_model(model):
    other = model.replace(P=np.full((4, 4), 0.25))
    job = sweep.make_jobs(other, [sweep.Simulated(None, SHORT, plant=model)], ("imm",), (1,), runs=1, seed=4)[0]
    expected = simulate(model, modes=SHORT, seed=job.data_seed)
    np.testing.assert_array_equal(sweep.sequence_of(job).y, expected.y)
    assert job.model is other


def test_a_job_reports_the_map_error_of_the_filter_it_names(model, sequence):
    job = sweep.make_jobs(model, [sequence], ("la-rbpf",), (3,), runs=1, seed=2)[0]
    record = sweep.run_job(job)
    result = jmlgdsl.filter(model, sequence.y, sequence.u, algorithm="la-rbpf", particles=3, seed=job.filter_seed)
    wrong = np.count_nonzero(result.map_modes != sequence.modes)
    assert record["error"] == pytest.approx(100.0 * wrong / 60)
    assert record["loglik"] == result.loglik
    assert (record["data"], record["filter"], record["particles"], record["run"]) == ("short", "la-rbpf", 3, 0)


def test_a_one_reading_prefilter_changes_nothing_and_a_longer_one_changes_the_data(model, sequence):
    plain, one, five = (sweep.make_jobs(model, [sequence], ("imm",), (1,), runs=1, seed=0, prefilter=w)[0]
                        for w in (None, 1, 5))
    assert sweep.run_job(one)["loglik"] == sweep.run_job(plain)["loglik"]
    assert sweep.run_job(five)["loglik"] != sweep.run_job(plain)["loglik"]


def test_sweeps_repeat_exactly_and_the_pool_matches_serial_runs(model, sequence):
    args = (model, [sequence], ("pf", "fc-rbpf"), (1, 5), 2, 11)
    serial = sweep.sweep(*args, workers=1)
    pooled = sweep.sweep(*args, workers=2)
    assert _without_time(serial) == _without_time(pooled)
    other = sweep.sweep(model, [sequence], ("pf", "fc-rbpf"), (1, 5), 2, 12, workers=1)
    assert _without_time(other) != _without_time(serial)


def test_the_sweep_runs_on_a_local_ray_cluster_with_the_same_results(model, sequence, files, tmp_path, capsys):
    """Each run a Ray task: the library's records, and the command's runs.csv, are the serial run's
    (the time per step apart); a failing run's error is the one without a cluster; the command stops
    the Ray it started."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install '.[cluster]')")
    args = (model, [sequence], ("la-rbpf", "imm"), (2,), 2, 3)
    bad = sweep.LabelledSequence("bad", sequence.y[:, :0], sequence.u, sequence.modes)  # no output column
    try:
        remote = sweep.sweep(*args, cluster="auto")
        with pytest.raises(DataError, match=r"^y must have shape"):
            sweep.sweep(model, [bad], ("imm",), (1,), runs=3, cluster="auto")
    finally:
        disconnect()
    assert _without_time(remote) == _without_time(sweep.sweep(*args, workers=1))
    spec, data = files
    common = ["bench", str(spec), str(data), "--runs", "2", "--particles", "2", "--filters", "rbpf,imm", "--no-figures"]
    assert main([*common, "--workers", "1", "-o", str(tmp_path / "serial")]) == 0
    assert main([*common, "--cluster", "auto", "-o", str(tmp_path / "ray")]) == 0
    assert not ray.is_initialized()
    assert "4/4 runs" in capsys.readouterr().err
    assert (_without_time(read_records(tmp_path / "ray" / "runs.csv"))
            == _without_time(read_records(tmp_path / "serial" / "runs.csv")))


def test_bad_sweeps_are_user_errors(model, sequence):
    with pytest.raises(DataError, match="unknown filter 'kalman'"):
        sweep.make_jobs(model, [sequence], ("kalman",), (1,))
    with pytest.raises(DataError, match="at least 1"):
        sweep.make_jobs(model, [sequence], ("pf",), (1,), runs=0)
    with pytest.raises(DataError, match="positive whole numbers, got 0"):
        sweep.make_jobs(model, [sequence], ("pf",), (4, 0))
    with pytest.raises(DataError, match="no filter to run"):
        sweep.make_jobs(model, [sequence], (), (1,))
    with pytest.raises(DataError, match="need at least one particle count"):
        sweep.make_jobs(model, [sequence], ("imm", "pf"), ())
    assert len(sweep.make_jobs(model, [sequence], ("imm",), (), runs=2)) == 2  # imm needs no particles


def test_a_failing_run_stops_the_pool_with_its_error(model, sequence):
    bad = sweep.LabelledSequence("bad", sequence.y[:, :0], sequence.u, sequence.modes)  # no output column
    with pytest.raises(DataError, match="y must have shape"):
        sweep.sweep(model, [bad], ("imm",), (1,), runs=3, workers=2)


def test_an_unreachable_cluster_is_a_user_error(model, sequence, files, capsys):
    with pytest.raises(ClusterError, match="--cluster 127.0.0.1:9: nothing answers there"):
        sweep.sweep(model, [sequence], ("imm",), (1,), runs=1, cluster="127.0.0.1:9")
    with pytest.raises(DataError, match="give one or the other"):
        sweep.sweep(model, [sequence], ("imm",), (1,), runs=1, workers=2, cluster="127.0.0.1:9")
    spec, data = files
    assert main(["bench", str(spec), str(data), "--runs", "1", "--cluster", "127.0.0.1:9"]) == 2
    assert "is the cluster's head started (ray start --head)?" in capsys.readouterr().err


RECORDS = [
    {"data": "d", "filter": "pf", "particles": 10, "run": 0, "error": 10.0, "ms_per_step": 1.0, "loglik": -5.0},
    {"data": "d", "filter": "pf", "particles": 10, "run": 1, "error": 20.0, "ms_per_step": 3.0, "loglik": -7.0},
    {"data": "d", "filter": "pf", "particles": 1, "run": 0, "error": 50.0, "ms_per_step": 0.5, "loglik": -9.0},
    {"data": "d", "filter": "pf", "particles": 1, "run": 1, "error": 70.0, "ms_per_step": 0.5, "loglik": -11.0},
    {"data": "d", "filter": "imm", "particles": None, "run": 0, "error": 4.0, "ms_per_step": 0.2, "loglik": -1.0},
    {"data": "d", "filter": "imm", "particles": None, "run": 1, "error": 4.0, "ms_per_step": 0.2, "loglik": -1.0},
]


def test_summary_is_the_mean_and_sample_sd_over_runs():
    rows = {(r["filter"], r["particles"]): r for r in sweep.summarise(RECORDS)}
    pf10 = rows["pf", 10]
    assert pf10["runs"] == 2
    assert pf10["error_mean"] == 15.0
    assert pf10["error_sd"] == pytest.approx(np.sqrt(50.0))
    assert pf10["ms_per_step_mean"] == 2.0
    assert rows["imm", None]["error_sd"] == 0.0


def test_markdown_table_has_the_published_shape():
    table = sweep.markdown_table(sweep.summarise(RECORDS)).splitlines()
    assert table[2:] == ["| N | pf | imm |", "|---|---|---|", "| 1 | 60.00 (14.14) |  |",
                         "| 10 | 15.00 (7.07) |  |", "| — |  | 4.00 (0.00) |"]
    assert "| 10 | 2 |  |" in sweep.markdown_table(sweep.summarise(RECORDS), "ms_per_step")


def test_one_run_gives_the_mean_without_a_spread(tmp_path):
    """One run has no SD: the tables give the mean alone (not 'mean (nan)'), the CSV an empty SD cell."""
    summary = sweep.summarise([r for r in RECORDS if r["run"] == 0])
    assert sweep.markdown_table(summary).splitlines()[4:] == ["| 1 | 50.00 |  |", "| 10 | 10.00 |  |",
                                                              "| — |  | 4.00 |"]
    assert "| 10 | -5.0 |  |" in sweep.markdown_table(summary, "loglik")
    sweep.write_table_csv(tmp_path / "t.csv", summary)
    rows = list(csv.DictReader((tmp_path / "t.csv").open()))
    assert rows[1]["pf_error_mean"] == "10" and rows[1]["pf_error_sd"] == ""


def test_table_and_record_csv_files(tmp_path):
    sweep.write_table_csv(tmp_path / "t.csv", sweep.summarise(RECORDS))
    rows = list(csv.DictReader((tmp_path / "t.csv").open()))
    assert [r["particles"] for r in rows] == ["1", "10", ""]
    assert float(rows[1]["pf_error_mean"]) == 15.0 and rows[1]["imm_error_mean"] == ""
    assert float(rows[2]["imm_error_mean"]) == 4.0
    sweep.write_records_csv(tmp_path / "runs.csv", RECORDS)
    assert read_records(tmp_path / "runs.csv") == RECORDS
    back = sweep.read_records_csv(tmp_path / "runs.csv")  # the reader --redraw uses: every measure, lag 0
    assert [{k: r[k] for k in RECORDS[0]} for r in back] == RECORDS
    assert all(r["lag"] == 0 and math.isnan(r["delay"]) for r in back)


def test_progress_bar_reports_runs_done_on_a_plain_stream():
    stream = io.StringIO()
    bar = Progress(20, stream)
    for _ in range(20):
        bar.update()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 10  # one line per tenth on a stream that is not a terminal
    assert lines[-1].startswith("[" + "#" * 30 + "] 20/20 runs")


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_count_without_total_redraws_once_a_second_on_a_terminal_only():
    """`run` reads rows whose number it cannot know: on a terminal their count and rate are redrawn
    in place at most once a second and finished with a newline; elsewhere nothing is written."""
    now = [0.0]
    terminal = Terminal()
    count = Progress(None, terminal, "rows", clock=lambda: now[0])
    for i in range(1, 2501):  # 2.5 s at 1,000 rows a second
        now[0] = i / 1000
        count.update()
    count.close()
    assert terminal.getvalue() == ("\r1000 rows, 0m01s elapsed, 1000 rows/s\r2000 rows, 0m02s elapsed, 1000 rows/s"
                                   "\r2500 rows, 0m02s elapsed, 1000 rows/s\n")
    short = Terminal()
    brief = Progress(None, short, "rows", clock=lambda: now[0])
    now[0] += 0.5
    brief.update(500)
    brief.close()
    assert short.getvalue() == ""  # under a second: nothing to watch
    plain = io.StringIO()
    quiet = Progress(None, plain, "rows")
    for _ in range(2500):
        quiet.update()
    quiet.close()
    assert plain.getvalue() == ""
    silent = Progress(20, None)  # no stream: nothing shown, bar or count
    for _ in range(20):
        silent.update()
    assert silent.done == 20


@pytest.fixture(scope="module")
def files(tmp_path_factory, model):
    """The model saved as JSON and a short simulated data file with its true modes."""
    return dryer_files(tmp_path_factory.mktemp("bench"), SHORT, 3)


def test_bench_command_prints_the_table_and_writes_tables_and_figures(files, tmp_path, capsys):
    spec, data = files
    out = tmp_path / "out"
    assert main(["bench", str(spec), str(data), "--runs", "2", "--particles", "1,4", "--filters",
                 "la-rbpf,imm", "--workers", "1", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert "## dryer, seq: 2 runs per setting" in captured.out
    assert "| N | la-rbpf | imm |" in captured.out
    assert "2/6 runs" not in captured.out and "6/6 runs" in captured.err
    names = {p.name for p in out.iterdir()}
    assert names == {"runs.csv", "seq-table.md", "seq-table.csv", "seq-error-vs-particles.png",
                     "seq-error-vs-time.png", "seq-boxplots.png"}
    assert len(read_records(out / "runs.csv")) == 6


def test_bench_command_on_simulated_sequences(files, tmp_path, capsys):
    spec, _ = files
    assert main(["bench", str(spec), "--modes", SHORT, "--runs", "2", "--particles", "2", "--filters", "rbpf",
                 "--workers", "1", "--prefilter", "ma:2", "--no-figures", "-o", str(tmp_path)]) == 0
    assert "## dryer, simulated: 2 runs per setting" in capsys.readouterr().out
    assert not list(tmp_path.glob("*.png"))


def test_bench_command_with_one_run(files, tmp_path, capsys):
    spec, data = files
    assert main(["bench", str(spec), str(data), "--runs", "1", "--filters", "imm", "--workers", "1",
                 "--no-figures", "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "## dryer, seq: 1 run per setting" in out and "(nan)" not in out
    assert "(nan)" not in (tmp_path / "seq-table.md").read_text()


def test_bench_command_simulates_the_nonlinear_equations(capsys, tmp_path):
    assert main(["bench", "specs/dryer.jmlg", "--simulate", "5", "--nonlinear"]) == 2
    assert "has no 'ode' block" in capsys.readouterr().err
    assert main(["bench", "specs/cstr4.jmlg", "--modes", "1-15:normal,16-30:fouling3", "--nonlinear", "--runs", "1",
                 "--filters", "imm", "--workers", "1", "--no-figures", "-o", str(tmp_path)]) == 0
    record = read_records(tmp_path / "runs.csv")[0]
    assert record["filter"] == "imm" and 0 <= record["error"] <= 100


@pytest.mark.parametrize("extra, message", [
    ([], "give data files with a 'mode' column, or --simulate T"),
    (["--simulate", "0"], "--simulate must be a positive number of steps"),
    (["--simulate", "10", "--prefilter", "box:3"], "write ma:K"),
    (["--simulate", "10", "--filters", "pf,nope"], "unknown filter 'nope'"),
    (["--simulate", "10", "--nonlinear"], "--nonlinear needs a .jmlg spec with an 'ode' block"),
    (["--simulate", "10", "--filters", "imm", "--workers", "0"], "worker processes must be at least 1, got 0"),
])
def test_bench_command_user_errors(files, extra, message, capsys):
    spec, _ = files
    assert main(["bench", str(spec), "--workers", "1", "--runs", "1", *extra]) == 2
    assert message in capsys.readouterr().err


def test_bench_command_needs_distinct_data_file_names(files, tmp_path, capsys):
    spec, data = files
    (tmp_path / "other").mkdir()
    twin = tmp_path / "other" / data.name
    twin.write_text(data.read_text())
    assert main(["bench", str(spec), str(data), str(twin), "--workers", "1"]) == 2
    assert "data files need different names" in capsys.readouterr().err


def test_bench_command_needs_the_true_modes(files, tmp_path, capsys):
    spec, data = files
    rows = data.read_text().splitlines()
    header = rows[0].split(",")
    keep = [i for i, h in enumerate(header) if h != "mode"]
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(",".join(r.split(",")[i] for i in keep) for r in rows) + "\n")
    assert main(["bench", str(spec), str(bare), "--workers", "1"]) == 2
    assert "bare.csv: no 'mode' column" in capsys.readouterr().err

