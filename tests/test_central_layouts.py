"""benchmarks/central_layouts.py: options it passes on to ``ncjax reconstruct`` and their refusal."""

import numpy as np
import pytest
from _scripts import script_module
from PIL import Image


def benchmark_module():
    """The module of ``benchmarks/central_layouts.py``."""
    return script_module("benchmarks", "central_layouts")


@pytest.mark.parametrize("options", [["--manhattan-margin", "2"], ["--wrold", "auto"]])
def test_an_option_reconstruct_refuses_is_an_error_and_no_earlier_record_is_scored(options, tmp_path, capsys):
    data, out = tmp_path / "data", tmp_path / "out"
    data.mkdir()
    Image.fromarray(np.zeros((64, 128, 3), np.uint8)).save(data / "room.png")
    (data / "room.txt").write_text("10 20\n10 40\n50 20\n50 40\n90 20\n90 40\n120 20\n120 40\n")
    out.mkdir()
    (out / "room.json").write_text('{"status": "OK"}')  # an earlier run's record
    assert benchmark_module().main(["--data", str(data), "--out", str(out), *options]) == 2
    captured = capsys.readouterr()
    assert captured.err.strip().endswith("central_layouts: error: ncjax reconstruct exited with code 2")
    assert "| room |" not in captured.out and not (out / "room.json").exists()
