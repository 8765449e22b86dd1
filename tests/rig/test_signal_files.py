import numpy as np
import pytest

from rig.protocols.errors import LogFileError
from rig.signal_files import read_signal_table


def test_reads_columns_and_skips_comments(tmp_path):
    path = tmp_path / "data.csv"
    path.write_text("# captured elsewhere\nt,u,y\n0,1.5,0.1\n0.001,-1.5,0.2\n")
    table = read_signal_table(path, ("u", "y"))
    np.testing.assert_array_equal(table["u"], [1.5, -1.5])
    np.testing.assert_array_equal(table["t"], [0.0, 0.001])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "the file is empty"),
        ("u,x\n1,2\n", "missing column\\(s\\) y"),
        ("u,y\n", "header but no data rows"),
        ("u,y\n1,abc\n", "line 2, column y: 'abc' is not a number"),
        ("u,y\n1,nan\n", "line 2, column y: nan is not a finite number"),
        ("u,y\n1\n", "line 2: expected 2 values, got 1"),
    ],
)
def test_damaged_files_name_line_and_column(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(LogFileError, match=message):
        read_signal_table(path, ("u", "y"))
