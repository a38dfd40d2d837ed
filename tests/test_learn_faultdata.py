"""Learning from recordings as a plant gives them: 52 sensors, one stuck at a constant in a fault,
two pairs exactly collinear (proportional control loops), one rounded to 0.1, one fault that drifts
away, no inputs. `jmlgdsl learn` models what the data cannot resolve, says so per mode and sensor
before fitting, keeps every mode stable, and writes a spec that loads and runs."""

import contextlib
import io

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl.cli import main
from jmlgdsl.data import write_columns
from jmlgdsl.learn import arx, basis
from jmlgdsl.learn.resolution import at_least, noise_floor, resolution, unresolved

NY, T = 52, 150
NAMES = [f"s{i + 1}" for i in range(NY)]
STUCK, QUANTISED, DRIFTING = 10, 7, 30  # s11 stuck at 42 in `stuck`; s8 rounded to 0.1; s31 runs away in `drift`


def recordings(seed=3) -> dict[str, np.ndarray]:
    """{mode: y (T, NY)}: a stable VAR(1) around levels in assorted units; s2 = 2.5 s1 and
    s6 = 3 - 0.5 s5 exactly in every mode; s8 rounded to 0.1; `stuck` holds s11 at 42.0; `bias`
    shifts s21; in `drift` s31 grows by 1.5 % a step."""
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((NY, NY)) / np.sqrt(NY)
    A = 0.9 * M / np.abs(np.linalg.eigvals(M)).max()
    level, scale = rng.uniform(10, 100, NY), rng.uniform(0.1, 10, NY)

    def record(fault=None):
        x, out = np.zeros(NY), []
        for t in range(T + 50):
            before, x = x[DRIFTING], A @ x + rng.standard_normal(NY)
            if fault == "drift":
                x[DRIFTING] = 1.015 * before + 0.5
            out.append(x.copy())
        y = np.array(out[50:]) * scale + level
        y[:, 1] = 2.5 * y[:, 0]
        y[:, 5] = 3.0 - 0.5 * y[:, 4]
        y[:, QUANTISED] = np.round(y[:, QUANTISED], 1)
        if fault == "stuck":
            y[:, STUCK] = 42.0
        if fault == "bias":
            y[:, 20] += 5 * scale[20]
        return y

    return {mode: record(mode) for mode in ("normal", "stuck", "bias", "drift")}


def test_resolution_is_the_rounding_step_or_a_fraction_of_the_spread():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((500, 3)) * [1.0, 5.0, 1.0]
    x[:, 0] = np.round(x[:, 0], 1)
    x[:, 2] = 7.0
    r = resolution(x)
    assert r[0] == pytest.approx(0.1)  # the step of rounding
    assert r[1] == pytest.approx(1e-3 * x[:, 1].std())  # continuous: no finer than 1e-3 of the spread
    assert r[2] == pytest.approx(7e-3)  # never moves: 1e-3 of its magnitude
    assert noise_floor(0.1) == pytest.approx(0.01 / 12)


def test_a_floor_raises_only_the_directions_below_it():
    """A singular covariance (two collinear outputs) becomes positive definite, at least the floor in
    every direction, while a direction well above the floor is kept."""
    v = np.array([1.0, 2.0]) / np.sqrt(5)
    S = 4.0 * np.outer(v, v)  # variance 4 along v, none across it
    floor = np.array([1e-4, 1e-4])
    raised = at_least(S, floor)
    assert np.allclose(raised, raised.T)
    assert v @ raised @ v == pytest.approx(4.0)
    across = np.array([2.0, -1.0]) / np.sqrt(5)
    assert across @ raised @ across == pytest.approx(1e-4)
    assert np.linalg.eigvalsh(raised - np.diag(floor)).min() > -1e-15
    assert np.array_equal(at_least(np.diag([1.0, 2.0]), floor), np.diag([1.0, 2.0]))


def test_unresolved_outputs_are_named_in_groups():
    y = recordings()["stuck"]
    groups = unresolved([y], resolution(y))
    assert groups == [(0, 1), (4, 5), (STUCK,)]  # the quantised s8 moves: it is resolved


def test_least_squares_leaves_out_what_the_data_cannot_resolve():
    """A constant output and collinear ones give a rank-deficient regression: the fit is finite, its
    constant output is predicted exactly, and the residual covariance keeps a finite log-determinant."""
    y = recordings()["stuck"]
    fit = arx.fit_arx(y, None, 1, 1, 0)
    assert np.isfinite(fit.theta).all() and np.isfinite(fit.bic)
    assert np.abs(fit.theta[:-1, STUCK]).max() < 1e-9 and fit.theta[-1, STUCK] == pytest.approx(42.0)
    sd = np.where(y.std(axis=0) > 0, y.std(axis=0), 1.0)
    standardised = fit.theta[:-1] * sd[:, None] / sd
    assert np.abs(standardised).max() < 3  # none growing without bound on the collinear pairs


