"""``scripts/check_report_in_chromium`` on pages written for the test: the screenshot covers the whole page, and a
figure outside it, or one that did not load, fails the check by name."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from chromium_check import png_size, require_chromium, run_checker

PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><style>html,body{{margin:0;padding:0}}img{{display:block}}</style></head>
<body>
{body}
</body></html>
"""
BLUE = (0, 0, 255)


@pytest.fixture(autouse=True)
def _chromium():
    require_chromium()


def _png(path: Path, size: tuple[int, int], colour: tuple[int, int, int]) -> None:
    from PIL import Image

    Image.new("RGB", size, colour).save(path)


def test_the_screenshot_covers_a_last_figure_below_content_that_grows_with_the_page_width(tmp_path):
    """A figure is as wide as the page allows, so the page is taller in a wide window than in a narrow one: the
    height that the screenshot needs is the one measured at the screenshot's width, after the images loaded."""
    report = tmp_path / "report"
    report.mkdir()
    _png(report / "first.png", (400, 100), (255, 0, 0))
    _png(report / "last.png", (400, 200), BLUE)
    # The block is twice as tall as the page is wide: 2560 px in the checker's 1280 px wide window.
    (report / "index.html").write_text(PAGE.format(body='<img src="first.png">\n'
                                                        '<div style="padding-top:200%;background:#eee"></div>\n'
                                                        '<img src="last.png">'))
    screenshot = tmp_path / "shot.png"
    completed = run_checker(report, screenshot)
    assert completed.returncode == 0, completed.stdout + completed.stderr
    width, height = png_size(screenshot)
    last_top = 100 + 2 * width
    assert width == 1280 and height >= last_top + 200, (width, height)
    from PIL import Image

    with Image.open(screenshot) as shot:
        assert shot.convert("RGB").getpixel((200, last_top + 190)) == BLUE  # the last figure's bottom rows
    assert "ok: every image loaded and lies within the screenshot" in completed.stdout


def test_a_missing_figure_and_figures_outside_the_screenshot_fail_by_name_with_the_pixels_cut_off(tmp_path):
    report = tmp_path / "report"
    report.mkdir()
    _png(report / "wide.png", (400, 100), BLUE)
    _png(report / "below.png", (400, 200), BLUE)
    _png(report / "shown.png", (400, 100), BLUE)
    (report / "index.html").write_text(PAGE.format(body=(
        '<img src="shown.png">\n'
        '<img src="wide.png" style="position:absolute;left:1100px;top:0">\n'
        '<div style="height:1400px"></div>\n'
        '<img src="below.png">\n'
        '<img src="missing.png" alt="never written">')))
    screenshot = tmp_path / "shot.png"
    completed = run_checker(report, screenshot, "--max-height", "1000")
    assert completed.returncode == 1, completed.stdout + completed.stderr
    assert png_size(screenshot) == (1280, 1000)
    lines = {re.match(r"(?:CUT OFF|NOT LOADED) +(\S+)", line).group(1): line
             for line in completed.stdout.splitlines() if line.startswith(("CUT OFF", "NOT LOADED"))}
    assert set(lines) == {"wide.png", "below.png", "missing.png"}, completed.stdout
    assert "wide.png (image 2 of 4)" in lines["wide.png"] and "below.png (image 3 of 4)" in lines["below.png"]
    assert "220 px beyond the right edge" in lines["wide.png"]  # 1100 + 400 - 1280
    # below the first image (100 px) and the block (1400 px): from 1500 to 1700 px, 1000 px shown
    assert "700 px beyond the bottom edge" in lines["below.png"] and "entirely outside" in lines["below.png"]
    assert "--max-height" in completed.stdout
