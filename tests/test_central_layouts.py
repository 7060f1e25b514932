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


def test_a_written_layout_the_metrics_cannot_back_project_counts_as_none(tmp_path, monkeypatch, capsys):
    """A layout whose ceiling corner is at the horizon (a run-away ceiling) is reported, not a crash."""
    module = benchmark_module()
    data, out = tmp_path / "data", tmp_path / "out"
    data.mkdir()
    Image.fromarray(np.zeros((64, 128, 3), np.uint8)).save(data / "room.png")
    (data / "room.txt").write_text("10 20\n10 40\n50 20\n50 40\n90 20\n90 40\n120 20\n120 40\n")

    def reconstruct(command):
        out.mkdir(exist_ok=True)
        (out / "room.json").write_text('{"status": "LOW_CONFIDENCE", "explained_fraction": 0.01}')
        (out / "room.label_cor.txt").write_text("10 32\n10 40\n50 20\n50 40\n90 20\n90 40\n120 20\n120 40\n")
        return 0

    monkeypatch.setattr(module, "ncjax_main", reconstruct)
    assert module.main(["--data", str(data), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| room | LOW_CONFIDENCE | 0.01 | not scored: " in printed and "horizon" in printed
    assert "0 of 1 images gave a layout" in printed and "1 written layouts could not be scored" in printed
    table = (out / "central_layouts.csv").read_text().splitlines()
    assert table[0] == "name,status,explained,iou2d,iou3d,corner_error,pixel_error,depth_rmse,delta1"
    assert table[1] == "room,LOW_CONFIDENCE,0.01,0.0,0.0,,,,"  # no layout: IoU 0, as the printed mean counts it
    assert table[2].startswith("mean (1 images),,,0.0,0.0,nan,")
