"""Run ``scripts/check_report_in_chromium`` from a test, and read what it wrote (standard library only)."""

from __future__ import annotations

import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pytest

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
