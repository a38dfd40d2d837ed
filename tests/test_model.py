"""The Model type: construction from arrays, validation, and lossless files."""

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl import JmlgError, Model, ModelError


def random_model(seed=0, K=3, nx=2, ny=2, nu=1):
    rng = np.random.default_rng(seed)
    P = rng.random((K, K))
    return Model.from_arrays(
        A=rng.normal(size=(K, nx, nx)) * 0.3, B=rng.normal(size=(K, nx, nx)), C=rng.normal(size=(K, ny, nx)),
        D=np.eye(ny) * 0.1 + 0.01 * rng.random((K, ny, ny)), P=P / P.sum(1, keepdims=True), p0=np.ones(K) / K,
        mu0=rng.normal(size=(K, nx)), Sigma0=np.eye(nx) * np.pi, F=rng.normal(size=(K, nx, nu)),
        G=rng.normal(size=(K, ny, nu)), f=rng.normal(size=(K, nx)), g=rng.normal(size=(K, ny)),
        modes=("a", "b", "c"), input_defaults=[np.nan], dt=0.1 / 3, name="rnd",
        descriptions={"a": "first"}, engineering_units={"y1": "m"})


def same(m1, m2):
    for key in ("A", "B", "C", "D", "F", "G", "f", "g", "P", "p0", "mu0", "Sigma0"):
        assert np.array_equal(getattr(m1, key), getattr(m2, key)), key
    assert np.array_equal(m1.input_defaults, m2.input_defaults, equal_nan=True)
    assert (m1.modes, m1.states, m1.inputs, m1.outputs, m1.dt, m1.name) == \
           (m2.modes, m2.states, m2.inputs, m2.outputs, m2.dt, m2.name)
    assert m1.descriptions == m2.descriptions and m1.engineering_units == m2.engineering_units


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_save_and_read_are_lossless(tmp_path, suffix):
    m = random_model()
    m.save(tmp_path / f"m{suffix}")
    same(m, jmlgdsl.load(tmp_path / f"m{suffix}"))


