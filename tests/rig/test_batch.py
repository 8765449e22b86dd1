import sys

import pytest

from rig.batch import map_files
from rig.protocols.errors import ConfigError


def parse_length(path):
    if path.endswith("bad"):
        raise ValueError(f"{path}: not a log")
    return len(path)


def test_outcomes_keep_the_order_and_errors_do_not_stop_the_batch():
    outcomes = map_files(parse_length, ["a", "bbb", "x.bad"], jobs=1)
    assert [(o.path, o.result, o.error) for o in outcomes] == [("a", 1, None), ("bbb", 3, None),
                                                                ("x.bad", None, "x.bad: not a log")]


def test_negative_jobs_and_a_missing_dask_are_named(monkeypatch):
    with pytest.raises(ValueError, match="--jobs: expected 0"):
        map_files(parse_length, ["a"], jobs=-1)
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as if Dask were not installed
    with pytest.raises(ConfigError, match=r"pip install 'dask\[distributed\]'"):
        map_files(parse_length, ["a"], scheduler="tcp://127.0.0.1:8786")
