import pytest

from rig.report import ReportFigure, ReportSection, missing_images, write_report


def draw_line(figure):
    axes = figure.add_subplot()
    axes.plot([0.0, 1.0], [0.0, 2.0])
    axes.set_xlabel("time [s]")
    axes.set_ylabel("angle [rad]")


def test_report_writes_every_referenced_figure(tmp_path):
    sections = [
        ReportSection("Signals", text="First paragraph.\n\nSecond <b> paragraph.",
                      table_header=("parameter", "true"), table_rows=(("m_l", "0.248"),),
                      figures=(ReportFigure("signals", "The output follows the input.", draw_line),)),
        ReportSection("Timing", figures=(ReportFigure("timing", "Jitter stays below 50 us.", draw_line),)),
    ]
    index = write_report(tmp_path / "report", "Demo", sections)
    page = index.read_text()
    assert page.count("<img ") == 2
    assert "Second &lt;b&gt; paragraph." in page
    assert "<td>0.248</td>" in page
    assert missing_images(index) == []
    (tmp_path / "report" / "timing.png").unlink()
    assert missing_images(index) == ["timing.png"]


def test_duplicate_figure_names_are_refused(tmp_path):
    figure = ReportFigure("same", "caption", draw_line)
    with pytest.raises(ValueError, match="repeated: same"):
        write_report(tmp_path, "x", [ReportSection("a", figures=(figure, figure))])


def test_figure_name_must_be_a_safe_file_stem():
    with pytest.raises(ValueError, match="letters, digits"):
        ReportFigure("../escape", "caption", draw_line)


def test_bounds_that_are_rounding_of_zero_print_as_zero_and_others_keep_their_digits():
    from rig.report import format_interval

    assert format_interval(-1.1535e-14, 0.011535) == "[0, 0.011535]"  # an LP vertex at a dead band's start
    assert format_interval(-3.2141, -3.0926) == "[-3.2141, -3.0926]"
    assert format_interval(-1e-6, 1e-6) == "[-1e-06, 1e-06]"  # small, but not small against its width
    assert format_interval(2.0e-12, float("inf")) == "[2e-12, inf]"  # no width to compare with: kept
    assert format_interval(0.25, 0.25, digits=3, unit="rad") == "[0.25, 0.25] rad"
