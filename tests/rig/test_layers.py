"""The layers of rig (docs/design.md): the library modules never import the commands; the commands import them."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _imported_modules(tree: ast.AST) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module is not None and node.level == 0:
            names.add(node.module)
    return names


def test_no_library_module_of_rig_imports_the_commands():
    offenders = []
    for path in sorted((ROOT / "rig").rglob("*.py")):
        relative = path.relative_to(ROOT).as_posix()
        if relative.startswith("rig/commands/") or relative == "rig/cli.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=relative)
        offenders += [f"{relative}: {name}" for name in sorted(_imported_modules(tree))
                      if name == "rig.commands" or name.startswith("rig.commands.")]
    assert offenders == []


def test_the_check_sees_a_lazy_import_inside_a_function():
    tree = ast.parse("def f():\n    from rig.commands.run import load_command_file\n")
    assert "rig.commands.run" in _imported_modules(tree)
