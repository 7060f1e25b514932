"""benchmarks/compare_runs.py: two benchmark CSVs image by image."""

import pytest
from _scripts import script_module


def compare(argv):
    return script_module("benchmarks", "compare_runs").main(argv)


def write(path, rows):
    path.write_text("\n".join(",".join(str(cell) for cell in row) for row in rows) + "\n")
    return str(path)


@pytest.fixture
def runs(tmp_path):
    header = ("name", "tags", "floor_error_px", "iou_3d")
    base = write(tmp_path / "base.csv", [header, ("a", "", 10, 0.5), ("b", "", 4, 0.9), ("c", "", 6, ""),
                                         ("mean (3 images)", "", 6.67, 0.7)])  # fmt: skip
    other = write(tmp_path / "other.csv", [header, ("b", "", 5, 0.8), ("a", "", 2, 0.75), ("d", "", 1, 1.0),
                                           ("c", "", 6, 0.4), ("mean (3 images)", "", 4.33, 0.65)])  # fmt: skip
    return base, other


def test_each_shared_image_and_which_way_it_moved(runs, capsys):
    assert compare(list(runs)) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "| image | floor_error_px | iou_3d |"
    # sorted by the largest move of the first column: a (-8), then b (+1), then c (0); d is in one run only
    assert [line.split(" |")[0] for line in lines[2:6]] == ["| a", "| b", "| c", "| mean (3 images)"]
    assert "| a | 10.000 -> 2.000 (-8.000) | 0.500 -> 0.750 (+0.250) |" in lines
    assert "| c | 6.000 -> 6.000 (+0.000) | nan -> 0.400 (+nan) |" in lines
    # errors: lower is better; IoU: higher is better; a cell missing in either run is not compared
    assert (
        "floor_error_px: mean 6.667 -> 4.333 (-2.333) over 3 images both scored; 1 better, 1 worse, 1 unchanged"
        in lines
    )
    assert "iou_3d: mean 0.700 -> 0.775 (+0.075) over 2 images both scored; 1 better, 1 worse, 0 unchanged" in lines


def test_sort_and_top(runs, capsys):
    assert compare([*runs, "--sort", "iou_3d", "--top", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[2].startswith("| a |") and lines[3].startswith("| mean (3 images) |")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--columns", "ceiling_error_px"], "unknown column 'ceiling_error_px'"),
        (["--sort", "nope"], "unknown column 'nope'"),
        (["--top", "0"], "--top must be >= 1"),
    ],
)
def test_bad_options_are_one_line(runs, capsys, extra, message):
    assert compare([*runs, *extra]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error


def test_missing_file_or_no_shared_image(runs, tmp_path, capsys):
    assert compare([runs[0], str(tmp_path / "missing.csv")]) == 2
    assert "missing.csv" in capsys.readouterr().err
    lonely = write(tmp_path / "lonely.csv", [("name", "iou_3d"), ("z", 0.3)])
    assert compare([runs[0], lonely]) == 2
    assert "share no image" in capsys.readouterr().err


def test_lower_is_better_for_errors_only():
    better = script_module("benchmarks", "compare_runs").better
    assert better("depth_rmse", 1.0, 0.5) == better("corner_error", 2.0, 1.0) == better("delta1", 0.5, 0.6) == 1
    assert better("iou3d", 0.6, 0.5) == better("floor_error_px", 1.0, 2.0) == -1
    assert better("iou3d", float("nan"), 0.5) == better("iou3d", 0.5, 0.5) == 0
    assert better("floor_signed_error_px", -3.0, 1.0) == 1 and better("floor_signed_error_px", -3.0, -4.0) == -1
    assert better("floor_signed_error_px", -3.0, 3.0) == 0
