"""The history of many data files on a Ray cluster (`jmlgdsl run SPEC *.csv -o OUT/ --cluster auto`):
the files in chunks, each chunk a Fleet in a Ray task, every table the same bytes as the run without
a cluster; a bad file's error as the user gets it without a cluster; the refusals. Every Ray here is a
local one bound to 127.0.0.1 (`--cluster auto`), and each test stops the Ray it started."""

import csv
import importlib.util
import io
import re
import subprocess
import time

import pytest
from conftest import ROOT, SOURCE, STARTUP_ENV, jmlgdsl_command

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.diagnosis.cluster import ClusterError, connect, disconnect
from jmlgdsl.diagnosis import Options
from jmlgdsl.diagnosis.fleet import diagnose_files
from jmlgdsl.errors import DataError

SPEC = str(ROOT / "specs" / "dryer.jmlg")
needs_ray = pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                               reason="Ray is not installed (pip install '.[cluster]')")


@pytest.fixture(scope="module")
def unit_files(tmp_path_factory):
    """Five dryers' records of different lengths, more files than this machine's CPUs (two chunks or more)."""
    folder = tmp_path_factory.mktemp("units")
    with open(ROOT / "examples" / "dryer_seq1.csv", newline="") as f:
        header, *rows = list(csv.reader(f))
    paths = []
    for k, (start, stop) in enumerate([(0, 1000), (100, 700), (200, 900), (0, 300), (500, 1000)]):
        body = [r[:] for r in rows[start:stop]]
        for r in body[::7]:  # each unit its own readings
            r[2] = str(float(r[2]) + 0.1 * k)
        paths.append(folder / f"unit{k}.csv")
        with open(paths[-1], "w", newline="") as f:
            csv.writer(f).writerows([header] + body)
    return paths


@pytest.fixture(scope="module")
def ray_cluster():
    """One local Ray for the tests that call the library, stopped after them."""
    pytest.importorskip("ray", reason="Ray is not installed (pip install '.[cluster]')")
    yield connect("auto")
    disconnect()


class Terminal(io.StringIO):
    def isatty(self):
        return True


@needs_ray
@pytest.mark.parametrize("options", [Options(), Options(algorithm="la-rbpf", particles=5, seed=3),
                                     Options(lag=5, prefilter=3, healthy=("normal", "grill"))])
def test_chunks_on_a_cluster_give_every_units_table_and_summary_as_one_fleet(ray_cluster, unit_files, options):
    model = jmlgdsl.load(SPEC)
    paths = [str(p) for p in unit_files]
    here = diagnose_files(model, paths, options)
    shown = Terminal()
    there = diagnose_files(model, paths, options, cluster="auto", progress=shown)
    assert [u.path for u in there.units] == paths
    assert there.units == here.units  # the tables byte for byte, the summaries field by field
    assert there.batched == here.batched == (options.lag == 0)  # smoothing steps unit after unit
    assert "] 5/5 files" in shown.getvalue()  # the files counted as their chunks finish


@needs_ray
@pytest.mark.filterwarnings("ignore::jmlgdsl.data.DataWarning")  # the header-only file's: no temp measured
def test_a_bad_file_in_a_chunk_is_the_users_error_as_without_a_cluster(ray_cluster, unit_files, tmp_path):
    model = jmlgdsl.load(SPEC)
    lines = unit_files[1].read_text().splitlines(keepends=True)
    lines[50] = re.sub(r"^([^,]*),([^,]*),[^,]*", r"\1,\2,oops", lines[50])
    bad = tmp_path / "bad.csv"
    bad.write_text("".join(lines))
    empty = tmp_path / "empty.csv"
    empty.write_text(lines[0])
    for wrong, message in ((bad, f"{bad}:51: column 'temp': 'oops' is not a number"), (empty, f"{empty}: no data rows")):
        paths = [str(unit_files[0]), str(wrong), *map(str, unit_files[2:])]
        with pytest.raises(DataError) as alone:
            diagnose_files(model, paths)
        with pytest.raises(DataError) as clustered:
            diagnose_files(model, paths, cluster="auto")
        assert str(clustered.value) == str(alone.value) == message


def without_timing(text):
    return re.sub(r"[\d.]+ us per unit-step", "... us per unit-step", text)


@needs_ray
def test_run_with_cluster_auto_writes_the_same_tables_and_lines_as_without(unit_files, tmp_path, capsys,
                                                                          monkeypatch):
    """End to end, as a user runs it: the command in its own process starts a local Ray and stops it."""
    names = [p.name for p in unit_files]
    folder = unit_files[0].parent
    monkeypatch.chdir(folder)  # relative paths, as typed: the tasks read them from the driver's folder
    assert main(["run", SPEC, *names, "-o", str(tmp_path / "alone"), "--lag", "3"]) == 0
    alone = capsys.readouterr().out
    env = {**STARTUP_ENV, **({"PYTHONPATH": str(ROOT)} if SOURCE else {})}
    done = subprocess.run([*jmlgdsl_command(), "run", SPEC, *names, "-o", str(tmp_path / "cluster"), "--lag", "3",
                           "--cluster", "auto"], cwd=folder, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert without_timing(done.stdout) == without_timing(alone).replace(str(tmp_path / "alone"),
                                                                        str(tmp_path / "cluster"))
    for name in names:
        assert (tmp_path / "cluster" / name).read_bytes() == (tmp_path / "alone" / name).read_bytes()


def test_cluster_with_one_data_file_is_refused_before_any_work(unit_files, tmp_path, capsys):
    assert main(["run", SPEC, str(unit_files[0]), "-o", str(tmp_path / "t.csv"), "--cluster", "auto"]) == 2
    assert "--cluster spreads several data files over a Ray cluster; with one file, leave it out" in (
        capsys.readouterr().err)
    assert not list(tmp_path.iterdir())


def test_an_address_where_nothing_answers_is_refused_at_once(unit_files, capsys):
    start = time.perf_counter()
    with pytest.raises(ClusterError, match=r"--cluster 127.0.0.1:9: nothing answers there"):
        connect("127.0.0.1:9")
    with pytest.raises(ClusterError, match="give HOST:PORT"):
        connect("127.0.0.1")
    assert main(["run", SPEC, *map(str, unit_files[:2]), "--cluster", "127.0.0.1:9"]) == 2
    assert "is the cluster's head started (ray start --head)?" in capsys.readouterr().err
    assert time.perf_counter() - start < 5
