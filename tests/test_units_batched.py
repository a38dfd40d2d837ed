"""Many units of one plant in one filter (jmlgdsl.infer.units) and `jmlgdsl run` on several files:
every unit's results are those of filtering its data alone, bit for bit, through missing readings,
inputs, gross errors and records of different lengths, and its table, alarms and truth those of
running it alone."""

import csv
import dataclasses
import re

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl import sealed
from jmlgdsl.cli import main
from jmlgdsl.diagnosis.pipeline import SAVED_KINDS
from jmlgdsl.errors import DataError
from jmlgdsl.infer import ALGORITHMS, Filter, FilterError, kalman
from jmlgdsl.infer.rbpf import Exact, RaoBlackwellised
from jmlgdsl.infer.result import Predictive
from jmlgdsl.infer.units import Units, _groups, filter_units
from jmlgdsl.simulation.linear import simulate

from infer_models import random_model

FIELDS = ("mode_posterior", "state_mean", "state_cov", "y_pred", "residuals", "loglik_steps", "ess", "rejected")


def fleet_data(model, units, T, seed=0):
    """Simulated records of `units` units, each spoilt its own way: a gap in the first output, a row
    with nothing measured and an absurd reading, a burst beyond the gate, every 7th reading of the
    second output missing, and lengths that differ. Every other unit moves its inputs a little a
    quarter of the way in, so the fleet's inputs agree at first (offsets shared) and then do not."""
    ys, us = [], []
    for s in range(units):
        sim = simulate(model, T + 7 * s, seed=seed + s)
        y = sim.y.copy()
        kind = s % 5
        if kind == 1:
            y[T // 5:T // 5 + 10, 0] = np.nan
        elif kind == 2:
            y[T // 3] = np.nan
            y[T // 3 + 10, -1] = 1e9
        elif kind == 3:
            y[T // 2:T // 2 + 4, 0] += 40.0
        elif kind == 4 and model.ny > 1:
            y[::7, 1] = np.nan
        u = sim.u.copy()
        if s % 2:
            u[T // 4:] += 0.05 * s
        ys.append(y)
        us.append(u)
    return ys, us


def assert_same(batched, alone):
    for field in FIELDS:
        a, b = getattr(batched, field), getattr(alone, field)
        assert np.array_equal(a, b, equal_nan=True), field
    assert batched.loglik == alone.loglik


@pytest.fixture(scope="module")
def dryer():
    return jmlgdsl.load("specs/dryer.jmlg")


@pytest.fixture(scope="module")
def wide():
    """Six outputs, modes that settle: IMM keeps its Kalman pieces on most steps."""
    return random_model(np.random.default_rng(8), K=3, nx=3, ny=6, stay=0.98)


@pytest.fixture(scope="module")
def many():
    """Nine modes (more than the 8 numbers numpy sums one after the other) and four states."""
    return random_model(np.random.default_rng(3), K=9, nx=4, ny=2, stay=0.9)


@pytest.mark.parametrize("spec", ["dryer", "cstr10", "wide", "many"])
def test_batched_imm_equals_each_unit_alone_bit_for_bit(spec, request):
    model = request.getfixturevalue(spec) if spec != "cstr10" else jmlgdsl.load("specs/cstr10.jmlg")
    ys, us = fleet_data(model, 6, 150)
    for batched, y, u in zip(filter_units(model, ys, us, algorithm="imm"), ys, us):
        assert_same(batched, jmlgdsl.filter(model, y, u, algorithm="imm"))


def own_numbers(model, units, seed):
    """`units` banks of the model's shape, each with its own numbers: dynamics, offsets, noise and
    sensor offsets moved at random (a fleet of one design whose units were each fitted)."""
    rng = np.random.default_rng(seed)
    return [model.replace(A=model.A * rng.uniform(0.97, 1.0), f=model.f + rng.normal(0, 0.3, model.f.shape),
                          g=model.g + rng.normal(0, 0.5, model.g.shape), B=model.B * rng.uniform(0.7, 1.4),
                          D=model.D * rng.uniform(0.7, 1.4))
            for _ in range(units)]


@pytest.mark.parametrize("spec", ["dryer", "wide", "many"])
def test_units_with_their_own_numbers_step_together_each_as_alone(spec, request, monkeypatch):
    """Each unit's own bank (models=), stacked under one vectorised IMM: every unit's results are those
    of filtering it alone under its own bank, bit for bit, through the same gaps, gross errors and
    inputs, and the units still step together (one covariance step for every unit of a mask)."""
    model = request.getfixturevalue(spec)
    models = own_numbers(model, 5, seed=4)
    ys, us = fleet_data(model, 5, 150, seed=1)
    calls = []
    step = kalman.covariance_step
    monkeypatch.setattr(kalman, "covariance_step", lambda *a: calls.append(a[0].shape) or step(*a))
    results = filter_units(model, ys, us, algorithm="imm", models=models)
    assert max(shape[0] for shape in calls if len(shape) == 4) >= 4  # (units, K, nx, nx): units in one call
    for batched, own, y, u in zip(results, models, ys, us):
        assert_same(batched, jmlgdsl.filter(own, y, u, algorithm="imm"))
    assert results[2].rejected.any()  # its absurd reading screened under its own bank


@pytest.mark.parametrize("algorithm, particles", [("la-rbpf", 5), ("pf", 30)])
def test_particle_filters_of_units_with_their_own_numbers_equal_each_alone(dryer, algorithm, particles):
    models = own_numbers(dryer, 2, seed=5)
    models = [models[0], models[1], models[0], models[1]]  # two banks, two units each: those step together
    ys, us = fleet_data(dryer, 4, 80, seed=3)
    results = filter_units(dryer, ys, us, algorithm=algorithm, particles=particles, seed=7, models=models)
    for batched, own, y, u in zip(results, models, ys, us):
        assert_same(batched, jmlgdsl.filter(own, y, u, algorithm=algorithm, particles=particles, seed=7))


def test_units_whose_banks_differ_in_shape_are_refused(dryer):
    other = jmlgdsl.load("specs/cstr4.jmlg")
    with pytest.raises(FilterError, match="modes, outputs, inputs, states"):
        Units(dryer, 2, models=[dryer, other])
    with pytest.raises(FilterError, match="1 banks for 2 units"):
        Units(dryer, 2, models=[dryer])
    gated = dryer.replace(outlier_gate=np.full(dryer.ny, 5.0))
    with pytest.raises(FilterError, match="gate"):
        Units(dryer, 2, models=[dryer, gated])


def test_the_wide_fleet_goes_through_every_path_of_the_step(wide, monkeypatch):
    """Kept Kalman pieces, units in groups by what they measured, and gross errors left out."""
    ys, us = fleet_data(wide, 5, 150)
    rows = []
    step = kalman.covariance_step
    monkeypatch.setattr(kalman, "covariance_step", lambda *a: rows.append(len(a[0])) or step(*a))
    results = filter_units(wide, ys, us, algorithm="imm")
    steps = sum(len(y) for y in ys)
    assert sum(rows) < 0.5 * wide.K * steps  # most unit-steps computed no mode's pieces
    assert results[2].rejected.any() and results[3].rejected.any()


@pytest.mark.parametrize("algorithm, particles, options", [
    ("pf", 30, {}), ("rbpf", 10, {}), ("la-rbpf", 5, {}), ("fc-rbpf", 3, {}),
    ("la-rbpf", 5, {"resampling": "stratified"}), ("la-rbpf", 8, {"ess_threshold": 0.6}),
    ("rbpf", 10, {"ess_threshold": 0.6}), ("pf", 30, {"resampling": "residual", "ess_threshold": 0.5})])
def test_every_particle_filter_over_units_equals_each_unit_alone(dryer, algorithm, particles, options):
    """The engines of units holding as many particles step together (`rbpf.step_together`,
    `pf.step_together`, their systematic resampling too), the others one by one; a unit whose gate
    redoes its step leaves the rest of its group as they were."""
    ys, us = fleet_data(dryer, 4, 80, seed=3)
    results = filter_units(dryer, ys, us, algorithm=algorithm, particles=particles, seed=7, **options)
    for batched, y, u in zip(results, ys, us):
        assert_same(batched, jmlgdsl.filter(dryer, y, u, algorithm=algorithm, particles=particles, seed=7, **options))
    assert results[2].rejected.any() and results[3].rejected.any()


@pytest.mark.parametrize("spare", [RaoBlackwellised.spare_nodes, -10**9])  # -10**9: compacted at every step
def test_rao_blackwellised_units_share_one_covariance_graph_each_unit_its_own_bits(dryer, monkeypatch, spare):
    """The units' engines hold one graph (each keeping its own representative of a class of nearly
    equal covariances), compacted for all of them together, and each unit's results stay those of
    its Filter alone, whose own graph is compacted on its own."""
    monkeypatch.setattr(RaoBlackwellised, "spare_nodes", spare)
    ys, us = fleet_data(dryer, 4, 60, seed=3)
    results = filter_units(dryer, ys, us, algorithm="la-rbpf", particles=5, seed=7)
    for batched, y, u in zip(results, ys, us):
        assert_same(batched, jmlgdsl.filter(dryer, y, u, algorithm="la-rbpf", particles=5, seed=7))
    fleet = Units(dryer, 3, "la-rbpf", 5, seed=1)
    for t in range(5):
        fleet.step(ys[0][t:t + 1].repeat(3, axis=0), us[0][t:t + 1].repeat(3, axis=0))
    graphs = {id(f.engine.graph) for f in fleet._filters}
    assert len(graphs) == 1 and fleet._filters[0].engine.graph.shared


@pytest.mark.parametrize("algorithm", ["la-rbpf", "pf"])
def test_particle_filters_step_their_units_together(dryer, monkeypatch, algorithm):
    ys, us = fleet_data(dryer, 6, 60)
    groups = []

    def counted(step):
        return lambda engines, *a: groups.append(len(engines)) or step(engines, *a)

    spec = ALGORITHMS[algorithm]
    monkeypatch.setitem(ALGORITHMS, algorithm, dataclasses.replace(spec, step_together=counted(spec.step_together)))
    filter_units(dryer, ys, us, algorithm=algorithm, particles=10, seed=2)
    assert sum(groups) > 0.5 * sum(len(y) for y in ys)  # most unit-steps in groups of two or more


def test_an_exact_fleet_past_its_bank_limit_names_the_unit_that_got_there_first(dryer, monkeypatch):
    """Each unit's bank grows with its own readings: the fleet stops at the first step at which a unit's
    would outgrow the limit, naming that unit (the first such, in order) with the message it gets alone."""
    monkeypatch.setattr(Exact, "max_gaussians", 20)
    ys, us = fleet_data(dryer, 3, 6)
    when = []
    for y, u in zip(ys, us):
        f = Filter(dryer, "exact")
        with pytest.raises(FilterError) as alone:
            for row, inputs in zip(y, u):
                f.step(row, inputs)
        when.append((f.t, str(alone.value)))
    first = min(range(len(ys)), key=lambda i: when[i][0])
    with pytest.raises(FilterError) as fleet:
        filter_units(dryer, ys, us, algorithm="exact")
    assert str(fleet.value) == f"unit {first}: {when[first][1]}"


def test_exact_over_units_equals_each_unit_alone(dryer):
    ys, us = fleet_data(dryer, 4, 6)
    ys, us = [y[:5 + i] for i, y in enumerate(ys)], [u[:5 + i] for i, u in enumerate(us)]  # 4^8 histories at most
    ys[0][2], ys[3][3:5] = 1e9, ys[3][3:5] + 40.0  # an absurd reading, a burst beyond the gate
    results = filter_units(dryer, ys, us, algorithm="exact")
    for batched, y, u in zip(results, ys, us):
        assert_same(batched, jmlgdsl.filter(dryer, y, u, algorithm="exact"))
    assert results[0].rejected[2].all() and results[3].rejected[3].all()


@pytest.mark.parametrize("ny", [1, 6, 70])
def test_units_are_grouped_by_what_they_measured_as_unique_rows_are(ny):
    rng = np.random.default_rng(ny)
    mask = (rng.random((5, ny)) > 0.3)[rng.integers(0, 5, 300)]
    patterns, which = _groups(mask)
    expected, inverse = np.unique(mask, axis=0, return_inverse=True)
    assert np.array_equal(patterns, expected) and np.array_equal(which, inverse.ravel())


def test_units_left_out_of_a_step_stay_where_they_are(dryer):
    sim = simulate(dryer, 20, seed=1)
    fleet = Units(dryer, 3)
    for t in range(20):
        fleet.step(np.repeat(sim.y[t:t + 1], 2, axis=0), np.repeat(sim.u[t:t + 1], 2, axis=0), units=[0, 2])
    assert list(fleet.t) == [20, 0, 20]
    first = fleet.step(sim.y[:3], sim.u[:3])
    alone = jmlgdsl.filter(dryer, sim.y[1:2], sim.u[1:2], algorithm="imm")
    assert np.array_equal(first.mode_posterior[1], alone.mode_posterior[0])
    assert first.records()[1].t == 1 and first.records()[0].t == 21
    assert fleet.loglik[1] == alone.loglik


def test_a_unit_is_named_in_what_goes_wrong(dryer):
    fleet = Units(dryer, 2)
    with pytest.raises(DataError, match=r"shape \(2, 1\) for 2 units"):
        fleet.step([[50.0]], [[15.0]])
    bare = dryer.replace(input_defaults=np.array([np.nan]))
    with pytest.raises(DataError, match=r"^unit 1, t=1: no value and no default for input current"):
        Units(bare, 2).step([[50.0], [50.0]], [[15.0], [np.nan]])
    unstable = dryer.replace(A=np.full((4, 1, 1), 1e200))
    with np.errstate(all="ignore"), pytest.raises(FilterError) as alone:
        jmlgdsl.filter(unstable, [[50.0]], [[15.0]])
    with np.errstate(all="ignore"), pytest.raises(FilterError) as batched:
        Units(unstable, 2).step([[50.0], [50.0]], [[15.0]] * 2)
    assert str(batched.value) == f"unit 0: {alone.value}"
    with pytest.raises(FilterError, match="number of units"):
        Units(dryer, 0)
    with pytest.raises(FilterError, match="the units' filters must have no lag"):
        Units(dryer, 1, filters=[Filter(dryer, "la-rbpf", lag=2)])


@pytest.fixture(scope="module")
def unit_files(tmp_path_factory):
    """Three dryers' records: the published sequence; a shorter one with a gap, an absurd reading
    and a burst beyond the gate; and one that moves the heater current."""
    folder = tmp_path_factory.mktemp("units")
    with open("examples/dryer_seq1.csv", newline="") as f:
        header, *rows = list(csv.reader(f))
    spoilt = [r[:] for r in rows[:600]]
    for r in spoilt[100:110]:
        r[2] = ""
    spoilt[300][2] = "1e9"
    for r in spoilt[400:404]:
        r[2] = str(float(r[2]) + 30)
    moved = [r[:] for r in rows[200:900]]
    for r in moved:
        r[1] = str(15 + (int(r[0]) // 100) % 3)
    paths = []
    for name, body in (("a", rows), ("b", spoilt), ("c", moved)):
        paths.append(folder / f"{name}.csv")
        with open(paths[-1], "w", newline="") as f:
            csv.writer(f).writerows([header] + body)
    return paths


@pytest.mark.parametrize("options", [[], ["--filter", "la-rbpf", "--seed", "3", "--persistence", "3"],
                                     ["--lag", "5"], ["--prefilter", "ma:3", "--healthy", "normal,grill"],
                                     ["--explain"], ["--explain", "--filter", "la-rbpf", "--seed", "3"]])
def test_run_on_several_files_writes_each_units_table_as_alone(unit_files, tmp_path, capsys, options):
    assert main(["run", "specs/dryer.jmlg", *map(str, unit_files), "-o", str(tmp_path / "out"), *options]) == 0
    printed = capsys.readouterr().out
    blocks = re.split(r"^(?=\S+\.csv: )", printed, flags=re.M)[1:]  # a unit's line and the lines under it
    assert len(blocks) == len(unit_files) and "3 units" in blocks[-1]
    for path, block in zip(unit_files, blocks):
        alone = tmp_path / f"alone_{path.name}"
        assert main(["run", "specs/dryer.jmlg", str(path), "-o", str(alone), *options]) == 0
        said = capsys.readouterr().out
        assert (tmp_path / "out" / path.name).read_bytes() == alone.read_bytes()
        error = re.search(r"diagnosis error: (\S+) %", said).group(1)
        assert block.startswith(f"{path}: ") and f"diagnosis error {error} %" in block
        evidence = said[said.index("evidence behind"):].splitlines() if "--explain" in options else []
        assert [line[2:] for line in block.splitlines()[1:] if line.startswith("  ")] == evidence
    if "--explain" in options:
        assert "evidence_temp" in (tmp_path / "out" / unit_files[0].name).read_text().splitlines()[0]
        assert re.search(r"^    t \d+ \(time \d+\): \w+ against normal, ", printed, flags=re.M)


def test_run_on_several_files_refuses_what_it_cannot_do_before_any_work(unit_files, tmp_path, capsys):
    spec, a, b = "specs/dryer.jmlg", str(unit_files[0]), str(unit_files[1])
    for extra, message in ((["--plot", str(tmp_path / "p.png")], "--plot takes one data file, not 2"),
                           (["-o", "-"], "several data files write a table each; give a folder"),
                           ([str(tmp_path / "a.csv")], "two data files would write the same table a.csv"),
                           (["-"], "standard input (-) has no name to give its table; give files"),
                           (["-o", a], "is a file, not a folder")):
        assert main(["run", spec, a, b, *extra]) != 0
        assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("algorithm", ["imm", "rbpf"])  # one vectorised engine; the units' own filters
def test_a_step_of_many_units_names_its_fields_as_a_result_does(dryer, algorithm):
    ys, us = fleet_data(dryer, 4, 40)
    results = filter_units(dryer, ys, us, algorithm=algorithm, seed=1)
    fleet = Units(dryer, 4, algorithm, seed=1)
    for t in range(40):
        steps = fleet.step([y[t] for y in ys], [u[t] for u in us])
    assert steps.t.tolist() == [40] * 4
    for i, result in enumerate(results):  # unit i's row of the step is row 40 of its Result, field by field
        for field in FIELDS:
            assert np.array_equal(getattr(steps, field)[i], getattr(result, field)[39], equal_nan=True), field
    assert any(result.rejected[:40].any() for result in results)  # the rows a gate left out are compared too


@pytest.mark.parametrize("algorithm, particles", [("la-rbpf", 5), ("rbpf", 10), ("pf", 30), ("pf", 40)])
def test_engines_stepped_together_give_their_estimates_as_rows_each_as_alone(dryer, algorithm, particles):
    """`step_together` gives its engines' Estimates as rows of arrays with a leading engine axis (a
    fleet makes its records from them, without a Step each): row i is, bit for bit, what engine i
    gets stepped alone, through missing readings and a gross error its gate leaves out (that engine's
    step redone alone, the others' together), and each engine goes on as alone, its step's
    Predictive and Genealogy as its own step makes them, and so saved before they are read (a
    group's engine makes them when they are read)."""
    ys, us = fleet_data(dryer, 4, 40, seed=5)
    together = [Filter(dryer, algorithm, particles, seed=s).engine for s in range(4)]
    alone = [Filter(dryer, algorithm, particles, seed=s).engine for s in range(4)]
    spec = ALGORITHMS[algorithm]
    gates = [Filter(dryer).gate] * 4
    screened = 0
    for t in range(40):
        y = np.array([y[t] for y in ys])
        u = np.array([u[t] for u in us])
        mask = np.abs(y) < 1e100
        mask[:] = mask[0]  # the group's one mask; the others' readings at those times left out
        y = np.where(mask, y, np.nan)
        if spec.share is not None:
            spec.share(together)
        groups = {}
        for i, e in enumerate(together):
            groups.setdefault(len(e.z), []).append(i)
        for members in groups.values():
            rows = spec.step_together([together[i] for i in members], y[members], mask[0], u[members],
                                      [gates[i] for i in members])
            for j, i in enumerate(members):
                est = alone[i].step(y[i], mask[0], u[i], gates[i])
                for field in ("mode_posterior", "state_mean", "state_cov", "y_pred", "loglik", "ess"):
                    assert np.array_equal(getattr(rows, field)[j], getattr(est, field), equal_nan=True), (t, i, field)
                for field in ("rejected", "flagged"):
                    expected = getattr(est, field)
                    assert np.array_equal(getattr(rows, field)[j], np.zeros(1, bool) if expected is None else expected)
                screened += est.rejected is not None
        kinds = (*SAVED_KINDS, Predictive)
        for a, b in zip(together, alone):
            assert np.array_equal(a.z, b.z) and np.array_equal(a.logw, b.logw)
            assert a.rng.bit_generator.state == b.rng.bit_generator.state
            saved = sealed.unseal(sealed.seal(a, {}, kinds, {"model": dryer}), kinds, {"model": dryer})
            for name in ("predictive", "genealogy"):  # what evidence and smoothing read of the step
                mine, its = vars(saved)[name], getattr(b, name)
                assert type(mine) is type(its) and all(np.array_equal(x, y, equal_nan=True) for x, y in zip(mine, its))
                mine = getattr(a, name)
                assert type(mine) is type(its) and all(np.array_equal(x, y, equal_nan=True) for x, y in zip(mine, its))
    assert screened > 0
