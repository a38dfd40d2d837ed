"""Every complete spec shown in docs/language.md compiles, so the reference stays true."""

import pathlib
import re

import pytest

from jmlgdsl.compile.lower import compile_text

DOC = pathlib.Path(__file__).resolve().parents[1] / "docs" / "language.md"
BLOCKS = [b for b in re.findall(r"```jmlg\n(.*?)```", DOC.read_text(), flags=re.S) if "plant " in b]


def test_the_reference_shows_several_complete_specs():
    assert len(BLOCKS) >= 6


@pytest.mark.parametrize("text", BLOCKS, ids=[re.search(r"plant (\w+)", b).group(1) for b in BLOCKS])
def test_documented_spec_compiles(text):
    model = compile_text(text, str(DOC))
    assert model.K >= 1 and model.nx >= 1
