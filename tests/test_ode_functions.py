"""Every function the language offers can appear in an ODE: the exact Jacobian the compiler takes
agrees with central finite differences of the equations."""

import numpy as np
from scipy.optimize import approx_fprime

from jmlgdsl.compile.lower import compile_text
from jmlgdsl.compile.ode import ode_system
from jmlgdsl.lang.check import check
from jmlgdsl.lang.parse import parse_text

SPEC = """\
plant functions
sample 0.5 s
param a = 0.7
input u = 0.4
state x = 1.5, z = 0.3
output x
output w = sin(z) + cos(x) * u
ode
  der(x) = 1 - a * x + exp(-z) * log(1 + x^2) / 10 - sqrt(x) * tanh(u) / 10 + pow(u, 2) / 3
  der(z) = -z + min(x, 2) * 0.1 + max(u, 0) * abs(z - 1) * 0.2 - tan(0.1 * z) + x ** 2 / 10
noise process 0.01, measurement 0.1
modes normal
"""


def test_exact_jacobians_match_finite_differences():
    plant, report = check(parse_text(SPEC))
    system = ode_system(plant)
    p, u = np.array([0.7]), np.array([0.4])
    x = np.array([1.3, 0.45])
    for name, fun in (("f", system.derivative), ("h", system.output)):
        exact_x = system.jacobian(f"{name}_x", x, u, p)
        exact_u = system.jacobian(f"{name}_u", x, u, p)
        rows = len(fun(x, u, p))
        numeric_x = np.array([approx_fprime(x, lambda s: fun(s, u, p)[i], 1e-7) for i in range(rows)])
        numeric_u = np.array([approx_fprime(u, lambda v: fun(x, v, p)[i], 1e-7) for i in range(rows)])
        np.testing.assert_allclose(exact_x, numeric_x, atol=1e-6)
        np.testing.assert_allclose(exact_u, numeric_u, atol=1e-6)


def test_a_plant_with_every_function_compiles_to_its_steady_state():
    model = compile_text(SPEC)
    plant, report = check(parse_text(SPEC))
    system = ode_system(plant)
    np.testing.assert_allclose(system.derivative(model.mu0[0], np.array([0.4]), np.array([0.7])), 0.0, atol=1e-10)
    assert np.abs(np.linalg.eigvals(model.A[0])).max() < 1
