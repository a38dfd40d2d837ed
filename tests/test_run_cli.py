"""`jmlgdsl simulate` and `jmlgdsl run` end to end: summaries, output tables, streaming, user errors."""

import csv
import subprocess
import threading
from pathlib import Path

import pytest
from conftest import dryer_files, jmlgdsl_command
from infer_models import DRYER_SEQ1

from jmlgdsl.cli import main
from jmlgdsl.infer import DEFAULT_ALGORITHM


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return dryer_files(tmp_path_factory.mktemp("run"), DRYER_SEQ1, 3, "seq1.csv")


def test_run_prints_a_diagnosis(files, capsys, tmp_path):
    spec, data = files
    out = tmp_path / "out.csv"
    assert main(["run", str(spec), str(data), "--filter", "fc-rbpf", "--seed", "1", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "dryer: 1000 steps, filter fc-rbpf with 4 particles" in text
    assert "  t 1\u201371: normal (p\u0304 0.99)" in text
    error = float(text.split("diagnosis error: ")[1].split(" %")[0])
    assert error < 5.0
    table = list(csv.DictReader(out.open()))
    assert len(table) == 1000
    assert list(table[0]) == ["t", "time", "map_mode", "p_normal", "p_fan", "p_grill", "p_fan_grill",
                              "x_mean", "temp_pred", "temp_resid", "ess", "alarm"]
    assert table[100]["map_mode"] == "fan"
    probs = [float(table[5][f"p_{m}"]) for m in ("normal", "fan", "grill", "fan_grill")]
    assert sum(probs) == pytest.approx(1.0, abs=1e-8)


def test_same_seed_same_output_bytes(files, tmp_path, capsys):
    spec, data = files
    outs = []
    for name in ("a.csv", "b.csv"):
        assert main(["run", str(spec), str(data), "--filter", "la-rbpf", "--seed", "4", "-o", str(tmp_path / name)]) == 0
        outs.append((tmp_path / name).read_bytes())
    assert outs[0] == outs[1]


def test_simulate_writes_to_standard_output(files, capsys):
    spec, _ = files
    assert main(["simulate", str(spec), "--steps", "3", "--seed", "0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "time,one,temp,mode,x_true" and len(lines) == 4


@pytest.mark.parametrize("content, message", [
    ("time,one\n1,1\n", "error: {data}: missing column 'temp'"),
    ("temp,mode\n50.1,normal\n50.2,oops\n", "error: {data}:3: column 'mode': unknown mode 'oops'"),
    ("temp\n50.1\nhot\n", "error: {data}:3: column 'temp': 'hot' is not a number"),
])
def test_bad_data_is_a_clear_error(files, tmp_path, capsys, content, message):
    spec, _ = files
    data = tmp_path / "bad.csv"
    data.write_text(content)
    assert main(["run", str(spec), str(data)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(message.format(data=data)) and "Traceback" not in err


def test_unwritable_output_is_a_clear_error(files, tmp_path, capsys):
    spec, data = files
    target = tmp_path / "no_such_folder" / "out.csv"
    for command in (["run", str(spec), str(data)], ["simulate", str(spec), "--steps", "3"]):
        assert main(command + ["-o", str(target)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: cannot write {target}: No such file or directory") and "Traceback" not in err


def test_negative_seed_is_a_clear_error(files, capsys):
    spec, data = files
    for command in (["run", str(spec), str(data), "--filter", "la-rbpf"], ["simulate", str(spec), "--steps", "3"]):
        assert main(command + ["--seed", "-1"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: the seed must be a non-negative whole number, got -1") and "Traceback" not in err


def test_bad_schedule_is_a_clear_error(files, capsys):
    spec, _ = files
    assert main(["simulate", str(spec), "--modes", "1-5:normal,6-9:boom"]) == 2
    assert "unknown mode 'boom'" in capsys.readouterr().err


def test_standard_input_is_filtered_row_by_row(files):
    spec, _ = files
    proc = subprocess.Popen([*jmlgdsl_command(), "run", str(spec), "-", "-o", "-", "--seed", "2"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    timer = threading.Timer(60, proc.kill)  # never hang the test run
    timer.start()
    try:
        proc.stdin.write("temp\n50.5\n")
        proc.stdin.flush()
        # Both lines arrive while standard input is still open: the row was flushed at once.
        assert proc.stdout.readline().startswith("t,map_mode,p_normal")
        assert proc.stdout.readline().startswith("1,normal,")
        proc.stdin.write("50.4\n")
        proc.stdin.close()
        assert proc.stdout.readline().startswith("2,normal,")
        assert proc.wait() == 0
        assert f"filter {DEFAULT_ALGORITHM}" in proc.stderr.read()
    finally:
        timer.cancel()
        proc.kill()


ROOT = Path(__file__).resolve().parent.parent
EXAMPLE_COMMAND = ["simulate", "specs/dryer.jmlg", "--steps", "1000", "--modes", DRYER_SEQ1, "--seed", "1"]


def test_bundled_example_is_what_its_command_makes(tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    assert main(EXAMPLE_COMMAND + ["-o", str(tmp_path / "seq1.csv")]) == 0
    assert (tmp_path / "seq1.csv").read_bytes() == (ROOT / "examples" / "dryer_seq1.csv").read_bytes()


def test_main_command_diagnoses_the_bundled_example(capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    assert main(["run", "specs/dryer.jmlg", "examples/dryer_seq1.csv"]) == 0
    text = capsys.readouterr().out
    for segment in ("t 1\u201371: normal", "t 72\u2013239: fan", "t 706\u20131000: fan"):
        assert segment in text
    assert float(text.split("diagnosis error: ")[1].split(" %")[0]) < 2.0


def test_simulate_takes_inputs_from_a_csv(files, tmp_path, capsys):
    spec, _ = files
    inputs = tmp_path / "in.csv"
    inputs.write_text("one\n1\n2\n\n3\n")
    assert main(["simulate", str(spec), "--inputs", str(inputs), "--seed", "0"]) == 0
    rows = list(csv.DictReader(capsys.readouterr().out.splitlines()))
    assert [r["one"] for r in rows] == ["1", "2", "3"]
    assert main(["simulate", str(spec), "--inputs", str(inputs), "--steps", "5"]) == 2
    assert "has 3 rows, fewer than --steps 5" in capsys.readouterr().err


def test_run_draws_the_diagnosis_figure(files, capsys, tmp_path):
    spec, data = files
    png = tmp_path / "diagnosis.png"
    assert main(["run", str(spec), str(data), "--plot", str(png)]) == 0
    assert f"figure: {png}" in capsys.readouterr().out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_run_prefilter_feeds_the_causal_moving_average_to_the_filter(files, tmp_path):
    spec, data = files
    out = tmp_path / "out.csv"
    assert main(["run", str(spec), str(data), "--prefilter", "ma:3", "-o", str(out)]) == 0
    raw = [float(r["temp"]) for r in csv.DictReader(data.open())]
    table = list(csv.DictReader(out.open()))
    seen = [float(r["temp_pred"]) + float(r["temp_resid"]) for r in table]  # what the filter was given
    assert seen[0] == pytest.approx(raw[0], abs=1e-8)
    assert seen[1] == pytest.approx((raw[0] + raw[1]) / 2, abs=1e-8)
    assert seen[500] == pytest.approx(sum(raw[498:501]) / 3, abs=1e-8)


def test_run_rejects_a_malformed_prefilter(files, capsys):
    spec, data = files
    assert main(["run", str(spec), str(data), "--prefilter", "mean:3"]) == 2
    assert "write ma:K for a moving average over K readings" in capsys.readouterr().err


def test_particles_for_a_filter_without_particles_is_refused(files, capsys):
    spec, data = files
    for algorithm in ("imm", "exact"):
        assert main(["run", str(spec), str(data), "--filter", algorithm, "--particles", "50"]) == 2
        err = capsys.readouterr().err
        assert err == (f"error: --particles: the {algorithm} filter uses no particles (the particle filters "
                       "are pf, rbpf, la-rbpf, fc-rbpf)\n")
    assert main(["run", str(spec), str(data), "--filter", "rbpf", "--particles", "5", "--seed", "1"]) == 0
    assert "filter rbpf with 5 particles" in capsys.readouterr().out


def test_one_change_point_is_one(tmp_path, capsys):
    data = tmp_path / "one.csv"
    rows = ["time,temp,mode"] + [f"{t},{50.5 if t < 30 else 44.2},{'normal' if t < 30 else 'fan'}" for t in range(60)]
    data.write_text("\n".join(rows) + "\n")
    assert main(["run", str(ROOT / "specs" / "dryer.jmlg"), str(data)]) == 0
    assert "NAB (1 change point): standard" in capsys.readouterr().out
