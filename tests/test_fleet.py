"""A fleet's diagnosis with one vectorised filter (jmlgdsl.diagnosis.fleet.Fleet): each unit's evidence
per sensor is, bit for bit, what diagnosing it alone gives, through missing readings, gross errors the
gate leaves out and units that stop early; and a fleet's filter saved unit by unit (Units.state) and
put back into a new one (Units.restore) goes on as if it had never stopped."""

import numpy as np
import pytest
from infer_models import random_model
from test_units_batched import fleet_data

import jmlgdsl
from jmlgdsl import sealed
from jmlgdsl.data import Row
from jmlgdsl.diagnosis import Diagnosis, Options
from jmlgdsl.diagnosis.fleet import Fleet
from jmlgdsl.infer.units import Units


def rows_of(y, u):
    return [Row(t + 1, float(t), y[t], u[t], None) for t in range(len(y))]


@pytest.mark.parametrize("spec, algorithm", [("dryer", "imm"), ("wide", "imm"), ("dryer", "la-rbpf")])
def test_the_evidence_of_every_unit_is_its_own_bit_for_bit(spec, algorithm):
    """Under imm the evidence comes from the fleet's vectorised filter; under la-rbpf from each unit's
    engine, stepped with the others of its group."""
    model = (jmlgdsl.load("specs/dryer.jmlg") if spec == "dryer"
             else random_model(np.random.default_rng(8), K=3, nx=3, ny=6, stay=0.98))
    ys, us = fleet_data(model, 6, 150)
    records = [rows_of(y, u) for y, u in zip(ys, us)]
    particles = {"particles": 5, "seed": 3} if algorithm != "imm" else {}
    # alarms rise and clear on both plants
    options = Options(explain=True, threshold=0.4, persistence=2, algorithm=algorithm, **particles)
    fleet = Fleet(model, len(records), options, scored=False)
    assert fleet.filter is not None  # one filter for every unit
    kept = [[] for _ in records]
    for unit, found in zip(fleet.units, kept):
        unit.sinks.append(type("Sink", (), {"collect": lambda self, done, found=found: found.append(done)})())
    fleet.run(records)
    screened = alarms = 0
    for rows, found, unit in zip(records, kept, fleet.units):
        alone = []
        single = Diagnosis(model, options, scored=False,
                           sinks=[type("Sink", (), {"collect": lambda self, done: alone.append(done)})()]).run(rows)
        assert len(found) == len(alone) == len(rows)
        assert (unit.alarms.raised, unit.summary.segments) == (single.alarms.raised, single.summary.segments)
        for a, b in zip(found, alone):
            screened += b.step.rejected is not None
            alarms += b.alarm
            np.testing.assert_equal((a.alarm, a.step.t, a.step.loglik, a.step.ess, a.step.rejected),
                                    (b.alarm, b.step.t, b.step.loglik, b.step.ess, b.step.rejected))
            assert (a.evidence is None) == (b.evidence is None)
            if a.evidence is not None:
                assert (a.evidence.mode, a.evidence.healthy, a.evidence.total) == \
                       (b.evidence.mode, b.evidence.healthy, b.evidence.total)
                np.testing.assert_array_equal(a.evidence.terms, b.evidence.terms)
            np.testing.assert_array_equal(a.step.mode_posterior, b.step.mode_posterior)
    assert alarms and screened  # the gate left readings out somewhere, and those rows' evidence is the redone step's


def test_a_fleet_filter_saved_unit_by_unit_goes_on_bit_for_bit():
    model = random_model(np.random.default_rng(8), K=3, nx=3, ny=6, stay=0.98)
    ys, us = fleet_data(model, 5, 120)
    T = min(len(y) for y in ys)

    def steps(units, span):
        return [units.step(np.array([y[t] for y in ys]), np.array([u[t] for u in us])) for t in span]

    whole = Units(model, 5, "imm")
    uninterrupted = steps(whole, range(T))
    first = Units(model, 5, "imm")
    steps(first, range(60))
    saved = sealed.seal([first.state(i) for i in range(5)], {})  # as a monitor's store keeps them
    second = Units(model, 5, "imm")
    for i, state in enumerate(sealed.unseal(saved)):
        second.restore(i, state)
    for a, b in zip(steps(second, range(60, T)), uninterrupted[60:]):
        for field in a._fields:
            assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field
    assert np.array_equal(second.loglik, whole.loglik) and np.array_equal(second.t, whole.t)


