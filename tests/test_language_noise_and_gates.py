"""Two constructs a user states without data: a mode that is another mode with its noise scaled
(`noise scale S`), and an output's gross-error gate (`outliers N` or `outliers off`)."""

import numpy as np
import pytest

import jmlgdsl
from jmlgdsl import SpecError
from jmlgdsl.model import DEFAULT_GATE

PLANT = """
plant rig
sample 1 s
output flow [m3/h] outliers 8, pressure [bar] outliers off, level
state x
modes normal, anomaly "Something is wrong: the normal dynamics, noisier"
transitions stay 0.99, otherwise uniform
mode normal {
  x[t] ~ Normal(0.9 * x[t-1] + 1, 0.1)
  flow ~ Normal(2 * x[t], 0.2); pressure ~ Normal(x[t], 0.3); level ~ Normal(x[t], 0.5)
}
mode anomaly like normal { noise scale 3 }
"""


def load(tmp_path, text):
    path = tmp_path / "rig.jmlg"
    path.write_text(text)
    return jmlgdsl.load(path)


def test_noise_scale_multiplies_every_noise_factor_of_the_mode(tmp_path):
    model = load(tmp_path, PLANT)
    normal, anomaly = model.mode_index("normal"), model.mode_index("anomaly")
    np.testing.assert_allclose(model.B[anomaly], 3 * model.B[normal])
    np.testing.assert_allclose(model.R[anomaly], 9 * model.R[normal])  # variances by 9
    np.testing.assert_array_equal(model.A[anomaly], model.A[normal])
    assert model.descriptions["anomaly"] == "Something is wrong: the normal dynamics, noisier"


def test_each_output_has_its_gate(tmp_path):
    np.testing.assert_array_equal(load(tmp_path, PLANT).outlier_gate, [8.0, np.inf, DEFAULT_GATE])


@pytest.mark.parametrize("change, message", [
    (("noise scale 3 }", "noise scale 0 }"), "a noise scale must be a positive number (got 0)"),
    (("transitions stay", "noise scale 2\ntransitions stay"), "'noise scale' multiplies one mode's noise"),
    (("outliers 8", "outliers -1"), "an outlier gate is a positive number of standard deviations (or 'off'); got -1"),
    (("noise scale 3", "noise sclae 3"), "unknown noise kind 'sclae'; use 'process', 'measurement' or 'scale'; "
                                         "did you mean 'scale'?"),
])
def test_bad_values_are_located_errors(tmp_path, change, message):
    with pytest.raises(SpecError) as error:
        load(tmp_path, PLANT.replace(*change))
    assert message in str(error.value)
    assert "rig.jmlg:" in str(error.value)


def test_a_gate_off_keeps_a_wild_reading(tmp_path):
    model = load(tmp_path, PLANT)
    y = np.tile([20.0, 10.0, 10.0], (30, 1))
    y[15] = [1e9, 1e9, 1e9]
    result = jmlgdsl.filter(model, y)
    assert result.rejected[15].tolist() == [True, False, True]  # pressure's gate is off
