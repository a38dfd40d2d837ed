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
