"""Simulation: schedules, the model's equations and noise levels, the chain, reproducibility."""

import numpy as np
import pytest
from infer_models import DRYER_SEQ1, dryer

from jmlgdsl import DataError
from jmlgdsl.data import read_csv, write_columns
from jmlgdsl.simulation.linear import parse_schedule, simulate


def test_schedule_covers_the_published_sequence():
    seq = parse_schedule(DRYER_SEQ1, dryer())
    assert len(seq) == 1000
    assert (seq[:70] == 0).all() and (seq[70:238] == 1).all() and seq[238] == 2 and seq[-1] == 1


@pytest.mark.parametrize("text, message", [
    ("1-5:normal,7-9:fan", "piece '7-9:fan' should start at step 6"),
    ("1-5:normal,6-4:fan", "should start at step 6 and end after it starts"),
    ("1-5:nromal", "unknown mode 'nromal'; modes are normal, fan"),
    ("1..5:normal", "cannot read '1..5:normal'"),
])
def test_schedule_errors(text, message):
    with pytest.raises(DataError, match=message):
        parse_schedule(text, dryer())


def test_schedule_length_must_match_steps():
    with pytest.raises(DataError, match="covers steps 1-5 but 8 steps"):
        simulate(dryer(), 8, modes="1-5:normal", seed=0)


def test_states_follow_the_model_and_noise_has_its_level():
    model = dryer().replace(B=np.zeros((4, 1, 1)))
    sim = simulate(model, 3000, seed=1, modes="1-1500:fan,1501-3000:grill")
    prev = np.concatenate([[sim.x0], sim.x[:-1]])
    expect = np.einsum("tij,tj->ti", model.A[sim.modes], prev) + model.F[sim.modes, :, 0]
    np.testing.assert_allclose(sim.x, expect, rtol=1e-12)
    assert sim.x0[0] == model.mu0[1, 0]  # Sigma0 = 0 and z0 = the schedule's first mode
    v = sim.y - sim.x
    # The sample SD of 3000 normal draws has a standard error of sigma / sqrt(2 * 3000).
    assert abs(v.std() - 0.05) < 4 * 0.05 / np.sqrt(6000)


def test_chain_transitions_have_the_model_frequencies():
    model = dryer().replace(P=np.array([[0.9, 0.1, 0, 0], [0, 0.8, 0.2, 0], [0, 0, 0.5, 0.5], [0.3, 0, 0, 0.7]]))
    seq = simulate(model, 20000, seed=2).modes
    counts = np.zeros((4, 4))
    np.add.at(counts, (seq[:-1], seq[1:]), 1)
    freq = counts / counts.sum(axis=1, keepdims=True)
    se = np.sqrt(model.P * (1 - model.P) / counts.sum(axis=1, keepdims=True))
    assert np.all(np.abs(freq - model.P) <= 4.5 * se + 1e-12)


def test_same_seed_same_run_and_csv_round_trip(tmp_path):
    a = simulate(dryer(), 50, seed=7)
    b = simulate(dryer(), 50, seed=7)
    assert a.y.tobytes() == b.y.tobytes() and (a.modes == b.modes).all()
    assert list(a.columns()) == ["time", "one", "temp", "mode", "x_true"]
    path = tmp_path / "sim.csv"
    write_columns(path, a.columns())
    data = read_csv(path, dryer())
    np.testing.assert_allclose(data.y, a.y, rtol=1e-9)
    np.testing.assert_array_equal(data.modes, a.modes)


def test_steps_come_from_the_schedule_or_must_be_given():
    assert len(simulate(dryer(), modes="1-12:fan", seed=0).y) == 12
    with pytest.raises(DataError, match="number of steps"):
        simulate(dryer(), seed=0)
