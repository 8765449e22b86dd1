"""Build the test FMUs (used by tests/conftest.py and benchmarks/fmu_plant_throughput.py): the Python models
with pythonfmu, the C servo with gcc; nothing is downloaded."""

from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

FMU_MODELS = Path(__file__).resolve().parent
PYTHON_MODELS = ("gearbox_servo", "two_port_gearbox")


def build_python_fmu(name: str, folder: Path) -> Path:
    """``fmu_models/<name>.py`` built by pythonfmu into ``folder`` (an FMI 2.0 co-simulation FMU; pythonfmu
    ships its C wrapper in its wheel, so this works offline)."""
    from pythonfmu.builder import FmuBuilder

    return Path(FmuBuilder.build_FMU(FMU_MODELS / f"{name}.py", dest=folder))


def without_linux_binaries(path: Path, out: Path) -> Path:
    """A copy of the FMU at ``path`` without its Linux binaries (an FMU exported for Windows only)."""
    with zipfile.ZipFile(path) as source, zipfile.ZipFile(out, "w") as target:
        for item in source.infolist():
            if not item.filename.startswith("binaries/linux"):
                target.writestr(item, source.read(item.filename))
    return out


def with_model_description(path: Path, out: Path, edits: dict[str, str]) -> Path:
    """A copy of the FMU at ``path`` whose modelDescription.xml has each key of ``edits`` replaced by its value
    (a unit, a range or a causality that the Python model cannot declare; its binary does not read them)."""
    with zipfile.ZipFile(path) as source, zipfile.ZipFile(out, "w") as target:
        for item in source.infolist():
            content = source.read(item.filename)
            if item.filename == "modelDescription.xml":
                text = content.decode("utf-8")
                for old, new in edits.items():
                    if old not in text:
                        raise ValueError(f"{path}: modelDescription.xml has no {old!r}")
                    text = text.replace(old, new)
                content = text.encode("utf-8")
            target.writestr(item, content)
    return out


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


def build_c_servo(folder: Path, fmi_version: str, interfaces: tuple[str, ...], broken_reset: bool = False) -> Path:
    """``tests/fmu_models/servo.c`` compiled with gcc for this platform and zipped as an FMI ``fmi_version``
    FMU that declares ``interfaces`` ("ModelExchange", "CoSimulation"); ``broken_reset``: its reset keeps
    the state."""
    import fmpy

    gcc = shutil.which("gcc")
    if gcc is None:
        raise FileNotFoundError("gcc is needed to build the C test FMU (apt-get install gcc)")
    platform = fmpy.platform if fmi_version == "2.0" else fmpy.platform_tuple
    name = f"servo_fmi{fmi_version[0]}_{'_'.join(i.lower() for i in interfaces)}{'_broken_reset' * broken_reset}"
    library = folder / f"{name}.so"
    subprocess.run([gcc, "-shared", "-fPIC", "-O2", *(["-DFMI3"] if fmi_version != "2.0" else []),
                    *(["-DBROKEN_RESET"] if broken_reset else []),
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