def test_a_diagnosis_stepped_from_outside_holds_each_row_until_its_record_comes_back():
    """The steps a fleet drives a unit's Diagnosis through: `hold` a row (its readings pre-filtered),
    step the filter, `heard` (the evidence handed in, the engine's predictive dropped), `finished`
    with each record the filter gives back, which pairs it with the oldest row held."""
    model = jmlgdsl.load("specs/dryer.jmlg")
    sim = jmlgdsl.simulate(model, 8, seed=3)
    rows = rows_of(sim.y, sim.u)
    unit = Diagnosis(model, Options(lag=2, prefilter=2, explain=True))
    done = []
    for i, row in enumerate(rows):
        readings = unit.hold(row)
        np.testing.assert_allclose(readings, sim.y[max(0, i - 1):i + 1].mean(axis=0))
        step = unit.filter.step(readings, row.u)
        unit.heard(evidence=f"evidence of row {i + 1}")
        assert unit.filter.engine.predictive is None  # no part of the saved state
        if step is not None:
            done.append(unit.finished(step))
    done += unit.finish()
    assert [d.row for d in done] == rows and [d.step.t for d in done] == list(range(1, len(rows) + 1))
    assert [d.evidence for d in done] == [f"evidence of row {t}" for t in range(1, len(rows) + 1)]
    assert unit.summary.T == len(rows)


def test_checking_many_files_tables_looks_at_each_path_once(tmp_path, monkeypatch):
    """`run` on a fleet's files checks, before any work, that no table would be one of the files: each
    path is looked at on the file system a few times, not once for every other file (200 files took
    over a second, as long as diagnosing them)."""
    import os

    from jmlgdsl.diagnosis.fleet import check_tables
    from jmlgdsl.errors import JmlgError

    count = 200
    paths = [tmp_path / f"u{k:03d}.csv" for k in range(count)]
    for path in paths:
        path.write_text("time,temp\n0,50\n")
    looks = [0]
    for name in ("stat", "lstat"):
        def counted(*args, _real=getattr(os, name), **kwargs):
            looks[0] += 1
            return _real(*args, **kwargs)
        monkeypatch.setattr(os, name, counted)
    check_tables(str(tmp_path / "tables"), [str(p) for p in paths], inputs=["spec.jmlg"])
    assert looks[0] < 50 * count
    with pytest.raises(JmlgError, match="tables/u007.csv is also an input"):
        check_tables(str(tmp_path / "tables"), [str(p) for p in paths], inputs=[str(tmp_path / "tables/u007.csv")])


def test_whole_files_are_diagnosed_as_arrays_each_unit_as_alone(tmp_path, monkeypatch):
    """`run` on many files whose units one vectorised filter steps (imm, no lag, pre-filter or
    evidence) diagnoses them as arrays over (step, unit), no unit's Diagnosis finishing a row at a
    time; each unit's table, steps, last mode, alarms raised, diagnosis error and scale warning are
    those of its file diagnosed alone: records of other lengths, rows without a true mode, a file
    without a time column, a record shorter than the scale check's rows."""
    import csv
    import warnings
    from pathlib import Path

    from jmlgdsl.diagnosis.files import diagnose_file
    from jmlgdsl.diagnosis.fleet import diagnose_files
    from jmlgdsl.diagnosis.pipeline import Diagnosis

    model = jmlgdsl.load("specs/dryer.jmlg")
    with open("examples/dryer_seq1.csv", newline="") as f:
        header, *rows = list(csv.reader(f))
    unlabelled = [r[:] for r in rows[100:900]]
    for r in unlabelled[::3]:
        r[3] = ""
    centi = [r[:2] + [str(100 * float(r[2]))] + r[3:] for r in rows]  # degC written as centi-degC
    bodies = {"a": (header, rows), "b": (header, unlabelled), "long": (header, centi),
              "short": (header, centi[:30]), "untimed": (header[1:], [r[1:] for r in rows[:700]])}
    paths = []
    for name, (head, body) in bodies.items():
        paths.append(str(tmp_path / f"{name}.csv"))
        with open(paths[-1], "w", newline="") as f:
            csv.writer(f).writerows([head] + body)
    options = Options(healthy=("normal",), threshold=0.3, persistence=2)

    alone, said = [], []
    for path in paths:
        table = tmp_path / f"alone_{Path(path).name}"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            diagnosis = diagnose_file(model, path, options, output=str(table)).diagnosis
        said += [str(w.message) for w in caught]
        alone.append((diagnosis.summary.T, model.modes[diagnosis.summary.current], diagnosis.alarms.raised,
                      diagnosis.summary.diagnosis_error, table.read_text()))
    monkeypatch.setattr(Diagnosis, "finished", lambda *args: pytest.fail("a unit's row finished alone"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        history = diagnose_files(model, paths, options)
    assert [str(w.message) for w in caught] == said and len(said) == 2  # the long record's at its 50th row first
    assert [(u.steps, u.last_mode, u.alarms, u.error, u.table) for u in history.units] == alone
    assert history.batched and [u.steps for u in history.units] == [1000, 800, 1000, 30, 700]
    assert history.units[1].error is not None and history.units[4].table.startswith("t,map_mode,")
