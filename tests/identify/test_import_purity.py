"""identify is pure numerics: importing it must not pull in hardware, plotting or driver code."""

import subprocess
import sys

FORBIDDEN = ("can", "canopen", "serial", "matplotlib", "rig", "sim_backend")


def test_import_identify_loads_no_io_or_driver_modules():
    code = (
        "import sys, pkgutil, importlib, identify\n"
        "for info in pkgutil.walk_packages(identify.__path__, 'identify.'):\n"
        "    importlib.import_module(info.name)\n"
        f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r})\n"
        "print(','.join(bad))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "", f"identify imported: {result.stdout.strip()}"


def test_sim_backend_imports_only_protocol_layer_of_rig():
    code = (
        "import sys, pkgutil, importlib, sim_backend\n"
        "for info in pkgutil.walk_packages(sim_backend.__path__, 'sim_backend.'):\n"
        "    importlib.import_module(info.name)\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'rig' and m not in ('rig',)\n"
        "             and not m.startswith('rig.protocols'))\n"
        "print(','.join(bad))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "", f"sim_backend imported: {result.stdout.strip()}"