def test_model_files_keep_the_key_units_for_the_engineering_units(tmp_path):
    """Model.engineering_units are written under "units", the key model files have always used, so files
    written before and after read alike."""
    m = random_model()
    assert m.to_dict()["units"] == {"y1": "m"}
    m.save(tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz") as z:
        assert '"units": {"y1": "m"}' in str(z["meta"])


def test_mat_export_puts_the_mode_axis_last(tmp_path):
    from scipy.io import loadmat

    m = random_model()
    m.save(tmp_path / "m.mat")
    mat = loadmat(tmp_path / "m.mat")
    assert mat["A"].shape == (2, 2, 3)
    np.testing.assert_array_equal(mat["A"][:, :, 1], m.A[1])
    np.testing.assert_array_equal(mat["P"], m.P)
    assert [str(cell[0]) for cell in mat["modes"].ravel()] == ["a", "b", "c"]  # a cell array of names


def test_arrays_are_read_only_and_derived_covariances_follow():
    m = random_model()
    with pytest.raises(ValueError):
        m.A[0, 0, 0] = 1.0
    np.testing.assert_allclose(m.Q, m.B @ np.swapaxes(m.B, 1, 2))
    np.testing.assert_allclose(m.R[2], m.D[2] @ m.D[2].T)


def test_from_arrays_promotes_single_mode_matrices():
    m = Model.from_arrays(A=[[0.9]], B=0.1, C=[[1.0]], D=0.2, P=[[1.0]], p0=[1.0], mu0=[3.0], Sigma0=0.5)
    assert (m.K, m.nx, m.ny, m.nu) == (1, 1, 1, 0)
    assert m.modes == ("mode1",) and m.outputs == ("y1",)
    assert m.Sigma0.tolist() == [[0.5]]


@pytest.mark.parametrize("change,message", [
    (dict(P=[[0.5, 0.4, 0.1], [0.5, 0.5, 0.1], [0, 0, 1]]), "every row of P must be a probability vector"),
    (dict(p0=[0.5, 0.6, -0.1]), "p0 must be a probability vector"),
    (dict(C=np.zeros((3, 2, 3))), r"C must have shape \(3, 2, 2\)"),
    (dict(D=np.zeros((3, 2, 2))), "measurement noise D D' must be positive definite"),
    (dict(modes=("a", "b")), "2 modes named for 3"),
])
def test_inconsistent_models_are_rejected(change, message):
    m = random_model()
    with pytest.raises(ModelError, match=message):
        m.replace(**change)


def test_reading_a_foreign_json_file_is_a_clear_error(tmp_path):
    (tmp_path / "x.json").write_text('{"hello": 1}')
    with pytest.raises(ModelError, match="not a jmlgdsl model file"):
        Model.read(tmp_path / "x.json")


def test_compiled_spec_round_trips_through_the_cli(tmp_path, capsys):
    import pathlib

    from jmlgdsl.cli import main

    spec = pathlib.Path(__file__).resolve().parents[1] / "specs" / "dryer.jmlg"
    assert main(["compile", str(spec), "-o", str(tmp_path / "dryer.json")]) == 0
    assert "wrote" in capsys.readouterr().out
    same(jmlgdsl.load(spec), jmlgdsl.load(tmp_path / "dryer.json"))


@pytest.mark.parametrize("name,content,message", [
    ("missing.json", None, "cannot read model file .*missing.json: No such file"),
    ("broken.json", "{bad", "broken.json: not a readable jmlgdsl model file"),
    ("partial.json", '{"format": "jmlgdsl-model"}', "partial.json: not a complete jmlgdsl model file: 'A' is missing"),
    ("broken.npz", "not a zip", "broken.npz: not a readable jmlgdsl model file"),
])
def test_unreadable_model_files_are_model_errors_naming_the_file(tmp_path, name, content, message):
    if content is not None:
        (tmp_path / name).write_text(content)
    with pytest.raises(ModelError, match=message):
        jmlgdsl.load(tmp_path / name)


def test_an_unwritable_model_file_is_a_clear_error(tmp_path):
    with pytest.raises(JmlgError, match="^cannot write .*m.json: No such file or directory$"):
        random_model().save(tmp_path / "no" / "such" / "folder" / "m.json")


def test_a_model_file_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    path = tmp_path / "m.json"
    path.write_text("the old model")
    monkeypatch.setattr(Model, "to_dict", lambda self: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        random_model().save(path)
    assert path.read_text() == "the old model" and [p.name for p in tmp_path.iterdir()] == ["m.json"]


def test_cli_reports_a_damaged_model_file_without_traceback(tmp_path, capsys):
    from jmlgdsl.cli import main

    (tmp_path / "m.json").write_text("{bad")
    assert main(["check", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert "m.json: not a readable jmlgdsl model file" in err and "Traceback" not in err


def test_a_model_without_states_is_validated_like_any_other():
    A, B, C = np.zeros((0, 0)), np.zeros((0, 0)), np.zeros((1, 0))
    m = Model.from_arrays(A=A, B=B, C=C, D=0.5, P=1, p0=1, mu0=np.zeros(0), Sigma0=np.zeros((0, 0)))
    assert (m.nx, m.ny) == (0, 1) and m.R.tolist() == [[[0.25]]]
    with pytest.raises(ModelError, match="measurement noise D D' must be positive definite"):
        m.replace(D=np.zeros((1, 1, 1)))


def test_inputs_of_the_wrong_size_are_a_model_error():
    m = random_model()
    assert m.resolve_inputs(np.arange(4.0), 4).tolist() == [[0.0], [1.0], [2.0], [3.0]]
    with pytest.raises(ModelError, match=r"inputs must be 4 steps x 1 \(u1\), got shape \(3,\)"):
        m.resolve_inputs(np.arange(3.0), 4)
