"""Run ``scripts/check_report_in_chromium`` from a test, and read what it wrote (standard library only)."""

from __future__ import annotations

import re
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pytest

CONTENT_WIDTH_PX = 960  # the report's column (rig.report's style: max-width 60rem); wider figures are scaled down

CHECKER = Path(__file__).resolve().parents[2] / "scripts" / "check_report_in_chromium"
CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def require_chromium() -> str:
    """The Chromium executable the checker will find; skips the test when there is none."""
    for candidate in CHROMIUM_CANDIDATES:
        found = candidate if Path(candidate).is_file() else shutil.which(candidate)
        if found:
            return found
    pytest.skip("Chromium is not installed (on Debian or Ubuntu: apt-get install chromium)")


def run_checker(report: Path, screenshot: Path, *options: str) -> subprocess.CompletedProcess:
    """The checker on ``report``, its screenshot written to ``screenshot``; never raises on its exit code."""
    return subprocess.run([sys.executable, str(CHECKER), str(report), "--screenshot", str(screenshot), *options],
                          capture_output=True, text=True, timeout=300, check=False)


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) in pixels of a PNG file, from its IHDR chunk."""
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR", f"{path} is not a PNG file"
    return struct.unpack(">II", head[16:24])


def check_page(index: Path, tmp_path: Path, figures: int) -> None:
    """The checker passes on the page, and the screenshot is at least as tall as the page's figures stacked."""
    page = index.read_text(encoding="utf-8")
    sources = re.findall(r'<img src="([^"]+)"', page)
    assert len(sources) == figures
    screenshot = tmp_path / "screenshot.png"
    completed = run_checker(index.parent, screenshot)
    assert completed.returncode == 0, completed.stdout + completed.stderr
    assert f"images      {figures} in the rendered page, {figures} in the page source, {figures} loaded" in \
        completed.stdout
    assert "ok: every image loaded and lies within the screenshot" in completed.stdout
    # Independently of the checker's own measurement: the figures stand one below the other, each at its size
    # in the page's column, so the screenshot must be at least as tall as they are together.
    shown_heights = []
    for source in sources:
        width, height = png_size(index.parent / source)
        shown_heights.append(height * min(1.0, CONTENT_WIDTH_PX / width))
    shot_width, shot_height = png_size(screenshot)
    assert shot_width == 1280 and shot_height >= sum(shown_heights), (shot_height, sum(shown_heights))
