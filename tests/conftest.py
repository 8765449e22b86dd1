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


SERVO_VARIABLES = {
    "2.0": """  <ModelVariables>
    <ScalarVariable name="command" valueReference="0" causality="input" variability="continuous"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="angle" valueReference="1" causality="output" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="speed" valueReference="2" causality="local" variability="continuous" initial="exact"><Real start="0" derivative="2"/></ScalarVariable>
    <ScalarVariable name="acceleration" valueReference="3" causality="local" variability="continuous"><Real derivative="3"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="2"/></Outputs>
    <Derivatives><Unknown index="3"/><Unknown index="4"/></Derivatives>
  </ModelStructure>
""",
    "3.0": """  <ModelVariables>
    <Float64 name="command" valueReference="0" causality="input" start="0"/>
    <Float64 name="angle" valueReference="1" causality="output" initial="exact" start="0"/>
    <Float64 name="speed" valueReference="2" causality="local" initial="exact" start="0" derivative="1"/>
    <Float64 name="acceleration" valueReference="3" causality="local" derivative="2"/>
    <Float64 name="angle_above_half" valueReference="4" causality="local"/>
  </ModelVariables>
  <ModelStructure>
    <Output valueReference="1"/>
    <ContinuousStateDerivative valueReference="2"/>
    <ContinuousStateDerivative valueReference="3"/>
    <EventIndicator valueReference="4"/>
  </ModelStructure>
""",
}


def build_c_servo(folder: Path, fmi_version: str, interfaces: tuple[str, ...]) -> Path:
    """``tests/fmu_models/servo.c`` compiled with gcc for this platform and zipped as an FMI ``fmi_version``
    FMU that declares ``interfaces`` ("ModelExchange", "CoSimulation")."""
    import shutil
    import subprocess

    import fmpy

    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc is needed to build the C test FMU (apt-get install gcc)")
    platform = fmpy.platform if fmi_version == "2.0" else fmpy.platform_tuple
    name = f"servo_fmi{fmi_version[0]}_{'_'.join(i.lower() for i in interfaces)}"
    library = folder / f"{name}.so"
    subprocess.run([gcc, "-shared", "-fPIC", "-O2", *(["-DFMI3"] if fmi_version != "2.0" else []),
                    "-o", str(library), str(FMU_MODELS / "servo.c"), "-lm"], check=True)
    token = 'guid="{8c4e810f-3df3-4a00-8276-176fa3c9f000}"' if fmi_version == "2.0" else \
        'instantiationToken="{8c4e810f-3df3-4a00-8276-176fa3c9f000}"'
    events = ' numberOfEventIndicators="1"' if fmi_version == "2.0" else ""
    declared = "".join(f'  <{interface} modelIdentifier="servo"/>\n' for interface in interfaces)
    description = (f'<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="{fmi_version}" '
                   f'modelName="servo" {token}{events}>\n{declared}{SERVO_VARIABLES[fmi_version]}'
                   "</fmiModelDescription>\n")
    path = folder / f"{name}.fmu"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("modelDescription.xml", description)
        archive.write(library, f"binaries/{platform}/servo.so")
    return path


@pytest.fixture(scope="session")
def c_servo_fmus(tmp_path_factory) -> dict[tuple[str, str], Path]:
    """The C servo as FMI 2.0 and 3.0, each with only a model-exchange or only a co-simulation interface."""
    folder = tmp_path_factory.mktemp("c_fmus")
    return {(version, interface): build_c_servo(folder, version, (interface,))
            for version in ("2.0", "3.0") for interface in ("ModelExchange", "CoSimulation")}
