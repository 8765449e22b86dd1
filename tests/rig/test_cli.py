import subprocess
import sys

from rig.cli import build_parser, main


def test_help_lists_commands_and_exit_codes():
    text = build_parser().format_help()
    assert "identify" in text
    assert "empty feasible set" in text


def test_console_script_runs_as_module():
    result = subprocess.run([sys.executable, "-m", "rig.cli", "--version"], capture_output=True, text=True)
    assert result.returncode == 0
    assert result.stdout.startswith("rig ")


def test_missing_command_is_a_usage_error(capsys):
    try:
        main([])
    except SystemExit as exit_:
        assert exit_.code == 2
    else:
        raise AssertionError("rig without a command must exit with a usage error")
