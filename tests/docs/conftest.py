"""The documentation site, built once per session for every test of ``tests/docs``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
BUILD_OPTIONS = ["-W", "--keep-going", "-q", "-b", "html"]
"""What ``scripts/build_docs`` passes to sphinx-build (checked in test_docs_build.py), so the tests build what the
script builds."""


@pytest.fixture(scope="session")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("docs") / "html"
    result = subprocess.run([sys.executable, "-m", "sphinx", *BUILD_OPTIONS, "-E", "-d", str(out.parent / "doctrees"),
                             str(DOCS), str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0 and not result.stderr.strip(), (
        f"sphinx-build exited {result.returncode}:\n{result.stderr[-6000:]}")
    return out
