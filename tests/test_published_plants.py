"""Each published plant compiles to its published numbers (method.md §5)."""

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.errors import SpecWarning

SPECS = "specs/"


def load(name):
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1]
    return jmlgdsl.load(root / SPECS / f"{name}.jmlg")


def steady_state(m):
    """F u + f over 1 - A for scalar plants under their default inputs."""
    drive = (m.F @ np.nan_to_num(m.input_defaults))[:, 0] + m.f[:, 0]
    return drive / (1 - m.A[:, 0, 0])


def test_dryer_is_the_zero_order_hold_of_its_fopdt_models():
    m = load("dryer")
    tau = np.array([30.45, 25.10, 41.68, 32.96])
    y_ss = np.array([50.52, 44.16, 54.76, 46.99])
    gain = np.array([1.94, 1.44, 2.34, 1.61])
    assert m.modes == ("normal", "fan", "grill", "fan_grill")
    np.testing.assert_allclose(m.A[:, 0, 0], np.exp(-1 / tau), rtol=1e-12)
    # The published EM-refined A (Table 5.3) agrees to its printed digits.
    np.testing.assert_allclose(m.A[:, 0, 0], [0.9676, 0.9609, 0.9762, 0.9701], atol=1.5e-4)
    np.testing.assert_allclose(steady_state(m), y_ss, rtol=1e-12)
    np.testing.assert_allclose(m.F[:, 0, 0], gain * (1 - np.exp(-1 / tau)), rtol=1e-12)
    np.testing.assert_allclose(m.mu0[:, 0], y_ss)
    np.testing.assert_allclose(m.B[:, 0, 0], 0.05)
    np.testing.assert_allclose(m.D[:, 0, 0], 0.05)
    np.testing.assert_allclose(m.P, np.full((4, 4), 0.002) + np.eye(4) * 0.992)
    np.testing.assert_allclose(m.p0, [0.988, 0.004, 0.004, 0.004])
    assert m.dt == 1.0 and m.inputs == ("current",) and m.outputs == ("temp",)
    assert m.input_defaults.tolist() == [15.0]
    assert m.descriptions["fan_grill"] == "Faulty fan and grill"


PUBLISHED = {
    "level_tank4": dict(
        A=[0.9801, 0.9829, 0.9910, 0.9872], F=[0.3099, 0.5368, 0.6163, 0.3544], x0=[15.54, 31.40, 68.84, 27.61],
        B=0.008, D=0.08, dt=1.0,
        P=[[0.996, 0.002, 0, 0.002], [0.002, 0.996, 0.002, 0], [0, 0.004, 0.996, 0], [0.002, 0, 0, 0.998]],
        p0=[0.99, 0.001, 0.001, 0.008]),
    "level_tank5": dict(
        A=[0.9864, 0.9886, 0.9880, 0.9894, 0.9925], F=[0.2169, 0.3484, 0.8285, 0.2574, 0.3114],
        x0=[15.93, 30.61, 69.00, 24.39, 41.52], B=0.05, D=0.05, dt=1.0,
        P=[[0.995, 0.002, 0.002, 0.001, 0], [0.001, 0.997, 0.001, 0, 0.001], [0.001, 0.002, 0.997, 0, 0],
           [0.001, 0, 0, 0.998, 0.001], [0, 0.001, 0, 0.001, 0.998]],
        p0=[0.996, 0.001, 0.001, 0.001, 0.001]),
    "heat_exchanger": dict(
        A=[0.9818, 0.9817, 0.981, 0.9858, 0.9786], F=[0.7209, 0.7591, 0.7970, 0.6695, 1.0999],
        x0=[39.63, 41.69, 44.03, 47.23, 51.44], B=0.005, D=0.05, dt=2.0,
        P=[[0.997, 0.0015, 0.001, 0.0005, 0], [0.001, 0.997, 0.001, 0.00075, 0.00025],
           np.array([0.0005, 0.002, 0.997, 0.001, 0]) / 1.0005, [0.00025, 0.00075, 0.001, 0.997, 0.001],
           [0, 0.0005, 0.001, 0.0015, 0.997]],
        p0=[0.0005, 0.001, 0.997, 0.001, 0.0005]),
    "robot_smooth": dict(
        A=[0.72977, 0.7385, 0.69264, 0.74912], F=[0.15183, 0.13171, 0.13108, 0.08982],
        x0=[0.56187, 0.5037, 0.4265, 0.35805], B=0.005, D=0.005, dt=0.1,
        P=[[0.99425, 0.005, 0.0005, 0.00025], [0.005, 0.9895, 0.005, 0.0005], [0.0005, 0.005, 0.9895, 0.005],
           [0.00025, 0.0005, 0.005, 0.99425]],
        p0=[0.9825, 0.01, 0.005, 0.0025]),
    "robot8": dict(
        A=[0.7298, 0.7385, 0.6926, 0.7491, 0.6101, 0.7032, 0.8194, 0.8430],
        F=[0.1518, 0.1317, 0.1311, 0.0898, 0.2043, 0.1379, 0.0727, 0.0499],
        x0=[0.5619, 0.5037, 0.4265, 0.3581, 0.5240, 0.4645, 0.4028, 0.3179], B=0.005, D=0.005, dt=0.1,
        P=None, p0=[0.9825, 0.01, 0.005, 0.0025, 0, 0, 0, 0]),
}


