"""Every complete spec shown in docs/language.md compiles to the matrices its text describes, so the
reference stays true. The expected values are worked out from the documented rules by hand."""

import pathlib
import re
import warnings

import numpy as np
import pytest
from scipy.linalg import expm

from jmlgdsl.compile.lower import compile_text
from test_language_gaps import DOC_CHECKS

DOC = pathlib.Path(__file__).resolve().parents[1] / "docs" / "language.md"
BLOCKS = {re.search(r"plant (\w+)", b).group(1): b
          for b in re.findall(r"```jmlg\n(.*?)```", DOC.read_text(), flags=re.S) if "plant " in b}


def close(actual, expected):
    np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-12)


def stay_otherwise_uniform(K, stay):
    """`transitions stay p, otherwise uniform` by hand: p on the diagonal, (1 - p) / (K - 1) elsewhere."""
    return np.where(np.eye(K, dtype=bool), stay, (1 - stay) / (K - 1))


def fopdt_row(dt, gain, tau, u_ss, y_ss):
    """A delay-free fopdt block: a = exp(-dt/tau), input weight K(1 - a), offset (1 - a)(y_ss - K u_ss)."""
    a = np.exp(-dt / tau)
    return a, gain * (1 - a), (1 - a) * (y_ss - gain * u_ss)


def check_dryer(m):
    assert m.modes == ("normal", "fan", "grill", "fan_grill") and m.dt == 1.0
    rows = [fopdt_row(1.0, 1.94, 30.45, 15, 50.52), fopdt_row(1.0, 1.44, 25.10, 15, 44.16),
            fopdt_row(1.0, 2.34, 41.68, 15, 54.76), fopdt_row(1.0, 1.61, 32.96, 15, 46.99)]
    close(m.A[:, 0, 0], [r[0] for r in rows])
    close(m.F[:, 0, 0], [r[1] for r in rows])
    close(m.f[:, 0], [r[2] for r in rows])
    close(m.mu0[:, 0], [50.52, 44.16, 54.76, 46.99])  # the operating points
    close(m.B[:, 0, 0], 0.05)
    close(m.D[:, 0, 0], 0.05)
    close(m.C[:, 0, 0], 1.0)
    close(m.P, stay_otherwise_uniform(4, 0.994))
    close(m.p0, [0.988, 0.004, 0.004, 0.004])
    close(m.input_defaults, [15.0])


def check_header_demo(m):
    assert m.dt == 6.0 and m.inputs == ("valve", "one") and m.states == ("h",)
    close(m.A[0], [[0.98]])
    close(m.F[0], [[0.01, (1 - 0.98) * 15.5]])  # inflow = 0.01 valve, drift * one
    close(m.f[0], [-0.4])
    close(m.B[0], [[0.01]])
    close(m.C[0], [[1.0]])
    close(m.D[0], [[0.08]])
    close(m.mu0[0], [15.5])
    close(m.Sigma0, [[0.2 ** 2]])
    close(m.input_defaults, [40.0, 1.0])


def check_level_tank(m):
    assert m.modes == ("low_in", "medium_in", "high_in", "low_out")
    close(m.A[:, 0, 0], [0.9801, 0.9829, 0.9910, 0.9872])
    close(m.f[:, 0], [0.3099, 0.5368, 0.6163, 0.3544])
    close(m.mu0[:, 0], [15.54, 31.40, 68.84, 27.61])
    close(m.B[:, 0, 0], 0.008)
    close(m.D[:, 0, 0], 0.08)
    close(m.P, [[0.996, 0.002, 0, 0.002],  # the remaining mass of each arrow row stays
                [0.002, 0.996, 0.002, 0],
                [0, 0.004, 0.996, 0],
                [0.002, 0, 0, 0.998]])
    close(m.p0, [0.99, 0.001, 0.001, 0.008])