def test_an_unstable_mode_is_scaled_inside_the_unit_circle_keeping_its_level():
    rng = np.random.default_rng(1)
    Phi = np.array([[1.02, 0.1, 0.0, 0.0], [0.0, 0.5, 0.0, 0.0]])  # order 2, two outputs
    mode = basis.LaggedMode(basis.Lags(2), Phi, np.zeros((2, 0)), np.array([0.3, 1.0]), np.eye(2), np.eye(2))
    level = rng.uniform(1, 10, 2)
    fixed = basis.stabilised(mode, level)
    assert np.abs(fixed.poles()).max() == pytest.approx(basis.MAX_RADIUS)
    lags = np.tile(level, 2)
    assert np.allclose(fixed.Phi @ lags + fixed.c, mode.Phi @ lags + mode.c)
    rho = basis.MAX_RADIUS / np.abs(mode.poles()).max()
    assert np.allclose(fixed.poles(), rho * mode.poles())


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    """`jmlgdsl learn` on the four recordings, 52 outputs, every mode by EM on its own (what the
    relative learning of few rows does is tests/test_learn_defaults.py's): (folder, the spec's path,
    standard error's lines, the report on standard output)."""
    folder = tmp_path_factory.mktemp("faultdata")
    argv = ["learn", "--output", ",".join(NAMES), "--dt", "180", "--order", "1", "--max-iter", "4",
            "--relative-to", "none", "--catch-all", "none"]
    for mode, y in recordings().items():
        write_columns(folder / f"{mode}.csv", {"time": np.arange(T) * 180.0, **dict(zip(NAMES, y.T))})
        argv += ["--mode", f"{mode}={folder / mode}.csv"]
    spec = folder / "learned.jmlg"
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        assert main(argv + ["-o", str(spec)]) == 0
    return folder, spec, err.getvalue().splitlines(), out.getvalue()


def test_learn_says_what_it_floors_before_fitting_and_why_it_changed_a_mode(learned):
    _, spec, err, report = learned
    # What the data cannot resolve is said per mode and sensor before any mode is fitted.
    early = err[:next(i for i, line in enumerate(err) if line.startswith("learned mode 1"))]
    step = resolution(np.vstack(list(recordings().values())))[STUCK]  # from s11's moves in the other modes
    floor = f"floored at rounding, sd s11 {step / np.sqrt(12):.3g}"
    assert f"mode stuck: s11 is constant at 42 (a stuck sensor or valve): measurement noise {floor}" in early
    for mode in ("normal", "stuck", "bias", "drift"):
        assert any(line.startswith(f"mode {mode}: s1, s2 move together exactly") for line in early)
        assert any(line.startswith(f"mode {mode}: s5, s6 move together exactly") for line in early)
    assert not any("s8" in line for line in early)  # rounded to 0.1, but it moves
    # The runaway mode is made stable, and says why, as soon as it is fitted and in the report.
    assert any(line.startswith("mode drift: poles scaled from modulus 1.0") for line in err)
    assert "poles scaled from modulus 1.0" in report and floor in report
    assert "fit 0.0 %" not in report and "no simulation fit (without inputs" in report
    assert "not converged: last gain" in report
    assert floor in spec.read_text()  # the floor is stated in the spec's comments


def test_the_spec_loads_and_runs_and_names_the_stuck_fault(learned):
    folder, spec, _, _ = learned
    model = jmlgdsl.load(spec)
    assert model.ny == NY and model.modes == ("normal", "stuck", "bias", "drift")
    assert all(np.abs(np.linalg.eigvals(A)).max() < 1 for A in model.A)
    for mode in ("stuck", "normal"):  # the stuck sensor names its fault, and only there
        assert main(["run", str(spec), str(folder / f"{mode}.csv"), "-o", str(folder / "diagnosis.csv")]) == 0
        rows = np.genfromtxt(folder / "diagnosis.csv", delimiter=",", names=True, dtype=None, encoding=None)
        assert ((rows["map_mode"] == "stuck") == (mode == "stuck")).all()


def test_collinear_outputs_stay_collinear_in_the_learned_noise(learned):
    """In the learned bank the noise across the collinear pair s1, s2 = 2.5 s1 is the rounding
    floor, not zero and not the sensors' own spread."""
    _, spec, _, _ = learned
    model = jmlgdsl.load(spec)
    R = model.D[0] @ model.D[0].T
    across = np.array([2.5, -1.0]) / np.hypot(2.5, 1)
    floor = noise_floor(resolution(np.vstack(list(recordings().values()))))
    assert across @ R[:2, :2] @ across == pytest.approx(across ** 2 @ floor[:2], rel=0.5)
    assert R[0, 0] > 1e4 * floor[0]
