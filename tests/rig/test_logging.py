"""Diagnostics go through ``logging`` (``rig -v`` shows them); the libraries never print."""

from __future__ import annotations

import ast
import json
import logging
import sys
from pathlib import Path


from rig.cli import OUR_LOGGERS, main

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "transports"))
from sim_rigs import CONFIGS, no_leaks, write_test_config  # noqa: E402,F401  (no_leaks is a fixture)


def _run(tmp_path, *verbosity: str) -> list[str]:
    out = tmp_path / f"run{len(verbosity)}.csv"
    code = main([*verbosity, "run", str(write_test_config("serial", tmp_path)), "--experiment",
                 str(CONFIGS / "experiments" / "prbs.toml"), "--out", str(out), "--duration", "0.05", "--json"])
    assert code == 0
    return [str(out)]


def test_rig_v_shows_the_bring_up_and_the_stop_and_keeps_stdout_clean(tmp_path, capsys, no_leaks):
    log = _run(tmp_path, "-v")
    captured = capsys.readouterr()
    assert json.loads(captured.out)["log"] == log[0]  # stdout is still exactly the JSON document
    lines = captured.err.splitlines()
    assert any(line.startswith("rig: INFO rig.transports.simulated: started the simulated serial rig") for line in lines)
    assert any("rig.transports.base" in line and "OPERATION ENABLED" in line for line in lines)
    assert any("rig.transports.base" in line and "disable" in line for line in lines)  # the controlled stop
    assert not any(" DEBUG " in line for line in lines)  # -v is INFO; -vv adds the details
    for name in OUR_LOGGERS:  # restored after the command
        assert logging.getLogger(name).handlers == [] and logging.getLogger(name).level == logging.NOTSET


def test_without_v_no_diagnostics_are_shown(tmp_path, capsys, no_leaks):
    _run(tmp_path)
    assert "rig: INFO" not in capsys.readouterr().err


def test_the_hammerstein_method_logs_the_order_it_chose(caplog):
    from identify.border_lifting import PathNodes
    from identify.cyclic_excitation import cyclic_random_excitation
    from identify.hammerstein_subspace import identify_hammerstein
    from identify.plant_blocks import LinearBlock, PlantModel, pouliquen2013_backlash

    u = cyclic_random_excitation(2050, -3.0, 3.0, hold_samples=50, rng=0)
    plant = PlantModel((pouliquen2013_backlash(), LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804),
                                                               sample_period_s=1.0)))
    with caplog.at_level(logging.INFO, logger="identify"):
        identify_hammerstein(u, plant.simulate(u), PathNodes.uniform(-3.0, 3.0, 8), hold_samples=50, refine=True)
    messages = [record.getMessage() for record in caplog.records if record.name == "identify.hammerstein_subspace"]
    assert any(message.startswith("order 2 chosen from the singular values") for message in messages), messages
    assert any(message.startswith("output-error refinement") for message in messages), messages


def test_no_library_module_calls_print():
    """identify, sim_backend and rig outside rig/commands and rig/cli.py report through results, errors,
    warnings and logging, never print (DESIGN.md, section 4)."""
    offenders = []
    for package in ("identify", "sim_backend", "rig"):
        for path in sorted((ROOT / package).rglob("*.py")):
            relative = path.relative_to(ROOT).as_posix()
            if relative.startswith("rig/commands/") or relative == "rig/cli.py":
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=relative)):
                if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                    offenders.append(f"{relative}:{node.lineno}")
    assert offenders == []
