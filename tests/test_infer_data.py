"""CSV binding by column name: round trips, missing values, and located errors."""

import io

import numpy as np
import pytest
from infer_models import dryer

from jmlgdsl import DataError, Filter, Model
from jmlgdsl.data import DataWarning, iter_rows, read_csv, with_defaults, write_columns


def two_input_model():
    return Model.from_arrays(A=[[0.9]], B=0.1, C=[[1.0]], D=0.1, F=[[1.0, 2.0]], P=[[1.0]], p0=[1.0],
                             mu0=[0.0], Sigma0=0.0, inputs=("flow", "power"), outputs=("level",),
                             input_defaults=[np.nan, 3.0], modes=("ok",))


def rows(text, model, **kw):
    return list(iter_rows(io.StringIO(text), model, "data.csv", **kw))


def test_round_trip(tmp_path):
    model = dryer()
    path = tmp_path / "d.csv"
    y = np.array([50.123456789, np.nan, 1e-7])
    write_columns(path, {"time": [1, 2, 3], "one": [1.0, 1.0, 1.0], "temp": y,
                         "mode": ["normal", "fan", "fan_grill"], "extra": [7, 8, 9]})
    data = read_csv(path, model)
    np.testing.assert_allclose(data.y[:, 0], y, rtol=1e-9)
    np.testing.assert_array_equal(data.modes, [0, 1, 3])
    np.testing.assert_array_equal(data.time, [1, 2, 3])
    assert path.read_text().splitlines()[2] == "2,1,,fan,8"


def test_missing_cells_and_defaults():
    model = two_input_model()
    got = rows("level,flow,power\n1.5,2,\nNA,4,5\n", model)
    np.testing.assert_array_equal(got[0].u, [2.0, 3.0])
    assert np.isnan(got[1].y[0]) and got[1].time is None and got[1].mode is None
    np.testing.assert_array_equal(got[1].u, [4.0, 5.0])


def test_optional_input_column_takes_its_default():
    with pytest.warns(DataWarning, match="no column 'one': input one took its default 1 throughout"):
        got = rows("temp\n50\n", dryer())
    np.testing.assert_array_equal(got[0].u, [1.0])


def test_spreadsheet_exports_read_cleanly():
    got = rows("\ufefftemp , one\r\n50.5, 2\r\n", dryer())
    assert got[0].y[0] == 50.5 and got[0].u[0] == 2.0
    # Repeated columns the model does not use are ignored like any other.
    with pytest.warns(DataWarning, match="no column 'one'"):
        assert rows("note,temp,note\na,51,b\n", dryer())[0].y[0] == 51.0


@pytest.mark.parametrize("text, message", [
    ("flow\n1\n", "data.csv: missing column 'level'; the header has flow"),
    ("level\n1\n", "data.csv: missing column 'flow'"),
    ("level,flow\n1,2\n\n# comment\n1,x2\n", "data.csv:5: column 'flow': 'x2' is not a number"),
    ("level,flow\n1,2\ninf,2\n", "data.csv:3: column 'level': 'inf' is not a finite number"),
    ("level,flow\n1,\n", "data.csv:2: column 'flow': missing value and the input has no default"),
    ("level,flow,mode\n1,2,ok\n1,2,broken\n", "data.csv:3: column 'mode': unknown mode 'broken'; modes are ok"),
    ("", "data.csv: no header line"),
    ("level,flow,level\n1,2,3\n", "data.csv: column 'level' appears 2 times in the header"),
    ("levle,flow\n1,2\n", "data.csv: missing column 'level'; the header has levle, flow; did you mean 'levle'?"),
    ("level,flow,mode\n1,2,okk\n", "data.csv:2: column 'mode': unknown mode 'okk'; modes are ok; did you mean 'ok'?"),
])
def test_errors_name_file_line_and_column(text, message):
    with pytest.raises(DataError) as err:
        rows(text, two_input_model())
    assert str(err.value).startswith(message)


def test_inputs_only_when_outputs_are_not_needed():
    with pytest.warns(DataWarning, match="no column 'power'"):
        got = rows("flow\n2\n", two_input_model(), outputs=False)
    assert np.isnan(got[0].y[0]) and got[0].u[0] == 2.0


def test_rows_arrive_before_the_stream_ends():
    class Live(io.StringIO):
        """A stream that fails if read past its third line, like a pipe still being written."""

        def readline(self):
            line = super().readline()
            if not line:
                raise AssertionError("read past the rows that have arrived")
            return line

    it = iter_rows(Live("level,flow\n1,2\n3,4\n"), two_input_model())
    assert next(it).y[0] == 1.0 and next(it).y[0] == 3.0


def test_read_missing_file_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match="cannot read .*nope.csv"):
        read_csv(tmp_path / "nope.csv", dryer())


def test_a_missing_input_takes_its_default_the_same_way_for_every_reader():
    model = two_input_model()  # flow has no default, power's is 3
    filled = with_defaults(np.array([[2.0, np.nan], [np.nan, 5.0]]), model.input_defaults)
    np.testing.assert_array_equal(filled, [[2.0, 3.0], [np.nan, 5.0]])  # NaN stays only without a default
    np.testing.assert_array_equal(rows("level,flow,power\n1.5,2,\n", model)[0].u, filled[0])
    given, defaulted = Filter(model), Filter(model)
    assert np.array_equal(given.step([1.5], filled[0]).state_mean, defaulted.step([1.5], [2.0, np.nan]).state_mean)
    with pytest.raises(DataError, match="flow"):  # an input with neither a value nor a default
        Filter(model).step([1.5], filled[1])