@pytest.mark.filterwarnings("ignore::jmlgdsl.SpecWarning")
@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_published_plant(name):
    want = PUBLISHED[name]
    m = load(name)
    np.testing.assert_allclose(m.A[:, 0, 0], want["A"], rtol=0, atol=1e-12)
    A, F = np.array(want["A"]), np.array(want["F"])
    np.testing.assert_allclose(steady_state(m), F / (1 - A), rtol=1e-12)
    np.testing.assert_allclose(m.mu0[:, 0], want["x0"], atol=1e-12)
    np.testing.assert_allclose(m.B[:, 0, 0], want["B"])
    np.testing.assert_allclose(m.D[:, 0, 0], want["D"])
    np.testing.assert_allclose(m.C[:, 0, 0], 1.0)
    assert m.dt == want["dt"]
    if want["P"] is not None:
        np.testing.assert_allclose(m.P, np.array(want["P"], dtype=float), atol=1e-15)
    np.testing.assert_allclose(m.p0, want["p0"])
    np.testing.assert_allclose(m.P.sum(axis=1), 1.0, atol=1e-15)


def test_robot8_transitions_follow_the_published_row_and_floor_pattern():
    m = load("robot8")
    np.testing.assert_allclose(m.P[0], [0.99, 0.005, 0.0005, 0.00025, 0.00425, 0, 0, 0])
    smooth = load("robot_smooth").P
    np.testing.assert_allclose(m.P[1:4, :4], smooth[1:4])
    np.testing.assert_allclose(m.P[4:, 4:], smooth)


def test_every_shipped_spec_checks_without_a_warning():
    """A shipped spec is an example to copy: `jmlgdsl check` on it says ok and nothing else (the heat
    exchanger's printed row 3, which sums to 1.0005, is written divided by its sum)."""
    import pathlib
    import warnings

    specs = sorted((pathlib.Path(__file__).resolve().parents[1] / SPECS).glob("*.jmlg"))
    assert len(specs) >= 8
    for path in specs:
        with warnings.catch_warnings():
            warnings.simplefilter("error", SpecWarning)
            jmlgdsl.load(path)


@pytest.mark.filterwarnings("ignore::jmlgdsl.SpecWarning")
def test_every_block_form_is_used_by_the_published_specs():
    import pathlib

    text = "".join(p.read_text() for p in (pathlib.Path(__file__).resolve().parents[1] / "specs").glob("*.jmlg"))
    for form in ("fopdt(", "arx(", "~ Normal(", "A = ", " like "):
        assert form in text
