"""The run summary serialises itself (kind ``run_summary``), and ``rig report`` reads what ``rig run --json`` wrote."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from identify.result_format import ResultFormatError
from rig.cli import main
from rig.runner import RunSummary


def _summary(**changes) -> RunSummary:
    values = dict(samples=1200, lost=3, late=7, duplicate=1, stale=2, frame_errors=4, rate_hz=999.87,
                  send_lateness_s=np.array([1e-5, 3e-5, 2e-5]), cpu_s=0.25, wall_s=1.31, not_followed=5, held=6,
                  min_lead_s=0.0123, stop="quick stop, then disabled (0.8 ms)",
                  warnings=("encoder EMCY 0x4210 at sample 400 (temperature)",), log="runs/a.csv")
    values.update(changes)
    return RunSummary(**values)


@pytest.mark.parametrize("min_lead_s", [0.0123, math.nan])
def test_a_run_summary_saved_as_json_reopens_equal(min_lead_s):
    summary = _summary(min_lead_s=min_lead_s)
    document = json.loads(json.dumps(summary.to_dict(), allow_nan=False))  # plain JSON, no NaN token
    again = RunSummary.from_dict(document)
    assert again.to_dict() == document
    for name in RunSummary.SAVED + ("log",):
        if name == "min_lead_s" and math.isnan(min_lead_s):
            assert math.isnan(again.min_lead_s) and document["min_lead_s"] is None
        else:
            assert getattr(again, name) == getattr(summary, name), name
    assert again.send_lateness_s.size == 0  # per-sample data are not part of the summary document


def test_a_document_of_another_kind_version_or_with_a_bad_key_is_refused_by_name():
    document = _summary().to_dict()
    with pytest.raises(ResultFormatError, match="expected a result of kind 'run_summary', got kind 'batch'"):
        RunSummary.from_dict({**document, "kind": "batch"})
    with pytest.raises(ResultFormatError, match="kind 'run_summary' version 2 cannot be read"):
        RunSummary.from_dict({**document, "version": 2})
    without = {key: value for key, value in document.items() if key != "lost"}
    with pytest.raises(ResultFormatError, match="kind 'run_summary': key 'lost' is missing"):
        RunSummary.from_dict(without)
    with pytest.raises(ResultFormatError, match="samples is -1, expected an integer >= 0"):
        RunSummary.from_dict({**document, "samples": -1})


def test_rig_report_shows_what_the_run_summary_says(tmp_path, capsys):
    path = tmp_path / "run.json"
    path.write_text(json.dumps(_summary().to_dict()))
    assert main(["report", str(path), "--out", str(tmp_path / "report")]) == 0
    page = (tmp_path / "report" / "index.html").read_text()
    for shown in ("Run: run.json", "1200", "runs/a.csv", "12.3", "encoder EMCY 0x4210", "quick stop, then disabled"):
        assert shown in page, shown
