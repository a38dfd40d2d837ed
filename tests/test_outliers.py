"""Gross errors: a reading beyond the outlier gate under every hypothesis is left out, as if it had
not been measured, at most MAX_REJECTIONS steps in a row, and every time if it is absurd (ABSURD times
beyond the gate plus the farthest a switch of mode moves the outputs); the gate is per output and can
be off."""

import numpy as np
import pytest
from infer_models import dryer

import jmlgdsl
from jmlgdsl.infer.online import MAX_REJECTIONS
from jmlgdsl.simulation.linear import simulate

SCHEDULE = "1-40:normal,41-80:fan"


@pytest.fixture(scope="module")
def data():
    model = dryer()
    sim = simulate(model, modes=SCHEDULE, seed=2)
    return model, sim


@pytest.mark.parametrize("algorithm, particles", [("imm", None), ("la-rbpf", 10), ("fc-rbpf", 4), ("exact", None)])
def test_a_wild_reading_is_the_same_as_a_missing_one(data, algorithm, particles):
    model, sim = data
    wild, missing = sim.y.copy(), sim.y.copy()
    wild[30], missing[30] = 1e9, np.nan  # (row 4 of the short exact run)
    if algorithm == "exact":
        wild, missing = wild[26:33], missing[26:33]  # 4^7 histories at most
    a = jmlgdsl.filter(model, wild, algorithm=algorithm, particles=particles, seed=1)
    b = jmlgdsl.filter(model, missing, algorithm=algorithm, particles=particles, seed=1)
    np.testing.assert_array_equal(a.mode_posterior, b.mode_posterior)
    np.testing.assert_array_equal(a.state_mean, b.state_mean)


def test_the_step_reports_the_rejected_reading(data):
    model, sim = data
    f = jmlgdsl.Filter(model)
    steps = [f.step(y) for y in np.where(np.arange(len(sim.y))[:, None] == 30, -1e9, sim.y)]
    assert [s.t for s in steps if s.rejected is not None] == [31]
    assert steps[30].rejected.tolist() == [True] and steps[30].residual[0] < -1e8


def span(model):
    """The largest distance between two of the dryer's steady-state temperatures (its input is 1)."""
    return np.ptp((model.F[:, 0, 0] + model.f[:, 0]) / (1.0 - model.A[:, 0, 0]))


@pytest.mark.parametrize("algorithm", ["imm", "rbpf", "la-rbpf", "fc-rbpf"])
@pytest.mark.parametrize("size", [1, -1, 3])
def test_a_change_that_lasts_is_taken_after_the_cap(data, algorithm, size):
    # a step up or down as large as the modes' steady states lie apart (10.4 degC, 150 predicted SD),
    # or three times that (a fault the modes do not describe), staying: the plant, not the sensor.
    # (The bootstrap PF is left out: it moves its particles only by the process noise, so no gate
    # lets it follow a step this size.)
    model, sim = data
    step = size * span(model)
    jumped = sim.y + np.where(np.arange(len(sim.y))[:, None] >= 30, step, 0.0)
    f = jmlgdsl.Filter(model, algorithm, seed=1)
    steps = [f.step(y) for y in jumped]
    rejected = [s.rejected is not None for s in steps]
    assert rejected[30:30 + MAX_REJECTIONS] == [True] * MAX_REJECTIONS
    assert not any(rejected[30 + MAX_REJECTIONS:])
    followed = np.array([s.state_mean[0] for s in steps[30 + MAX_REJECTIONS + 3:]])
    np.testing.assert_allclose(followed, sim.x[30 + MAX_REJECTIONS + 3:, 0] + step, atol=0.1 * abs(step))  # followed


def test_the_gate_is_per_output_and_can_be_off(data):
    model, sim = data
    wild = sim.y.copy()
    wild[30] = 1e9
    off = model.replace(outlier_gate=np.array([np.inf]))
    kept = jmlgdsl.filter(off, wild)
    assert kept.state_mean[30, 0] > 1e6  # the reading was used
    assert jmlgdsl.filter(model, wild).state_mean[30, 0] < 100


def test_the_gate_round_trips_through_model_files(tmp_path, data):
    model, _ = data
    off = model.replace(outlier_gate=np.array([np.inf]))
    for suffix in (".json", ".npz"):
        np.testing.assert_array_equal(jmlgdsl.Model.read(off.save(tmp_path / f"m{suffix}")).outlier_gate, [np.inf])
    with pytest.raises(jmlgdsl.ModelError, match="outlier_gate must hold 1 positive"):
        model.replace(outlier_gate=np.array([0.0]))


def test_the_gate_is_armed_again_once_readings_are_plausible(data):
    model, sim = data
    y = sim.y + np.where(np.arange(len(sim.y))[:, None] >= 30, span(model), 0.0)  # a lasting change at 30 ...
    y[70] = 1e9  # ... and a glitch once the filter has followed it
    f = jmlgdsl.Filter(model)
    rejected = [f.step(row).rejected is not None for row in y]
    assert [t for t, r in enumerate(rejected) if r] == [30, 31, 70]


@pytest.fixture(scope="module")
def cstr10():
    model = jmlgdsl.load("specs/cstr10.jmlg")
    sim = simulate(model, modes=f"1-120:{model.modes[0]},121-160:{model.modes[3]}", seed=5)
    return model, sim


