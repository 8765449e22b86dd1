import numpy as np

from identify.experiment_record import ExperimentMetadata, ExperimentRecord, SampleFlag
from rig.plots.experiment import signal_figure, timing_figure
from rig.report import ReportSection, missing_images, write_report


def make_record():
    n = 200
    time_s = np.arange(n) * 1e-3 + np.r_[0.0, np.full(n - 1, 2e-6)]
    flags = np.zeros(n, dtype=np.uint8)
    flags[50] = SampleFlag.LOST
    flags[80] = SampleFlag.LATE
    angle = np.sin(time_s * 20)
    angle[50] = np.nan
    return ExperimentRecord(time_s, np.sign(np.sin(time_s * 30)), angle, None, flags,
                            ExperimentMetadata(sample_period_s=1e-3, excitation="prbs"))


def test_experiment_figures_render_with_counts_in_captions(tmp_path):
    record = make_record()
    figures = (signal_figure(record, "signals"), timing_figure(record, "timing"))
    assert "1 lost" in figures[0].caption
    assert "1 late cycles" in figures[1].caption
    index = write_report(tmp_path, "Experiment", [ReportSection("Run", figures=figures)])
    assert missing_images(index) == []
