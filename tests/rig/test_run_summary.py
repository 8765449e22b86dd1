"""The run summary serialises itself (kind ``run_summary``), and ``rig report`` reads what ``rig run --json`` wrote."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from identify.experiment_record import ExperimentMetadata, SampleFlag
from identify.result_format import ResultFormatError
from rig.cli import main
from rig.log_file import LogWriter
from rig.runner import RunSummary, SendLateness, send_lateness_quantiles


def _summary(**changes) -> RunSummary:
    values = dict(samples=1200, lost=3, late=7, duplicate=1, stale=2, frame_errors=4, rate_hz=999.87,
                  send_lateness_s=np.array([1e-5, 3e-5, 2e-5]), cpu_s=0.25, wall_s=1.31, not_followed=5, held=6,
                  min_lead_s=0.0123, stop="quick stop, then disabled (0.8 ms)",
                  warnings=("encoder EMCY 0x4210 at sample 400 (temperature)",), log="runs/a.csv",
                  send_lateness_p50_s=2e-5, send_lateness_p99_s=2.98e-5, send_lateness_max_s=3e-5,
                  sync_jitter_max_s=4.2e-4, receive_drops=9)
    values.update(changes)
    return RunSummary(**values)


NOT_MEASURED = {"device-clocked": {"send_lateness_p50_s": math.nan, "send_lateness_p99_s": math.nan,
                                   "send_lateness_max_s": math.nan},
                "host-paced": {"min_lead_s": math.nan, "sync_jitter_max_s": math.nan}}


@pytest.mark.parametrize("link", ["device-clocked", "host-paced"])
def test_a_run_summary_saved_as_json_reopens_equal(link):
    summary = _summary(**NOT_MEASURED[link])
    document = json.loads(json.dumps(summary.to_dict(), allow_nan=False))  # plain JSON, no NaN token
    assert document["version"] == 4
    again = RunSummary.from_dict(document)
    assert again.to_dict() == document
    for name in RunSummary.SAVED + ("log",):
        if name in NOT_MEASURED[link]:
            assert math.isnan(getattr(again, name)) and document[name] is None, name
        else:
            assert getattr(again, name) == getattr(summary, name), name
    assert again.send_lateness_s.size == 0  # per-sample data are not part of the summary document


def test_a_document_of_another_kind_version_or_with_a_bad_key_is_refused_by_name():
    document = _summary().to_dict()
    with pytest.raises(ResultFormatError, match="expected a result of kind 'run_summary', got kind 'batch'"):
        RunSummary.from_dict({**document, "kind": "batch"})
    with pytest.raises(ResultFormatError, match="kind 'run_summary' version 5 cannot be read"):
        RunSummary.from_dict({**document, "version": 5})
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
    for shown in ("Run: run.json", "1200", "runs/a.csv", "12.3", "encoder EMCY 0x4210", "quick stop, then disabled",
                  "send lateness p99 [us]", "<td>30</td>"):
        assert shown in page, shown
    # a summary written before the send lateness was added (version 1) is still shown
    old = {key: value for key, value in _summary().to_dict().items() if not key.startswith("send_lateness_")}
    path.write_text(json.dumps({**old, "version": 1}))
    assert main(["report", str(path), "--out", str(tmp_path / "report_v1")]) == 0
    page = (tmp_path / "report_v1" / "index.html").read_text()
    assert "runs/a.csv" in page and "send lateness" not in page


def _log(path, time_s, flags, summary):
    metadata = ExperimentMetadata(sample_period_s=0.001, source="test", transport="serial:///dev/ttyUSB0")
    writer = LogWriter(path, metadata)
    writer.append_many(time_s, np.zeros(time_s.size), np.zeros(time_s.size), None, flags)
    if summary is not None:
        writer.write_summary(summary)
    writer.close()
    return path


def test_rig_report_says_what_is_known_of_the_timing_of_each_kind_of_log(tmp_path, capsys):
    grid_s = np.arange(200) * 0.001
    held = np.zeros(200, dtype=np.uint8)
    held[[50, 51, 120]] = SampleFlag.HELD
    device = _log(tmp_path / "device.csv", grid_s, held,
                  {"frame_errors": 0, "stop": "", "sample_clock": "device", "min_lead_s": -0.0042})
    measured_s = grid_s + np.where(np.arange(200) == 100, 3e-4, 0.0)  # one send 300 us late
    host = _log(tmp_path / "host.csv", measured_s, np.zeros(200, dtype=np.uint8),
                {"frame_errors": 0, "stop": "", "sample_clock": "host", "send_lateness_p50_s": 1.2e-5,
                 "send_lateness_p99_s": 8.5e-5, "send_lateness_max_s": 3e-4})
    old_device = _log(tmp_path / "old_device.csv", grid_s, held, None)  # a log without the timing summary
    assert main(["report", str(device), str(host), str(old_device), "--out", str(tmp_path / "report")]) == 0
    page = (tmp_path / "report" / "index.html").read_text()
    paragraphs = {name: next(line for line in page.splitlines() if f"{name}: 200 samples" in line)
                  for name in ("device.csv", "host.csv", "old_device.csv")}
    assert "device-clocked" in paragraphs["device.csv"] and "3 HELD samples" in paragraphs["device.csv"]
    assert "-4.2 ms" in paragraphs["device.csv"] and "period deviation" not in paragraphs["device.csv"]
    assert "host-paced: largest period deviation 300 us" in paragraphs["host.csv"]
    assert "p50 12 us, p99 85 us, max 300 us" in paragraphs["host.csv"]
    assert "HELD" not in paragraphs["host.csv"]
    assert "3 HELD samples" in paragraphs["old_device.csv"]
    assert "the smallest lead is not in this log" in paragraphs["old_device.csv"]


def test_a_version_1_summary_still_reads_with_the_send_lateness_not_measured():
    document = _summary().to_dict()
    old = {key: value for key, value in document.items()
           if not key.startswith("send_lateness_") and key not in ("sync_jitter_max_s", "receive_drops")}
    again = RunSummary.from_dict({**old, "version": 1})
    assert again.samples == 1200 and again.min_lead_s == 0.0123
    assert all(math.isnan(getattr(again, f"send_lateness_{name}_s")) for name in ("p50", "p99", "max"))
    assert math.isnan(again.sync_jitter_max_s)
    version_2 = {key: value for key, value in document.items() if key not in ("sync_jitter_max_s", "receive_drops")}
    assert math.isnan(RunSummary.from_dict({**version_2, "version": 2}).sync_jitter_max_s)
    version_3 = {key: value for key, value in document.items() if key != "receive_drops"}
    assert RunSummary.from_dict({**version_3, "version": 3}).receive_drops == 0  # not counted before version 4
    # version 2 without them is malformed
    with pytest.raises(ResultFormatError, match="key 'send_lateness_p50_s' is missing"):
        RunSummary.from_dict({**old, "version": 2})


def test_the_send_lateness_quantiles_of_a_run():
    lateness = np.linspace(0.0, 1e-3, 101)  # 0, 10 us, ..., 1 ms
    quantiles = send_lateness_quantiles(lateness)
    assert quantiles["send_lateness_p50_s"] == pytest.approx(5e-4)
    assert quantiles["send_lateness_p99_s"] == pytest.approx(9.9e-4)
    assert quantiles["send_lateness_max_s"] == 1e-3
    assert all(math.isnan(value) for value in send_lateness_quantiles(np.zeros(0)).values())


def test_the_send_lateness_of_a_long_run_is_kept_in_bounded_memory_within_half_a_bin():
    """Exact up to SendLateness.EXACT_SAMPLES samples; beyond, a fixed histogram: the quantiles within 0.5 %
    of numpy's over every value, the largest exact, and the memory the same for 3 or 300 million samples."""
    rng = np.random.default_rng(5)
    values = np.concatenate([rng.lognormal(np.log(30e-6), 0.5, 200_000), [0.0, 2e-9, 0.25]])
    rng.shuffle(values)
    few, many = SendLateness(), SendLateness()
    for value in values[:1000].tolist():
        few.add(value)
    assert few.quantiles() == send_lateness_quantiles(values[:1000])  # exact
    for value in values.tolist():
        many.add(value)
    got, exact = many.quantiles(), send_lateness_quantiles(values)
    assert got["send_lateness_max_s"] == exact["send_lateness_max_s"] == 0.25
    for name in ("send_lateness_p50_s", "send_lateness_p99_s"):
        assert got[name] == pytest.approx(exact[name], rel=0.005)
    assert many.count == values.size and many.first == values[0] and many.last == values[-1]
    assert np.array_equal(many.kept, values[:SendLateness.EXACT_SAMPLES])
    assert len(many._histogram) == SendLateness.BINS < 2100


@pytest.mark.parametrize("link", ["device-clocked", "host-paced"])
def test_a_run_summary_equals_its_reopened_copy_and_differs_after_a_change(link):
    summary = _summary(**NOT_MEASURED[link])
    again = RunSummary.from_dict(json.loads(json.dumps(summary.to_dict(), allow_nan=False)))
    assert summary == again  # NaN (not measured) equals NaN; the per-sample send lateness is not saved
    assert summary != dataclasses.replace(summary, lost=summary.lost + 1)
    frame = summary.to_pandas()
    assert len(frame) == 1 and frame["samples"].item() == summary.samples