def check_cstr_normal(m):
    A = np.array([[0.9752, -0.0002149, -3.55e-7], [0.2376, 0.9943, 0.003256], [0.001767, 0.01465, 0.9596]])
    F = np.array([[0.1299], [-0.1635], [2.056]])
    close(m.A[0], A)
    close(m.F[0], F)
    close(m.C[0], np.eye(3))
    close(m.B[0], 0.01 * np.eye(3))
    close(m.D[0], 0.06 * np.eye(3))
    # no initial mean is written: the steady state under the default input one = 1
    close(m.mu0[0], np.linalg.solve(np.eye(3) - A, F[:, 0]))


def check_furnace(m):
    # cold: delay 5 s = 2 samples + 1 s, so u_{t-2} and u_{t-3}; hot: 8 s = 4 samples, so u_{t-4}
    assert m.states == ("temp", "temp_u0", "temp_u1", "temp_u2", "temp_u3") and m.dt == 2.0
    a_cold, a_hot = np.exp(-2 / 90), np.exp(-2 / 70)
    part = np.exp(-(2 - 1) / 90)
    close(m.A[0, 0], [a_cold, 0, 3.1 * (1 - part), 3.1 * (part - a_cold), 0])
    close(m.A[1, 0], [a_hot, 0, 0, 0, 2.6 * (1 - a_hot)])
    close(m.f[:, 0], [(1 - a_cold) * (320 - 3.1 * 40), (1 - a_hot) * (410 - 2.6 * 40)])
    shift = np.diag([1.0, 1.0, 1.0], -1)  # every mode keeps every register shifting
    for k in range(2):
        close(m.A[k, 1:, 1:], shift)
        close(m.F[k, :, 0], [0, 1, 0, 0, 0])
    close(m.mu0, [[320, 40, 40, 40, 40], [410, 40, 40, 40, 40]])
    close(m.B[:, 0, 0], 0.1)
    assert not m.B[:, 1:].any()  # the registers carry no noise
    close(m.D[:, 0, 0], 0.3)
    close(m.P, [[0.99, 0.01], [0.01, 0.99]])
    close(m.p0, [0.5, 0.5])


def check_level_arx(m):
    assert m.states == ("level", "level_y1", "level_u0")
    close(m.A[0], [[0.9864, 0, 0], [1, 0, 0], [0, 0, 0]])
    close(m.F[0, :, 0], [0.2169, 0, 1])
    close(m.A[1], [[1.2, -0.25, 0.3], [1, 0, 0], [0, 0, 0]])
    close(m.F[1, :, 0], [0.4, 0, 1])
    close(m.f, 0.0)  # no operating point
    close(m.C, [[[1, 0, 0]], [[1, 0, 0]]])
    close(m.B[:, 0, 0], 0.05)
    close(m.P, [[0.995, 0.005], [0.005, 0.995]])


CSTR = dict(CAi=10.8, a=2560, k0=1.43, dH=867, Cp=0.9, Cpj=1.0, A=500, rho=80,
            Tri=150, Tji=80, V=250, W=1000, Wj=1050, Mj=4000)


def cstr_rates(x, U):
    """The documented CSTR equations, written out again here."""
    CA, Tr, Tjo = x
    c = CSTR
    k = c["k0"] * np.exp(-c["a"] / (Tr + 460))
    return np.array([
        c["W"] / (c["V"] * c["rho"]) * (c["CAi"] - CA) - k * CA ** 2,
        (c["W"] * c["Cp"] * (c["Tri"] - Tr) - U * c["A"] * (Tr - Tjo) + c["dH"] * c["V"] * k * CA ** 2)
        / (c["V"] * c["rho"] * c["Cp"]),
        (U * c["A"] * (Tr - Tjo) - c["Wj"] * c["Cpj"] * (Tjo - c["Tji"])) / (c["Mj"] * c["Cpj"])])


