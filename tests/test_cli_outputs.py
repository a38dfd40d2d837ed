"""run, learn and prbs check their outputs and numbers before any work (issue 14, items 12, 15-17)."""

import pytest
from infer_models import dryer

from jmlgdsl.cli import main
from jmlgdsl.data import write_columns
from jmlgdsl.simulate import simulate


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("outputs")
    spec, data = folder / "dryer.json", folder / "seq.csv"
    dryer().save(spec)
    write_columns(data, simulate(dryer(), modes="1-20:normal,21-40:fan", seed=1).columns())
    return spec, data


def refused(argv, capsys, message):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_run_refuses_to_write_over_its_data(files, capsys):
    spec, data = files
    before = data.read_bytes()
    refused(["run", str(spec), str(data), "-o", str(data)], capsys, "")
    assert data.read_bytes() == before


@pytest.mark.parametrize("plot, message", [("fig.txt", "--plot"), ("missing/fig.png", "missing")])
def test_run_checks_the_figure_path_before_filtering(files, capsys, tmp_path, plot, message):
    spec, data = files
    refused(["run", str(spec), str(data), "--plot", str(tmp_path / plot)], capsys, message)


def test_run_refuses_zero_particles(files, capsys):
    spec, data = files
    refused(["run", str(spec), str(data), "--filter", "la-rbpf", "--particles", "0"], capsys, "--particles")


def test_learn_checks_its_output_and_sample_time(files, capsys, tmp_path):
    _, data = files
    refused(["learn", "--mode", f"normal={data}", "--output", "temp", "--dt", "1", "-o", str(data)], capsys, "")
    with pytest.raises(SystemExit):
        main(["learn", "--mode", f"normal={data}", "--output", "temp", "--dt", "inf", "-o", str(tmp_path / "s.jmlg")])
    assert capsys.readouterr().err.endswith("error: argument --dt: expected a finite number, not 'inf'\n")
    assert not (tmp_path / "s.jmlg").exists()


@pytest.mark.parametrize("extra, message", [
    (["--amplitude", "nan"], "argument --amplitude: expected a finite number, not 'nan'"),
    (["--around", "inf"], "argument --around: expected a finite number, not 'inf'"),
    (["--dt", "inf"], "argument --dt: expected a finite number, not 'inf'"),
    (["--dt", "0"], "argument --dt: must be positive, not 0"),
    (["--settling", "-5"], "argument --settling: must be positive, not -5"),
])
def test_prbs_refuses_unusable_numbers_as_it_reads_them(capsys, tmp_path, extra, message):
    with pytest.raises(SystemExit) as done:
        main(["prbs", "--cells", "5", "-o", str(tmp_path / "u.csv"), *extra])
    assert done.value.code == 2 and capsys.readouterr().err.endswith(f"error: {message}\n")
    assert not (tmp_path / "u.csv").exists()


def test_prbs_refuses_a_sequence_too_long_to_write(capsys, tmp_path):
    refused(["prbs", "--cells", "20", "--periods", "1000", "-o", str(tmp_path / "u.csv")], capsys, "GiB")


def test_run_warns_about_an_output_in_another_unit(files, capsys, tmp_path):
    import csv

    spec, data = files
    rows = list(csv.DictReader(data.open()))
    scaled = tmp_path / "centi.csv"
    write_columns(scaled, {"temp": [100 * float(r["temp"]) for r in rows]})  # degC written as centi-degC
    assert main(["run", str(spec), str(scaled)]) == 0
    err = capsys.readouterr().err
    assert "warning: output 'temp': its residuals are about" in err and "times the model's noise" in err
    assert main(["run", str(spec), str(data)]) == 0
    assert "residuals are about" not in capsys.readouterr().err  # data in the spec's unit: no warning


def test_simulate_says_what_it_wrote_as_compile_does(files, capsys, tmp_path):
    spec, _ = files
    out = tmp_path / "sim.csv"
    assert main(["simulate", str(spec), "--steps", "7", "--seed", "1", "-o", str(out)]) == 0
    assert capsys.readouterr().out == f"wrote {out} (7 rows, 4 modes)\n"
    assert main(["compile", str(spec), "-o", str(tmp_path / "m.npz")]) == 0
    assert capsys.readouterr().out.startswith(f"wrote {tmp_path / 'm.npz'} (4 modes")
    assert main(["simulate", str(spec), "--steps", "7", "--seed", "1"]) == 0
    assert capsys.readouterr().out.startswith("time,")  # to standard output: the data alone
