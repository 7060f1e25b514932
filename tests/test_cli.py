"""The command line entry point."""

import subprocess
import sys

import pytest

from ncjax import cli


def test_info_prints_versions_and_conventions(capsys):
    assert cli.main(["info"]) == 0
    out = capsys.readouterr().out
    assert "ncjax 0.1.0" in out and "azimuth" in out


def test_unknown_command_fails_cleanly():
    with pytest.raises(SystemExit) as excinfo:
        cli.main(["frobnicate"])
    assert excinfo.value.code == 2


def test_console_script_runs():
    result = subprocess.run([sys.executable, "-m", "ncjax.cli", "--version"], capture_output=True, text=True)
    assert result.returncode == 0 and "ncjax" in result.stdout
