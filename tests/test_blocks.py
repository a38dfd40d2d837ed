"""Block forms lower to matrices that reproduce their defining equations exactly."""

import numpy as np
import pytest

from jmlgdsl.compile.lower import compile_text
from jmlgdsl.errors import SpecWarning


def free_response(m, k, u, x0=None):
    """Noise-free outputs of mode k for inputs u (T, nu), from x0 (default: zero state)."""
    x = np.zeros(m.nx) if x0 is None else x0
    ys = []
    for ut in u:
        x = m.A[k] @ x + m.F[k] @ ut + m.f[k]
        ys.append(m.C[k] @ x + m.G[k] @ ut + m.g[k])
    return np.array(ys)[:, 0]


FOPDT = """
plant step
sample {dt} s
input u
output y
noise process 0.1, measurement 0.1
mode only: y ~ fopdt(u, gain {gain}, tau {tau} s, delay {delay} s)
"""


@pytest.mark.parametrize("delay", [0.0, 3.0, 2.5, 0.4, 7.25])
def test_fopdt_step_response_matches_the_continuous_solution_sample_for_sample(delay):
    dt, gain, tau = 1.0, 2.5, 6.0
    m = compile_text(FOPDT.format(dt=dt, gain=gain, tau=tau, delay=delay))
    T = 30
    y = free_response(m, 0, np.ones((T, 1)))
    # The input steps to 1 at time 0 and is held over each sample (u_t acts on (t-1, t]).
    t = np.arange(1, T + 1) * dt
    expected = gain * np.clip(1 - np.exp(-(t - delay) / tau), 0, None)
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-12)


def test_fopdt_delay_states_are_whole_samples():
    m = compile_text(FOPDT.format(dt=2.0, gain=1, tau=5, delay=6))
    assert m.states == ("y", "y_u0", "y_u1", "y_u2")
    np.testing.assert_allclose(m.A[0, 0, 0], np.exp(-2 / 5))
    assert m.B[0, 0, 0] == 0.1 and not m.B[0, 1:].any()  # no noise on the input registers


def test_fopdt_with_minutes_and_an_operating_point_relaxes_to_it():
    text = FOPDT.format(dt=6, gain=1.5, tau=0.5, delay=0).replace("tau 0.5 s", "tau 0.5 min")
    text = text.replace("delay 0 s)", "delay 0 s, at u 10 -> 40)")
    m = compile_text(text.replace("input u", "input u = 10"))
    np.testing.assert_allclose(m.A[0, 0, 0], np.exp(-6 / 30))
    np.testing.assert_allclose(m.mu0[0], [40.0])
    y = free_response(m, 0, np.full((400, 1), 12.0), x0=m.mu0[0])
    np.testing.assert_allclose(y[-1], 40 + 1.5 * 2, rtol=1e-9)


ARX = """
plant arx
sample 1 s
input u
output y
noise process 0.1, measurement 0.1
mode only: y ~ arx(u, na 3, nb 2, a [-1.1 0.25 0.05], b [0.4 -0.2 0.1], at u 2 -> 5)
"""


def test_arx_block_reproduces_its_difference_equation_on_a_random_input():
    m = compile_text(ARX)
    rng = np.random.default_rng(7)
    u = rng.normal(2, 1, size=60)
    y = free_response(m, 0, u[:, None], x0=m.mu0[0])
    a, b = np.array([-1.1, 0.25, 0.05]), np.array([0.4, -0.2, 0.1])
    # Deviations from the operating point obey the difference equation from the first sample on.
    dy, du = np.r_[np.zeros(3), y - 5], np.r_[np.zeros(2), u - 2]
    for t in range(60):
        lhs = dy[t + 3] + a @ dy[t + 2:t - 1 if t else None:-1][:3]
        rhs = b @ du[t + 2::-1][:3] if t == 0 else b @ du[t + 2:t - 1:-1]
        assert lhs == pytest.approx(rhs, abs=1e-12)


def test_arx_process_noise_is_the_equation_error():
    m = compile_text(ARX)
    assert m.states[0] == "y"
    assert m.B[0, 0, 0] == 0.1 and np.count_nonzero(m.B[0]) == 1


def test_generative_statements_extract_affine_coefficients():
    m = compile_text("""
        plant two
        sample 1 s
        input u = 1, w
        output y1, y2
        state a, b
        param k = 0.5
        let drive = 2 * u - w / 4
        mode only {
          a[t] ~ Normal(k * a[t-1] - 0.1 * b[t-1] + drive + 3, 0.2)
          b[t] ~ Normal((a[t-1] + b[t-1]) / 2, 0.3)
          y1 ~ Normal(a[t] - b[t] + 7 * u, 0.05)
          y2[t] ~ Normal(b[t], 0.01)
        }
    """)
    np.testing.assert_allclose(m.A[0], [[0.5, -0.1], [0.5, 0.5]])
    np.testing.assert_allclose(m.F[0], [[2, -0.25], [0, 0]])
    np.testing.assert_allclose(m.f[0], [3, 0])
    np.testing.assert_allclose(m.C[0], [[1, -1], [0, 1]])
    np.testing.assert_allclose(m.G[0], [[7, 0], [0, 0]])
    np.testing.assert_allclose(m.B[0], np.diag([0.2, 0.3]))
    np.testing.assert_allclose(m.D[0], np.diag([0.05, 0.01]))


def test_matrices_with_eye_and_scalar_products():
    m = compile_text("""
        plant mat
        sample 0.1 min
        input one = 1
        output c1, c2, c3
        state x1, x2, x3
        mode normal {
          A = [0.9752 -0.0002149 -3.55e-7; 0.2376 0.9943 0.003256; 0.001767 0.01465 0.9596]
          F = [0.1299; -0.1635; 2.056]
          C = eye(3)
          B = 0.01 * eye(3)
          D = 0.06 * eye(3)
        }
        mode fouled like normal { A = [0.9752, -0.0002144, -3.36e-7; 0.2386, 0.9945, 0.003095; 0.001686, 0.01393, 0.9603] }
        transitions stay 0.99, otherwise uniform
    """)
    assert m.dt == 6.0
    np.testing.assert_allclose(m.A[0, 1], [0.2376, 0.9943, 0.003256])
    np.testing.assert_allclose(m.A[1, 0, 2], -3.36e-7)
    np.testing.assert_allclose(m.F[1, :, 0], [0.1299, -0.1635, 2.056])  # inherited through `like`
    np.testing.assert_allclose(m.B, 0.01 * np.eye(3)[None].repeat(2, 0))
    np.testing.assert_allclose(m.P, [[0.99, 0.01], [0.01, 0.99]])


def test_declared_values_use_the_nominal_parameters_even_when_the_first_mode_overrides_them():
    with pytest.warns(SpecWarning, match="mode 'plain' compiles to exactly the same model as mode 'raised'"):
        m = compile_text("""
plant nominal
sample 1 s
param m0 = 1
input u = 3 * m0
state x = 2 * m0 sd m0
output y
noise process 0.1, measurement 0.1
modes raised: m0 = 5, plain
transitions stay 0.9, otherwise uniform
mode raised { x[t] ~ Normal(0.5 * x[t-1], 0.1); y ~ Normal(x[t], 0.1) }
mode plain like raised
""")
    assert m.input_defaults.tolist() == [3.0]
    assert m.mu0.tolist() == [[2.0], [2.0]]
    assert m.Sigma0.tolist() == [[1.0]]
