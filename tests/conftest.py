"""What every test shares: the installed jmlgdsl, not the checkout's, the spec-error checks, a model
file with data simulated from it, and the fixtures of live servers (mosquitto brokers, a diagnosed
store and its page; their helpers are in monitor_servers.py).

The suite tests the package as a user has it. `python -m pytest` puts the working directory (the
checkout) first on sys.path, where the source tree would shadow the installed distribution, so the
checkout is taken off the path here before anything imports jmlgdsl, and a session whose jmlgdsl
still comes from the checkout (an editable install) stops with a message. A developer iterating on
the source may set JMLGDSL_TEST_SOURCE=1 to test the checkout instead; CI never does.
"""

import os
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]  # the checkout: its specs/ and examples/ are the tests' data
# The environment the suite started with: a test's subprocess that must compute exactly as this process
# does gets it back (a library that starts worker processes may set OPENBLAS_NUM_THREADS=1 and the like
# in os.environ, and BLAS sums a long product in another order with another number of threads).
STARTUP_ENV = dict(os.environ)
SOURCE = os.environ.get("JMLGDSL_TEST_SOURCE") == "1"
if SOURCE:
    sys.path.insert(0, str(ROOT))
else:
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != ROOT]

import jmlgdsl  # noqa: E402  (after the path is settled)

if not SOURCE and Path(jmlgdsl.__file__).resolve().is_relative_to(ROOT):
    raise pytest.UsageError(
        f"jmlgdsl is imported from the checkout ({Path(jmlgdsl.__file__).parent}), not from an installed "
        "distribution: install it with 'python -m pip install .[test]' (not -e), or set "
        "JMLGDSL_TEST_SOURCE=1 to test the source tree on purpose")

from infer_models import dryer  # noqa: E402

from jmlgdsl.compile.lower import compile_text  # noqa: E402
from jmlgdsl.data import write_columns  # noqa: E402
from jmlgdsl.errors import SpecError  # noqa: E402
from jmlgdsl.simulation.linear import simulate  # noqa: E402


def jmlgdsl_command() -> list[str]:
    """The installed `jmlgdsl` console script (beside this Python), as a user runs it; with
    JMLGDSL_TEST_SOURCE=1, the checkout's package through this Python."""
    if SOURCE:
        return [sys.executable, "-m", "jmlgdsl"]
    script = shutil.which("jmlgdsl", path=str(Path(sys.executable).parent))
    if script is None:
        raise pytest.UsageError(f"no jmlgdsl console script beside {sys.executable}: install the package")
    return [script]


def errors_of(text, path):
    """The diagnostics of a spec that must fail to compile."""
    with pytest.raises(SpecError) as info:
        compile_text(text, path)
    return info.value.diagnostics


def assert_located(text, path, line, column, fragment):
    """Compiling `text` reports `fragment` at path:line:column, shown with its source line and a caret."""
    diagnostics = errors_of(text, path)
    found = [d for d in diagnostics if fragment in d.message]
    assert found, f"no diagnostic containing {fragment!r} in {[d.format() for d in diagnostics]}"
    d = found[0]
    assert (d.file, d.line, d.column) == (path, line, column), d.format()
    shown = d.format().splitlines()
    assert shown[0].startswith(f"{path}:{line}:{column}: ")
    assert shown[1].strip() == text.splitlines()[line - 1].strip()
    assert shown[2].index("^") - 4 == column - 1


def dryer_files(folder, modes, seed, data="seq.csv"):
    """The tests' dryer (infer_models.dryer) saved as folder/dryer.json, and data simulated from it on
    the mode schedule `modes` with `seed` in folder/`data`, as `jmlgdsl simulate` writes them:
    (spec, data)."""
    model, spec = dryer(), folder / "dryer.json"
    model.save(spec)
    write_columns(folder / data, simulate(model, modes=modes, seed=seed).columns())
    return spec, folder / data


# ------------------------------------------------------------------ live servers (monitor_servers.py)

@pytest.fixture
def broker(tmp_path):
    """A test's mosquittos (monitor_servers.Brokers), every one stopped after it."""
    from monitor_servers import Brokers

    brokers = Brokers(tmp_path)
    yield brokers
    for port in list(brokers.running):
        brokers.stop(port)


@pytest.fixture(scope="module")
def dryer_store(tmp_path_factory):
    """A store of the bundled dryer recording, diagnosed to its end."""
    from monitor_servers import DATA, SPEC

    from jmlgdsl.cli import main

    path = str(tmp_path_factory.mktemp("page") / "dryer.db")
    assert main(["monitor", SPEC, "--source", str(DATA), "--store", path, "--no-follow"]) == 0
    return path


@pytest.fixture
def store(dryer_store, tmp_path):
    """A copy of it, for a test that acts on its alarms."""
    import sqlite3

    copy = tmp_path / "dryer.db"
    with sqlite3.connect(dryer_store) as source, sqlite3.connect(copy) as target:
        source.backup(target)
    return str(copy)


@pytest.fixture
def page(store):
    """The page of that copy, served on a free port of 127.0.0.1 while the test runs."""
    from jmlgdsl.page import Page

    served = Page(store, "127.0.0.1", 0).start()
    yield served
    served.stop()
