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


def test_edge_snap_is_on_unless_asked_off():
    import argparse

    from ncjax import EdgeSnap
    from ncjax._app import add_reconstruct_arguments

    parser = argparse.ArgumentParser()
    add_reconstruct_arguments(parser)
    base = ["room.png", "--rc", "0.5", "--out", "out"]
    assert parser.parse_args(base).edge_snap == EdgeSnap()
    assert parser.parse_args([*base, "--no-edge-snap"]).edge_snap is None


def test_fine_tuning_from_another_architecture_is_refused(tmp_path, capsys):
    import ncjax

    tiny = ncjax.HorizonNetConfig(depth=10, width=8, input_height=64, input_width=128, lstm_hidden=16, lstm_layers=1)
    ncjax.save_model(ncjax.init_model(tiny), tmp_path / "tiny.safetensors")
    checkpoints = tmp_path / "checkpoints"
    code = cli.main(["train", "--data", "painted", "--steps", "1", "--corner-base", "0.8", "--checkpoint-dir",
                     str(checkpoints), "--init-from", str(tmp_path / "tiny.safetensors")])
    assert code == 2 and "cannot start" in capsys.readouterr().err and not checkpoints.exists()
