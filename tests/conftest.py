"""Fixtures shared across the test folders."""

from __future__ import annotations

from pathlib import Path

import pytest

from fmu_models.build import PYTHON_MODELS, build_c_servo, build_python_fmu, without_linux_binaries


@pytest.fixture(scope="session")
def test_fmus(tmp_path_factory) -> dict[str, Path]:
    """The test FMUs of ``tests/fmu_models``, built once per session with pythonfmu (offline: its C wrapper
    ships in the wheel; about 0.1 s each), and one copy of the gearbox without its Linux binary."""
    folder = tmp_path_factory.mktemp("fmus")
    built = {name: build_python_fmu(name, folder) for name in PYTHON_MODELS}
    built["windows_only"] = without_linux_binaries(built["gearbox_servo"], folder / "windows_only.fmu")
    return built


@pytest.fixture(scope="session")
def c_servo_fmus(tmp_path_factory) -> dict[tuple[str, str] | str, Path]:
    """The C servo as FMI 2.0 and 3.0, each with only a model-exchange or only a co-simulation interface, and
    as FMI 2.0 co-simulation with a reset that keeps its state (``"broken_reset"``)."""
    import shutil

    if shutil.which("gcc") is None:
        pytest.skip("gcc is needed to build the C test FMU (apt-get install gcc)")
    folder = tmp_path_factory.mktemp("c_fmus")
    built = {(version, interface): build_c_servo(folder, version, (interface,))
             for version in ("2.0", "3.0") for interface in ("ModelExchange", "CoSimulation")}
    built["broken_reset"] = build_c_servo(folder, "2.0", ("CoSimulation",), broken_reset=True)
    return built
