"""Inputs of the report tests: a CSV of columns, and the JSON a ``rig`` command prints, saved as a file."""

from __future__ import annotations

from pathlib import Path

from rig import exit_codes
from rig.cli import main


def write_csv(path: Path, header: str, *columns) -> Path:
    """``path`` with the header line and one row per sample of ``columns`` (floats in full precision)."""
    path.write_text(header + "\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in zip(*columns)))
    return path


def printed_to(capsys, argv: list[str], path: Path, expected_code: int = exit_codes.SUCCESS) -> Path:
    """Run ``rig argv``, check its exit code, and save what it printed (its ``--json``) to ``path``."""
    assert main(argv) == expected_code
    path.write_text(capsys.readouterr().out)
    return path
