"""Real recordings as they come: semicolons, ISO time stamps and 0/1 anomaly / change-point labels."""

import numpy as np
import pytest

from jmlgdsl.data import Columns, read_csv
from jmlgdsl.errors import DataError

COLUMNS = Columns(outputs=("flow", "pressure"))


def test_a_semicolon_file_with_time_stamps_and_labels(tmp_path):
    path = tmp_path / "rig.csv"
    path.write_text("datetime;flow;pressure;anomaly;changepoint\n"
                    "2020-03-09 10:14:33;32.0;0.05;0.0;0.0\n"
                    "2020-03-09 10:14:34;32.5;;1.0;1.0\n"
                    "2020-03-09 10:14:37;31.9;0.06;1;0\n")
    data = read_csv(path, COLUMNS)
    np.testing.assert_array_equal(data.time - data.time[0], [0.0, 1.0, 4.0])  # seconds, with the 3 s gap
    assert data.time[0] == 1583748873.0  # 2020-03-09 10:14:33 UTC
    np.testing.assert_array_equal(data.y, [[32.0, 0.05], [32.5, np.nan], [31.9, 0.06]])
    np.testing.assert_array_equal(data.anomaly, [0, 1, 1])
    np.testing.assert_array_equal(data.changepoint, [0, 1, 0])
    assert data.modes is None


def test_commas_inside_a_semicolon_header_keep_commas_as_the_separator(tmp_path):
    path = tmp_path / "plain.csv"
    path.write_text("time,flow,pressure\n1,2,3\n")
    assert read_csv(path, COLUMNS).y.tolist() == [[2.0, 3.0]]


@pytest.mark.parametrize("cell, message", [
    ("2020-13-09 10:14:33", "column 'datetime': '2020-13-09 10:14:33' is not an ISO time stamp"),
    ("yesterday", "column 'datetime': 'yesterday' is not an ISO time stamp"),
])
def test_bad_time_stamps_are_located(tmp_path, cell, message):
    path = tmp_path / "rig.csv"
    path.write_text(f"datetime;flow;pressure\n{cell};1;2\n")
    with pytest.raises(DataError, match=f"rig.csv:2: {message}"):
        read_csv(path, COLUMNS)


def test_a_label_must_be_zero_or_one(tmp_path):
    path = tmp_path / "rig.csv"
    path.write_text("flow,pressure,anomaly\n1,2,0.5\n")
    with pytest.raises(DataError, match=r"rig.csv:2: column 'anomaly': '0.5' is not a 0/1 label"):
        read_csv(path, COLUMNS)


def test_a_header_with_spaces_binds_to_the_name_written_with_underscores(tmp_path):
    path = tmp_path / "rig.csv"
    path.write_text("Volume Flow Rate;Pressure (bar)\n32.0;0.05\n")
    data = read_csv(path, Columns(outputs=("Volume_Flow_Rate", "Pressure__bar_")))
    assert data.y.tolist() == [[32.0, 0.05]]
