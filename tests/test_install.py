"""The package as a user installs it: every module and data file of the source tree is in the installed
distribution, and every command, the README's set-up line, its tour and its Python example run from a
folder that is not the checkout, through the installed `jmlgdsl` console script."""

import argparse
import importlib
import importlib.metadata
import json
import os
import pkgutil
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path

import pytest
from conftest import ROOT, SOURCE, jmlgdsl_command

import jmlgdsl
from jmlgdsl.cli import build_parser

pytestmark = pytest.mark.skipif(SOURCE, reason="JMLGDSL_TEST_SOURCE=1 tests the checkout, not an installation")

README = (ROOT / "README.md").read_text()
# The data a README line reads: a user has them in the clone; the tests copy them into an empty folder.
DATA_FOLDERS = ("specs", "examples")


def _shipped(path: Path) -> bool:
    """Whether a file of the source tree belongs in the wheel: code, the grammar and the page's files."""
    return path.suffix in (".py", ".lark", ".html", ".js", ".css") and "__pycache__" not in path.parts


def test_every_module_and_data_file_of_the_source_tree_is_installed():
    source = {(Path(folder) / name).relative_to(ROOT).as_posix()  # through the link to grammars/ too
              for folder, _, names in os.walk(ROOT / "jmlgdsl", followlinks=True)
              for name in names if _shipped(Path(folder) / name)}
    installed = {f.as_posix() for f in importlib.metadata.files("jmlgdsl") if _shipped(Path(f.as_posix()))}
    assert {"jmlgdsl/grammars/jmlg.lark", "jmlgdsl/fitting/__init__.py", "jmlgdsl/page/static/page.js"} <= source
    assert source - installed == set(), "in the source tree but not installed"
    assert installed - source == set(), "installed but not in the source tree (a stale build?)"


