"""Learned banks that switch (issue 16): banks learned at orders 1-4 from one PRBS experiment per
mode, far from zero, diagnose a switching sequence nearly as well as the true plant."""

import numpy as np
import pytest

from jmlgdsl import Model, simulate
from jmlgdsl.infer import filter as run_filter
from jmlgdsl.learn import bank
from jmlgdsl.learn.prbs import prbs

#: The issue's bounds on the learned bank's diagnosis error above the true plant's, in points.
ALLOWED = {"fc-rbpf": 1.0, "imm": 1.5}
LEVEL = 45.0  # the operating level: offsets scale with it, which broke per-mode state bases
SEQUENCE = "1-300:normal,301-550:slow,551-800:normal,801-1050:offset,1051-1275:normal"  # the issue's


def plant(states: int) -> Model:
    """Three modes (normal, slow, an actuator offset of 0.4) of a chain of `states` first-order lags
    from u + LEVEL to the output; process sd 0.03 per state, measurement sd 0.05."""
    poles = {"normal": [0.85, 0.75], "slow": [0.93, 0.88], "offset": [0.85, 0.75]}
    A, F = [], []
    for a in poles.values():
        a = np.array(a[:states])
        A.append(np.diag(a) + np.diag(1 - a[1:], -1))
        F.append(np.eye(states, 1) * (1 - a[0]))
    F = np.array(F)
    return Model.from_arrays(
        A=np.array(A), F=F, f=F[:, :, 0] * (LEVEL + np.array([[0.0], [0.0], [0.4]])), C=np.eye(1, states, states - 1),
        B=0.03 * np.eye(states), D=[[0.05]], P=bank.default_transitions(3, 0.995), p0=[0.99, 0.005, 0.005],
        mu0=np.full(states, LEVEL), Sigma0=0.09 * np.eye(states), modes=("normal", "slow", "offset"),
        input_defaults=[0.0])


@pytest.fixture(scope="module")
def plants():
    """Each plant, its experiments (a 315-sample PRBS of +-1 per mode), a switching test sequence
    and the true plant's diagnosis errors on it."""
    out = {}
    for states in (1, 2):
        model = plant(states)
        u = prbs(6, clock=5)[:, None]
        exps = {name: bank.Experiment(simulate(model, modes=[name] * len(u), u=u, seed=10 * states + k).y, u, name)
                for k, name in enumerate(model.modes)}
        sim = simulate(model, modes=SEQUENCE, u=prbs(7, clock=10, samples=1275)[:, None], seed=states)
        out[states] = model, exps, sim, {a: error(model, sim, a) for a in ALLOWED}
    return out


def error(model, sim, algorithm):
    particles = 50 if algorithm == "fc-rbpf" else None
    result = run_filter(model, sim.y, sim.u, algorithm=algorithm, particles=particles, seed=1)
    return result.diagnosis_error(sim.modes)


@pytest.mark.parametrize("states, order", [(1, 1), (1, 3), (2, 2), (2, 4)])
def test_learned_banks_of_any_order_diagnose_a_switching_plant_like_the_truth(plants, states, order):
    """Orders 1-4, each at or above the plant's own. Within 1 point of the true plant's error with
    fc-rbpf (50 particles, close to the exact posterior for three modes; the exact filter itself
    cannot carry 3^1275 histories) and 1.5 points with IMM, the issue's bounds. With per-mode state
    bases such banks erred on 24-47 % of the steps. Seeds are fixed, so the test is deterministic;
    the worst margin when it was written was 0.3 point for fc-rbpf (1 point is 13 steps) and 0.5 for
    IMM, with EM at its defaults (fewer iterations leave order 4 over the bound)."""
    model, exps, sim, truth = plants[states]
    learned = bank.learn_modes(exps, order=(order, order, 0))
    fitted = bank.assemble(learned, P=model.P, p0=model.p0, operating_input=[0.0], inputs=model.inputs,
                           outputs=model.outputs, input_defaults=model.input_defaults)
    assert fitted.nx == order + order - 1  # order output lags and order - 1 input lags
    for algorithm, allowed in ALLOWED.items():
        assert truth[algorithm] < 5
        assert error(fitted, sim, algorithm) <= truth[algorithm] + allowed, algorithm