def cstr_jacobian(x, U):
    """d rates / d (CA, Tr, Tjo) by hand."""
    CA, Tr, _ = x
    c = CSTR
    k = c["k0"] * np.exp(-c["a"] / (Tr + 460))
    dk = k * c["a"] / (Tr + 460) ** 2
    VrC = c["V"] * c["rho"] * c["Cp"]
    return np.array([
        [-c["W"] / (c["V"] * c["rho"]) - 2 * k * CA, -dk * CA ** 2, 0],
        [2 * c["dH"] * c["V"] * k * CA / VrC, (-c["W"] * c["Cp"] - U * c["A"] + c["dH"] * c["V"] * dk * CA ** 2) / VrC,
         U * c["A"] / VrC],
        [0, U * c["A"] / (c["Mj"] * c["Cpj"]), (-U * c["A"] - c["Wj"] * c["Cpj"]) / (c["Mj"] * c["Cpj"])]])


def check_cstr(m):
    assert m.modes == ("normal", "fouling1", "fouling2", "fouling3") and m.dt == 6.0
    for k, U in enumerate([1.2, 0.95 * 1.2, 0.90 * 1.2, 0.85 * 1.2]):
        x = m.mu0[k]
        assert np.abs(cstr_rates(x, U)).max() < 1e-8 * (1 + np.abs(x).max())  # each mode's own steady state
        np.testing.assert_allclose(m.A[k], expm(0.1 * cstr_jacobian(x, U)), rtol=1e-9, atol=1e-12)  # per minute
        close(m.C[k], np.eye(3))
        close(m.B[k], 0.01 * np.eye(3))
        close(m.D[k], 0.06 * np.eye(3))
    assert abs(m.mu0[0, 1] - 190.0611) < 1e-3  # the documented guess is the normal steady state
    close(m.P, stay_otherwise_uniform(4, 0.998))
    close(m.p0, [0.997, 0.001, 0.001, 0.001])


def check_catch_all(m):
    assert m.modes == ("normal", "anomaly")
    close(m.A, [[[0.9]], [[0.9]]])
    close(m.f, [[3.2], [3.2]])
    close(m.B, [[[0.1]], [[0.3]]])
    close(m.D, [[[0.2, 0.0], [0.0, 0.01]], [[0.6, 0.0], [0.0, 0.03]]])
    close(m.C, [[[1.0], [0.05]], [[1.0], [0.05]]])
    np.testing.assert_array_equal(m.outlier_gate, [20.0, np.inf])
    close(m.P, stay_otherwise_uniform(2, 0.99))
    close(m.p0, [0.99, 0.01])


def check_heater_unknown(m):
    """Unfitted, each unknown is its prior's median: gain 2, tau 40 s, kept 0.75, the measurement sd
    0.2 x 0.674 (HalfNormal) and the fouled mode's process sd 0.1 x 0.674."""
    a = np.exp(-1 / 40)
    close(m.A[:, 0, 0], [a, a])
    close(m.F[:, 0, 0], [2 * (1 - a), 1.5 * (1 - a)])
    close(m.f[:, 0], [(1 - a) * (40 - 20), (1 - a) * (40 - 15)])
    close(m.D[:, 0, 0], [0.2 * HALF_NORMAL_MEDIAN] * 2)
    close(m.B[:, 0, 0], [0.05, 0.1 * HALF_NORMAL_MEDIAN])


HALF_NORMAL_MEDIAN = 0.6744897501960817
EXPECTED_WARNINGS = {"heater_unknown": ["gain", "tau", "kept", "noise.measurement", "fouled.noise.process"]}

CHECKS = {name[len("check_"):]: fn for name, fn in globals().items() if name.startswith("check_")}
CHECKS.update(DOC_CHECKS)  # the examples of multi-input blocks, input values per mode and output sd


def test_every_documented_spec_has_its_expected_matrices():
    assert set(BLOCKS) == set(CHECKS)


@pytest.mark.parametrize("name", sorted(BLOCKS))
def test_documented_spec_compiles_to_the_documented_matrices(name):
    """... and warns only where the page says it does (an unfitted unknown: one warning naming it)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", ResourceWarning)  # a file another test left open, collected now
        model = compile_text(BLOCKS[name], str(DOC))
    CHECKS[name](model)
    assert [str(w.message).split("warning: ")[1].split(" is unknown: ")[0] for w in caught] == \
        EXPECTED_WARNINGS.get(name, [])
