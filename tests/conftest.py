"""Fixtures shared across the test folders."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest

FMU_MODELS = Path(__file__).resolve().parent / "fmu_models"


@pytest.fixture(scope="session")
def test_fmus(tmp_path_factory) -> dict[str, Path]:
    """The test FMUs of ``tests/fmu_models``, built once per session with pythonfmu (offline: its C wrapper
    ships in the wheel; about 0.1 s each), and one copy of the gearbox without its Linux binary."""
    from pythonfmu.builder import FmuBuilder

    folder = tmp_path_factory.mktemp("fmus")
    built = {name: Path(FmuBuilder.build_FMU(FMU_MODELS / f"{name}.py", dest=folder))
             for name in ("gearbox_servo", "two_port_gearbox")}
    windows_only = folder / "windows_only.fmu"
    with zipfile.ZipFile(built["gearbox_servo"]) as source, zipfile.ZipFile(windows_only, "w") as target:
        for item in source.infolist():
            if not item.filename.startswith("binaries/linux"):
                target.writestr(item, source.read(item.filename))
    built["windows_only"] = windows_only
    return built
