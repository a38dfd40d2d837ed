"""The usage example in the docstring of every public package runs as written, from the repository
root (where its specs/ and examples/ are), against the installed package."""

import doctest
import importlib

import pytest
from conftest import ROOT

PACKAGES = ["jmlgdsl", "jmlgdsl.infer", "jmlgdsl.diagnosis", "jmlgdsl.learn", "jmlgdsl.fitting", "jmlgdsl.studies",
            "jmlgdsl.monitor", "jmlgdsl.page"]


@pytest.mark.parametrize("name", PACKAGES)
def test_the_package_example_runs(name, monkeypatch):
    monkeypatch.chdir(ROOT)
    package = importlib.import_module(name)
    assert ">>> " in package.__doc__, f"{name} has no usage example"
    failed, tried = doctest.testmod(package, optionflags=doctest.ELLIPSIS, report=True)
    assert tried >= 3 and failed == 0


def test_diagnose_is_public_beside_load_filter_and_smooth(monkeypatch):
    """`jmlgdsl.diagnose` is the pipeline's short form (jmlgdsl.diagnosis.diagnose), and the example in
    its docstring runs as written."""
    import jmlgdsl
    from jmlgdsl.diagnosis import diagnose

    monkeypatch.chdir(ROOT)
    assert jmlgdsl.diagnose is diagnose and "diagnose" in jmlgdsl.__all__
    [test] = doctest.DocTestFinder().find(jmlgdsl.diagnose, "diagnose", globs={})
    assert test.examples and doctest.DocTestRunner(optionflags=doctest.ELLIPSIS).run(test).failed == 0
