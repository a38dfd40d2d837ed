"""bench --lag: smoothing lags as one more dimension of a sweep, with error and detection delay."""

import csv

import numpy as np
import pytest
from infer_models import dryer

import jmlgdsl
from jmlgdsl.studies import sweep
from jmlgdsl.cli import main
from jmlgdsl.data import write_columns
from jmlgdsl.diagnosis.metrics import switch_delays
from jmlgdsl.simulation.linear import simulate

SHORT = "1-20:normal,21-40:fan,41-60:grill"


@pytest.fixture(scope="module")
def sequence():
    model = dryer()
    sim = simulate(model, modes=SHORT, seed=5)
    return model, sweep.LabelledSequence("short", sim.y, sim.u, sim.modes)


@pytest.mark.parametrize("algorithm, particles, lag", [("imm", None, 3), ("imm", None, None), ("la-rbpf", 5, 2)])
def test_a_lagged_job_measures_the_smoother_with_the_filters_seed(sequence, algorithm, particles, lag):
    model, data = sequence
    jobs = sweep.make_jobs(model, [data], (algorithm,), (particles or 1,), runs=1, seed=3, lags=(0, lag))
    assert [j.lag for j in jobs] == [0, lag] and jobs[0].filter_seed is jobs[1].filter_seed
    record = sweep.run_job(jobs[1])
    result = jmlgdsl.smooth(model, data.y, data.u, algorithm=algorithm, particles=particles, lag=lag,
                            seed=jobs[1].filter_seed)
    assert record["lag"] == lag and record["error"] == result.diagnosis_error(data.modes)
    assert record["delay"] == switch_delays(result.map_modes, data.modes, lag).mean()


def test_bench_command_compares_lags(sequence, tmp_path, capsys):
    model, data = sequence
    spec, table = tmp_path / "dryer.json", tmp_path / "seq.csv"
    model.save(spec)
    write_columns(table, {"temp": data.y[:, 0], "mode": [model.modes[k] for k in data.modes]})
    out = tmp_path / "out"
    assert main(["bench", str(spec), str(table), "--filters", "imm", "--runs", "1", "--workers", "1",
                 "--lag", "0,5,offline", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    for section in ("### filtering", "### lag 5", "### off-line smoothing"):
        assert section in printed
    assert (out / "seq-error-vs-lag.png").exists()
    rows = list(csv.DictReader((out / "seq-table.csv").open()))
    assert [r["lag"] for r in rows] == ["0", "5", "offline"]
    offline = jmlgdsl.smooth(model, data.y, data.u).diagnosis_error(data.modes)
    assert float(rows[2]["imm_error_mean"]) == pytest.approx(offline)


def test_a_bad_lag_list_is_a_clear_error(sequence, tmp_path, capsys):
    model, _ = sequence
    spec = tmp_path / "dryer.json"
    model.save(spec)
    with pytest.raises(SystemExit) as stop:  # argparse's usage error: status 2, no traceback
        main(["bench", str(spec), "--simulate", "10", "--lag", "0,soon"])
    assert stop.value.code == 2
    assert "argument --lag: invalid comma-separated list of lags (whole numbers or 'offline') value: '0,soon'" \
        in capsys.readouterr().err


@pytest.mark.parametrize("lag", [0, 4])
def test_a_record_scores_the_default_alarm_rule_where_each_alarm_is_known(sequence, lag):
    from jmlgdsl.diagnosis.alarms import AlarmRule
    from jmlgdsl.diagnosis.metrics import changepoints, score

    model, data = sequence
    job = sweep.make_jobs(model, [data], ("imm",), (1,), runs=1, seed=0, lags=(lag,))[0]
    record = sweep.run_job(job)
    result = jmlgdsl.smooth(model, data.y, data.u, lag=lag)
    rule = AlarmRule(("normal",))
    alarm = np.r_[np.zeros(lag, int), rule.alarms(result.mode_posterior, model.modes)][:len(data.y)]
    truth = rule.truth(data.modes, model.modes)  # rows 21-60 (fan, grill) are faults
    expected = score(alarm, truth, model.dt, changepoints(truth)).summary()
    assert (record["f1"], record["far"], record["mar"], record["nab"]) == (
        expected["f1"], expected["far"], expected["mar"], expected["nab_standard"])
    assert 0.9 < record["f1"] <= 1.0  # 20 normal then 40 faulty steps: the alarms follow them closely