@pytest.mark.parametrize("algorithm, particles, back", [("imm", None, 5), ("fc-rbpf", 4, 5), ("rbpf", 100, 20),
                                                        ("la-rbpf", 10, 20), ("pf", 200, 20)])
@pytest.mark.parametrize("sign", [1, -1])
def test_one_wild_reading_in_every_output_does_not_derail_the_diagnosis(cstr10, algorithm, particles, back, sign):
    model, sim = cstr10
    y = sim.y.copy()
    y[60] = sign * 1e9
    result = jmlgdsl.filter(model, y, sim.u, algorithm=algorithm, particles=particles, seed=3)
    clean = jmlgdsl.filter(model, sim.y, sim.u, algorithm=algorithm, particles=particles, seed=3)
    window = slice(60 + back, 120)
    assert (clean.map_modes[window] == sim.modes[window]).all()  # the clean run is right there ...
    assert (result.map_modes[window] == sim.modes[window]).all()  # ... and so is the run with the glitch
    assert np.isfinite(result.mode_posterior).all()


def burst(y, start, sign, rows=50):
    """y with `rows` readings of +-1e9 (alternating, the first with `sign`) from row `start`: a
    sensor that fails and comes back."""
    y = y.copy()
    y[start:start + rows] = sign * 1e9 * (-1.0) ** np.arange(rows)[:, None]
    return y


@pytest.mark.parametrize("algorithm, particles", [("imm", None), ("la-rbpf", 10), ("fc-rbpf", 4), ("exact", None)])
@pytest.mark.parametrize("sign", [1, -1])
def test_a_burst_of_absurd_readings_is_the_same_as_missing_ones(data, algorithm, particles, sign):
    # however long it lasts, a reading no mode could produce is left out: the filter ends where a gap
    # in the data would have left it (the selection of these filters draws after the screening, so
    # bit for bit)
    model, sim = data
    start, rows = (28, 4) if algorithm == "exact" else (20, 50)  # 4^8 histories at most for exact
    wild, missing = burst(sim.y, start, sign, rows), sim.y.copy()
    missing[start:start + rows] = np.nan
    if algorithm == "exact":
        wild, missing = wild[26:34], missing[26:34]
    a = jmlgdsl.filter(model, wild, algorithm=algorithm, particles=particles, seed=1)
    b = jmlgdsl.filter(model, missing, algorithm=algorithm, particles=particles, seed=1)
    np.testing.assert_array_equal(a.mode_posterior, b.mode_posterior)
    np.testing.assert_array_equal(a.state_mean, b.state_mean)
    assert a.rejected.any(axis=1).tolist() == np.isnan(missing).any(axis=1).tolist()


@pytest.mark.parametrize("algorithm, particles", [("imm", None), ("fc-rbpf", 4), ("rbpf", 100), ("la-rbpf", 10),
                                                  ("pf", 200)])
@pytest.mark.parametrize("sign", [1, -1])
def test_a_burst_of_garbage_in_every_output_leaves_no_trace(cstr10, algorithm, particles, sign):
    # 50 rows of +-1e9 from row 20 on the 10-mode CSTR: ten rows after the sensor is back every
    # filter is right again, as its clean run is
    model, sim = cstr10
    y = burst(sim.y, 20, sign)
    result = jmlgdsl.filter(model, y, sim.u, algorithm=algorithm, particles=particles, seed=3)
    clean = jmlgdsl.filter(model, sim.y, sim.u, algorithm=algorithm, particles=particles, seed=3)
    window = slice(80, 120)
    assert (clean.map_modes[window] == sim.modes[window]).all()
    assert (result.map_modes[window] == sim.modes[window]).all()
    assert result.rejected[20:70].all() and not result.rejected[70:120].any()


def test_a_mode_with_no_steady_state_leaves_the_cap_in_force(data):
    # an integrating mode can take the output anywhere, so no reading is beyond its reach: a lasting
    # one is taken after the cap, however large
    model, sim = data
    drifting = model.replace(A=np.concatenate([model.A[:3], np.ones((1, 1, 1))]))
    f = jmlgdsl.Filter(drifting)
    rejected = [f.step(y).rejected is not None for y in burst(sim.y, 20, 1)]
    assert [t for t, r in enumerate(rejected) if r] == list(range(20, 20 + MAX_REJECTIONS))


def test_a_filter_stepped_from_outside_through_its_gate_and_accept_goes_on_as_itself(data):
    # a change that lasts: the filter's gate leaves it out MAX_REJECTIONS steps, then stops enforcing
    model, sim = data
    jumped = sim.y + np.where(np.arange(len(sim.y))[:, None] >= 30, span(model), 0.0)
    alone, outside = jmlgdsl.Filter(model, "rbpf", seed=1), jmlgdsl.Filter(model, "rbpf", seed=1)
    enforced = []
    for y, u in zip(jumped, sim.u):
        mine = alone.step(y, u)
        enforced.append(bool(outside.gate.enforce[0]))
        theirs = outside.accept(outside.engine.step(y, np.ones(model.ny, dtype=bool), u, outside.gate), y, u)
        for field in ("t", "mode_posterior", "state_mean", "state_cov", "y_pred", "residual", "loglik", "ess"):
            assert np.array_equal(getattr(mine, field), getattr(theirs, field)), field
        assert (mine.rejected is None) == (theirs.rejected is None)
    assert enforced.index(False) == 30 + MAX_REJECTIONS  # the gate the engine was handed moved with the counts
    assert outside.t == alone.t and outside.loglik == alone.loglik