def test_ci_pins_every_lower_bound_pyproject_declares():
    """.ci/oldest.txt, with which .ci/run runs the suite a second time, pins exactly the lower bound
    of each dependency and test extra pyproject.toml declares: a bound raised in one and not the other
    would leave CI testing versions nobody declared."""
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirement = re.compile(r"^([A-Za-z0-9_.-]+)(?:\[[^]]*\])?>=([0-9][0-9.]*)\s*(;.*)?$")

    def release(version):  # 7 and 7.0 are one release
        return re.sub(r"(\.0)+$", "", version)

    declared = {}
    for line in project["dependencies"] + project["optional-dependencies"]["test"]:
        name, bound, marker = requirement.match(line).groups()
        declared[name.lower()] = (release(bound), (marker or "").replace("'", '"').strip("; "))
    pinned = {}
    for line in (ROOT / ".ci" / "oldest.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            pin, _, marker = line.partition(";")
            name, version = pin.strip().split("==")
            pinned[name.lower()] = (release(version), marker.strip())
    assert pinned == declared


def test_every_installed_module_imports():
    names = [m.name for m in pkgutil.walk_packages(jmlgdsl.__path__, "jmlgdsl.") if m.name != "jmlgdsl.__main__"]
    assert "jmlgdsl.fitting.estimate" in names
    for name in names:
        assert not Path(importlib.import_module(name).__file__).resolve().is_relative_to(ROOT), name


def test_the_distribution_names_its_license():
    meta = importlib.metadata.metadata("jmlgdsl")
    assert meta["License-Expression"] == "MIT"
    assert any(Path(f.as_posix()).name == "LICENSE" for f in importlib.metadata.files("jmlgdsl"))


@pytest.fixture
def user_folder(tmp_path):
    """An empty folder holding only copies of the README's data, and an environment whose `jmlgdsl`
    is the installed console script."""
    for name in DATA_FOLDERS:
        shutil.copytree(ROOT / name, tmp_path / name)
    script = Path(jmlgdsl_command()[0])
    env = {**os.environ, "PATH": f"{script.parent}{os.pathsep}{os.environ.get('PATH', '')}", "MPLBACKEND": "Agg"}
    env.pop("PYTHONPATH", None)
    return tmp_path, env


def _run(line, folder, env, timeout=300):
    done = subprocess.run(["bash", "-c", f"set -o pipefail; {line}"], cwd=folder, env=env, capture_output=True,
                          text=True, timeout=timeout)
    assert done.returncode == 0, f"{line}\n{done.stdout}\n{done.stderr}"
    assert "Traceback" not in done.stderr, done.stderr
    return done


def _commands():
    """Every subcommand the installed command line offers."""
    sub, = (a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert {"run", "fit", "learn", "bench"} <= set(sub.choices)
    return list(sub.choices)


@pytest.mark.parametrize("command", _commands())
def test_every_command_explains_itself(command, tmp_path):
    done = subprocess.run(jmlgdsl_command() + [command, "--help"], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0 and done.stderr == ""
    assert done.stdout.startswith(f"usage: jmlgdsl {command}")


def test_no_arguments_lists_the_commands(tmp_path):
    done = subprocess.run(jmlgdsl_command(), cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 2
    for command in _commands():
        assert re.search(rf"^\s+{command}\s+\S", done.stdout + done.stderr, flags=re.M), command


def _block(heading):
    """The first code block after a README heading."""
    return re.search(rf"^## {heading}\n.*?```\w*\n(.*?)```", README, flags=re.S | re.M).group(1)


def _tour():
    """The tour's command lines, comments taken off."""
    return [line.split("  #")[0].strip() for line in _block("A short tour").splitlines() if line.strip()]


def test_the_set_up_line_runs_the_bundled_example(user_folder):
    folder, env = user_folder
    install, main_job = _block("Set up").splitlines()[0].split(" && ")
    assert install == "python -m pip install ."
    assert main_job.startswith("jmlgdsl run ")  # the console script: `python -m` would run a checkout's source
    out = _run(main_job, folder, env).stdout
    assert "diagnosis error: 1.00 % (10 of 1000 steps)" in out


def test_every_tour_line_runs_from_an_empty_folder(user_folder):
    folder, env = user_folder
    lines = [line for line in _tour() if not line.startswith(("tail ", "jmlgdsl dashboard "))]  # they run on
    assert len(lines) >= 8
    for line in lines:
        _run(line, folder, env)
    for made in ("dryer.mat", "sim.csv", "result.csv", "result.png", "fitted.jmlg"):
        assert (folder / made).stat().st_size > 0, made


def test_the_readme_stream_prints_each_row_as_it_is_appended(user_folder):
    """The tour's `tail -f` line, run as written on a file the test appends to row by row: each
    row's result is out before the next row is written."""
    folder, env = user_folder
    line, = (line for line in _tour() if line.startswith("tail "))
    logged = folder / re.search(r"(\S+\.csv)", line).group(1)
    rows = ["time,current,temp", "0,15,50.5", "1,15,50.4", "2,15,50.6"]
    logged.write_text(rows[0] + "\n" + rows[1] + "\n")
    proc = subprocess.Popen(["bash", "-c", line], cwd=folder, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    lines = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    try:
        assert lines.get(timeout=60).startswith("t,time,map_mode,p_normal")
        for number, row in enumerate(rows[1:], start=1):
            if number > 1:
                with logged.open("a") as f:
                    f.write(row + "\n")
            assert lines.get(timeout=60).startswith(f"{number},{number - 1},normal,")
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)


def test_the_readme_dashboard_serves_the_store_the_tour_made(user_folder):
    folder, env = user_folder
    tour = _tour()
    for line in tour[:next(i for i, line in enumerate(tour) if line.startswith("jmlgdsl monitor ")) + 1]:
        if line.startswith(("jmlgdsl simulate ", "jmlgdsl monitor ")):
            _run(line, folder, env)
    line, = (line for line in tour if line.startswith("jmlgdsl dashboard "))
    url = re.search(r"open (http://\S+)", _block("A short tour")).group(1)
    proc = subprocess.Popen(["bash", "-c", line], cwd=folder, env=env, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        assert proc.stderr.readline().strip() == f"the operator's page: {url}/"
        with urllib.request.urlopen(url + "/api/run", timeout=60) as answer:
            assert json.load(answer)["plant"] == "dryer"
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)


def test_the_readme_python_example_runs(user_folder):
    folder, env = user_folder
    code = re.search(r"From Python:\n\n```python\n(.*?)```", README, flags=re.S).group(1)
    done = subprocess.run([sys.executable, "-c", code], cwd=folder, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert (folder / "result.csv").read_text().startswith("t,map_mode,p_normal,")
