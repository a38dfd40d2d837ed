"""Gross errors: a reading beyond the outlier gate under every hypothesis is left out, as if it had
not been measured, at most MAX_REJECTIONS steps in a row; the gate is per output and can be off."""

import numpy as np
import pytest
from infer_models import dryer

import jmlgdsl
from jmlgdsl.infer.online import MAX_REJECTIONS
from jmlgdsl.simulate import simulate

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


def test_a_change_that_lasts_is_taken_after_the_cap(data):
    model, sim = data
    jumped = sim.y + np.where(np.arange(len(sim.y))[:, None] >= 30, 40.0, 0.0)  # 40 degC up and staying
    f = jmlgdsl.Filter(model)
    rejected = [f.step(y).rejected is not None for y in jumped]
    assert rejected[30:30 + MAX_REJECTIONS] == [True] * MAX_REJECTIONS
    assert not any(rejected[30 + MAX_REJECTIONS:])


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
    y = sim.y + np.where(np.arange(len(sim.y))[:, None] >= 30, 40.0, 0.0)  # a lasting change at 30 ...
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
