"""The spec writer: repr-exact numbers, and writing then loading gives back the same model."""

from pathlib import Path

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.learn.writer import matrix, number, write_spec
from jmlgdsl.model import Model, ModelError


def test_numbers_read_back_exactly():
    for x in (0.0, -0.0, 15.0, -3.0, 0.1, 1 / 3, -2.5e-17, 6.02e23, 1e15, np.nextafter(1.0, 2.0)):
        assert float(number(x)) == x
    assert number(15.0) == "15" and number(-0.0) == "0" and number(0.994) == "0.994"
    assert matrix([[1, 0.5], [-2, 0]]) == "[1 0.5; -2 0]"
    assert matrix([1.5, 2]) == "[1.5; 2]"


def random_model(seed=5):
    """Two modes, two states, two inputs (one without a default), offsets and feedthrough, full B."""
    rng = np.random.default_rng(seed)
    K, nx, ny, nu = 2, 2, 1, 2
    P = rng.random((K, K)) + np.eye(K)
    return Model.from_arrays(
        A=rng.normal(size=(K, nx, nx)) / 3, B=np.tril(rng.normal(size=(K, nx, nx))) / 10,
        C=rng.normal(size=(K, ny, nx)), D=rng.random((K, ny, ny)) + 0.1, F=rng.normal(size=(K, nx, nu)),
        G=rng.normal(size=(K, ny, nu)), f=rng.normal(size=(K, nx)), g=rng.normal(size=(K, ny)),
        P=P / P.sum(1, keepdims=True), p0=[0.3, 0.7], mu0=rng.normal(size=(K, nx)) * 50,
        Sigma0=np.diag(rng.random(nx)), modes=("normal", "leak"), states=("x1", "x2"),
        inputs=("valve", "pump"), outputs=("level",), input_defaults=[0.5, np.nan], dt=0.1,
        name="tank", descriptions={"leak": 'A "small" leak'}, engineering_units={"level": "cm", "valve": "%"})


def test_written_spec_loads_back_to_the_same_model(tmp_path):
    model = random_model()
    path = tmp_path / "tank.jmlg"
    path.write_text(write_spec(model, "Learned from tank.csv\nsecond line"))
    back = jmlgdsl.load(path)
    for key in ("A", "B", "C", "D", "F", "G", "f", "g", "P", "p0", "mu0", "Sigma0"):
        assert np.allclose(getattr(back, key), getattr(model, key), rtol=1e-12, atol=0), key
    assert back.input_defaults[0] == 0.5 and np.isnan(back.input_defaults[1])
    assert (back.name, back.dt, back.modes, back.states, back.inputs, back.outputs) == \
        ("tank", 0.1, ("normal", "leak"), ("x1", "x2"), ("valve", "pump"), ("level",))
    assert back.engineering_units == model.engineering_units
    assert back.descriptions == {"leak": "A 'small' leak"}


def test_uniform_rests_are_written_as_rules_and_read_back_exactly(tmp_path):
    dryer = jmlgdsl.load(Path(__file__).resolve().parents[1] / "specs" / "dryer.jmlg")
    text = write_spec(dryer)
    assert "initial     normal 0.988, otherwise uniform\ntransitions stay 0.994, otherwise uniform\n" in text
    path = tmp_path / "dryer.jmlg"
    path.write_text(text)
    back = jmlgdsl.load(path)
    for key in ("A", "B", "C", "D", "F", "G", "f", "g", "P", "p0", "mu0", "Sigma0", "input_defaults"):
        assert np.array_equal(getattr(back, key), getattr(dryer, key)), key
    assert back.descriptions == dryer.descriptions


def test_header_becomes_comments():
    text = write_spec(random_model(), "first\nsecond")
    assert text.startswith("# first\n# second\nplant tank\nsample 0.1 s\n")


def test_correlated_initial_states_cannot_be_written():
    model = random_model().replace(Sigma0=np.array([[1.0, 0.2], [0.2, 1.0]]))
    with pytest.raises(ModelError, match="Sigma0 must be diagonal"):
        write_spec(model)
