"""The files of the command line: outputs that appear together, reruns, resuming, folders as input,
Ctrl-C, unwritable or wrong paths, bad model files, summary.csv of several runs, help texts and the
mesh's orientation. The reconstruction itself is replaced by a fast stand-in where only the files count."""

from __future__ import annotations

import argparse
import csv
import json
import os
import pickle
import signal

import jax
import numpy as np
import pytest
from test_app import write_png
from test_export import L_SHAPE, RECTANGLE, failed_layout, make_layout

import ncjax
import ncjax.io.export
import ncjax.network.predict
import ncjax.reconstruction
from ncjax import cli
from ncjax.cli import demo, inputs, outputs, reconstruct, summary
from ncjax.cli.arguments import DefaultsHelpFormatter
from ncjax.cli.main import build_parser
from ncjax.io.files import replace_together
from ncjax.network.checkpoint import load_model
from ncjax.network.config import AdaptConfig
from ncjax.reconstruction import Reconstruction
from ncjax.viz import overlay

SIZE = (128, 64)  # (W, H) of the stand-in panoramas
IMAGE = np.full((SIZE[1], SIZE[0], 3), 90, np.uint8)
MESH_SUFFIXES = (".obj", ".ply", ".glb")


class FakeReconstruction:
    """A stand-in for :func:`ncjax.reconstruction.reconstruct_batch`: the same layout for every image, at once.

    Attributes:
        layout: the unbatched layout every image gets.
        calls: the number of images of each call.
        batch_sizes: the ``batch_size`` of each call (the programs' chunk).
        adapt: the ``adapt`` of each call.
        interrupt_on_call: raise KeyboardInterrupt on this call (1-based), None never.
        signal_on_call: send this process SIGINT (a Ctrl-C) during this call, None never.
    """

    def __init__(self, layout=None, interrupt_on_call=None, signal_on_call=None):
        self.layout = make_layout(RECTANGLE) if layout is None else layout
        self.calls: list[int] = []
        self.batch_sizes: list[int] = []
        self.adapt: list = []
        self.interrupt_on_call = interrupt_on_call
        self.signal_on_call = signal_on_call

    def __call__(self, images, rc, world, **options):
        self.calls.append(len(images))
        self.batch_sizes.append(options["batch_size"])
        self.adapt.append(options["adapt"])
        if len(self.calls) == self.interrupt_on_call:
            raise KeyboardInterrupt
        if len(self.calls) == self.signal_on_call:
            signal.raise_signal(signal.SIGINT)
        batch, height, width = images.shape[:3]
        layouts = jax.tree.map(lambda *fields: np.stack([np.asarray(x) for x in fields]), *[self.layout] * batch)
        rows = np.full((batch, width), 0.3 * height, np.float32)
        # the plumbing only (the gate itself: tests/test_adapt.py): every panorama within max_rc counts as adapted
        adapt = options["adapt"]
        adapted = np.asarray(rc) <= (-1.0 if adapt is None else adapt.max_rc)
        return Reconstruction(
            layouts, rows, height - rows, np.zeros((batch, width), np.float32), np.zeros(batch, np.int32), None, adapted
        )


@pytest.fixture
def fake(monkeypatch):
    """Every ``ncjax reconstruct`` of the test uses a :class:`FakeReconstruction` (set its attributes to vary)."""
    stand_in = FakeReconstruction()
    monkeypatch.setattr(ncjax.reconstruction, "reconstruct_batch", stand_in)
    return stand_in


def panoramas(folder, *names):
    folder.mkdir(parents=True, exist_ok=True)
    return [write_png(folder / f"{name}.png", IMAGE) for name in names]


def reconstruct_cli(images, out, *options):
    return cli.main(["reconstruct", *map(str, images), "--rc", "0.5", "--out", str(out), *options])


def summary_rows(out):
    with open(out / "summary.csv", newline="") as file:
        return list(csv.DictReader(file))


def files_of(out, name):
    """The files of the image ``name`` in ``out``."""
    return sorted(
        path.name for path in out.iterdir() if path.name.split(".")[0] in (name, f"{name}_overlay", f"{name}_plan")
    )


def error_lines(stderr):
    """The lines of stderr that are not the progress bar's."""
    return [line for line in stderr.splitlines() if line.strip() and "%|" not in line]


# ----------------------------------------------------------------------------- outputs of one image


@pytest.mark.slow
def test_the_outputs_of_an_image_appear_together_or_not_at_all(tmp_path, fake, monkeypatch, capsys):
    real_write_png = ncjax.io.export.write_png

    def full_disk_for_b(path, image):
        if os.path.basename(path).startswith("b_"):  # after b's json, meshes and layout formats
            raise OSError(28, "No space left on device", str(path))
        real_write_png(path, image)

    monkeypatch.setattr(ncjax.io.export, "write_png", full_disk_for_b)
    out = tmp_path / "out"
    assert reconstruct_cli(panoramas(tmp_path / "in", "a", "b", "c"), out, "--export", "label_cor") == 1
    assert files_of(out, "a") == sorted([*outputs.output_names("a")[:7], "a.label_cor.txt"])
    assert files_of(out, "b") == [] and not [name for name in os.listdir(out) if name.startswith(".")]
    assert files_of(out, "c") == sorted([*outputs.output_names("c")[:7], "c.label_cor.txt"])
    rows = {row["name"]: row for row in summary_rows(out)}
    assert [rows[name]["result"] for name in "abc"] == ["ok", "error", "ok"]
    assert rows["b"]["message"].startswith("its outputs could not be written (")
    assert "b_overlay.png: No space left on device" in capsys.readouterr().err


def test_a_failed_write_keeps_the_earlier_outputs_of_the_image(tmp_path, fake, monkeypatch):
    images = panoramas(tmp_path / "in", "room")
    out = tmp_path / "out"
    assert reconstruct_cli(images, out) == 0
    earlier = {name: (out / name).read_bytes() for name in os.listdir(out) if name != "summary.csv"}

    def interrupted(path, image):
        raise KeyboardInterrupt

    monkeypatch.setattr(ncjax.io.export, "write_png", interrupted)
    fake.layout = failed_layout()
    assert reconstruct_cli(images, out) == 130
    assert {name: (out / name).read_bytes() for name in os.listdir(out) if name != "summary.csv"} == earlier


def test_files_staged_together_are_renamed_together_or_removed(tmp_path):
    (tmp_path / "old.txt").write_text("old")
    (tmp_path / "stale.txt").write_text("stale")
    (tmp_path / "other.txt").write_text("other")
    with pytest.raises(KeyboardInterrupt), replace_together(tmp_path, owned=["old.txt", "stale.txt"]) as staging:
        (staging / "old.txt").write_text("new")
        raise KeyboardInterrupt
    assert sorted(os.listdir(tmp_path)) == ["old.txt", "other.txt", "stale.txt"]
    assert (tmp_path / "old.txt").read_text() == "old"
    with replace_together(tmp_path, owned=["old.txt", "stale.txt", "record.json"], last="record.json") as staging:
        (staging / "old.txt").write_text("new")
        (staging / "record.json").write_text("{}")
    assert sorted(os.listdir(tmp_path)) == ["old.txt", "other.txt", "record.json"]
    assert (tmp_path / "old.txt").read_text() == "new"


def test_a_rerun_removes_the_outputs_the_new_layout_does_not_have(tmp_path, fake):
    images = panoramas(tmp_path / "in", "room")
    out = tmp_path / "out"
    assert reconstruct_cli(images, out, "--export", "label_cor,zind") == 0
    assert files_of(out, "room") == sorted(
        ["room.json", "room.obj", "room.ply", "room.glb", "room.html", "room.label_cor.txt", "room.zind.json"]
        + ["room_overlay.png", "room_plan.png"]
    )
    fake.layout = failed_layout()
    assert reconstruct_cli(images, out, "--export", "label_cor,zind") == 1
    assert json.loads((out / "room.json").read_text())["ok"] is False
    assert files_of(out, "room") == ["room.json", "room_overlay.png", "room_plan.png"]
    fake.layout = make_layout(RECTANGLE)
    assert reconstruct_cli(images, out, "--export", "zind") == 0
    assert "room.zind.json" in files_of(out, "room") and "room.label_cor.txt" not in files_of(out, "room")
    assert reconstruct_cli(images, out) == 0
    assert not any(name.endswith((".zind.json", ".label_cor.txt")) for name in os.listdir(out))


def test_the_mesh_normals_point_out_of_the_room(tmp_path, fake):
    fake.layout = make_layout(L_SHAPE)
    out = tmp_path / "out"
    assert reconstruct_cli(panoramas(tmp_path / "in", "room"), out) == 0
    record = json.loads((out / "room.json").read_text())
    lines = (out / "room.obj").read_text().splitlines()
    assert "normals point out of the room" in lines[0]
    vertices = np.array([[float(x) for x in line.split()[1:]] for line in lines if line.startswith("v ")])
    faces = np.array([[int(i) - 1 for i in line.split()[1:]] for line in lines if line.startswith("f ")])
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    signed_volume = np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6
    assert record["floor_area"] == pytest.approx(21.0)
    assert signed_volume == pytest.approx(record["floor_area"] * record["room_height"], rel=1e-5)


# ----------------------------------------------------------------------------- which images


def test_skip_existing_resumes_a_batch(tmp_path, fake, capsys):
    images = panoramas(tmp_path / "in", "a", "b", "c")
    out = tmp_path / "out"
    assert reconstruct_cli(images[:1], out) == 0
    (out / "c.json").write_text("not json")  # an unreadable record is skipped too
    fake.calls.clear()
    capsys.readouterr()
    assert reconstruct_cli(images, out, "--skip-existing", "--batch", "1") == 0
    assert fake.calls == [1]  # b only
    rows = {row["name"]: row for row in summary_rows(out)}
    assert [rows[name]["result"] for name in "abc"] == ["skipped", "ok", "skipped"]
    assert rows["a"]["room_height_m"] == "2.5000" and rows["a"]["floor_area_m2"] == "12.0000"
    assert "earlier result: ok" in rows["a"]["message"] and "unreadable" in rows["c"]["message"]
    printed = capsys.readouterr().out
    assert "1 of 3 images reconstructed" in printed and "2 skipped" in printed


def test_batches_are_the_images_and_the_programs_take_the_batch_size(tmp_path, fake):
    for batch in ("1", "2"):
        fake.calls.clear()
        fake.batch_sizes.clear()
        assert reconstruct_cli(panoramas(tmp_path / "in", "a", "b", "c"), tmp_path / batch, "--batch", batch) == 0
        # the run's first image alone (its files come soonest), then batches of --batch (reconstruct_batch pads a
        # short one: the programs take the batch size whatever the images)
        assert fake.calls == ([1, 1, 1] if batch == "1" else [1, 2])
        assert set(fake.batch_sizes) == {int(batch)}


def test_one_key_gives_every_image_the_key_of_a_batch_of_one():
    from ncjax.reconstruction import _image_key_data

    alone = np.asarray(jax.random.key_data(jax.random.split(jax.random.key(0), 1)[0]))
    for key in (None, jax.random.key(0), jax.random.PRNGKey(0)):
        data, impl = _image_key_data(key, 3)
        np.testing.assert_array_equal(data, np.broadcast_to(alone, (3, *alone.shape)))
        assert impl == "threefry2x32"
    per_image = jax.random.split(jax.random.key(7), 3)
    np.testing.assert_array_equal(_image_key_data(per_image, 3)[0], jax.random.key_data(per_image))


@pytest.mark.slow
def test_folders_give_their_panoramas(tmp_path, fake, capsys):
    folder = tmp_path / "captures"
    panoramas(folder, "b", "a")
    write_png(folder / "c.JPG", IMAGE)
    panoramas(folder / "floor2", "d")
    panoramas(folder / ".thumbnails", "e")
    (folder / "notes.txt").write_text("not a panorama")
    (folder / ".hidden.png").write_bytes(b"")
    flat = inputs.expand_inputs([str(folder)])
    assert flat == [str(folder / name) for name in ("a.png", "b.png", "c.JPG")]
    deep = inputs.expand_inputs([str(folder)], recursive=True)
    assert deep == [*flat, str(folder / "floor2" / "d.png")]
    out = folder / "out"  # an output folder inside the input folder is never read
    assert reconstruct_cli([folder], out, "--recursive") == 0
    assert [row["name"] for row in summary_rows(out)] == ["a", "b", "c", "d"]
    assert reconstruct_cli([folder], out, "--recursive") == 0
    assert [row["name"] for row in summary_rows(out)] == ["a", "b", "c", "d"]
    same = tmp_path / "same"  # outputs beside the panoramas: a rerun does not read the overlays
    panoramas(same, "room")
    for _ in range(2):
        assert reconstruct_cli([same], same) == 0
        assert [row["name"] for row in summary_rows(same)] == ["room"]


def test_a_folder_without_panoramas_is_one_line_before_any_work(tmp_path, fake, capsys):
    empty = tmp_path / "empty"
    (empty / "sub").mkdir(parents=True)
    panoramas(empty / "sub", "room")
    out = tmp_path / "out"
    assert reconstruct_cli([empty], out) == 2
    error = capsys.readouterr().err
    assert len(error.strip().splitlines()) == 1 and "without panorama files" in error and "--recursive" in error
    assert not out.exists() and fake.calls == []


def test_a_resized_panorama_is_exported_in_the_pixels_of_its_file(tmp_path, fake, capsys):
    """A file wider than 2048 pixels is reconstructed at 2048 x 1024, and its outputs give the file's pixels:
    the JSON's image_size and corner_columns, label_cor and HorizonNet's json, which ncjax evaluate reads so."""
    from ncjax.io.formats_read import read_layout
    from ncjax.io.layout_corners import project_points

    file_size = (4100, 2050)
    (tmp_path / "in").mkdir()
    image = write_png(tmp_path / "in" / "wide.png", np.full((file_size[1], file_size[0], 3), 90, np.uint8))
    out = tmp_path / "out"
    assert reconstruct_cli([image], out, "--export", "label_cor,horizonnet", "--texture-size", "64") == 0
    record = json.loads((out / "wide.json").read_text())
    assert record["image_size"] == list(file_size) and record["reconstructed_size"] == [2048, 1024]
    mask = np.asarray(fake.layout.mask)
    columns = np.asarray(fake.layout.corner_columns, np.float64)[mask]
    np.testing.assert_allclose(record["corner_columns"], (columns + 0.5) * file_size[0] / 2048 - 0.5, atol=1e-4)
    # the corners projected into the file's image (label_cor starts at the leftmost: compare by column)
    cam = ncjax.NonCentralPanorama(*file_size, rc=0.5)
    expected = project_points(cam, np.asarray(record["ceiling_corners"]))
    label = read_layout(out / "wide.label_cor.txt", *file_size)
    np.testing.assert_allclose(
        label.ceiling[np.argsort(label.ceiling[:, 0])], expected[np.argsort(expected[:, 0])], atol=1e-3
    )
    assert label.ceiling[:, 0].max() > 2048  # not the 2048-wide image's pixels
    assert json.loads((out / "wide.horizonnet.json").read_text())["ncjax"]["image_size"] == list(file_size)
    # ncjax evaluate reads the label_cor, which records no size, at the size the record gives: the same layout
    scores = tmp_path / "scores.json"
    assert cli.main(["evaluate", str(out / "wide.label_cor.txt"), str(out / "wide.json"), "--json", str(scores)]) == 0
    (row,) = json.loads(scores.read_text())["images"].values()
    assert row["iou2d"] > 0.999 and row["iou3d"] > 0.999 and row["corner_error"] < 1e-3, row


def test_a_flagged_layout_is_one_short_line_and_its_reason_is_in_the_summary(tmp_path, fake, capsys):
    fake.layout = make_layout(RECTANGLE, status=int(ncjax.LayoutStatus.LOW_CONFIDENCE))
    image = panoramas(tmp_path / "in", "room")
    out = tmp_path / "out"
    assert reconstruct_cli(image, out) == 1
    lines = error_lines(capsys.readouterr().err)
    assert lines == [
        "1 failed (what each status means: summary.csv's reason column):",
        f"  {image[0]}: layout of low confidence written (LOW_CONFIDENCE; room height 2.50 ± 0.02 m); "
        "see room_overlay.png",
    ]
    (row,) = summary_rows(out)
    assert row["result"] == "low confidence" and row["message"] == lines[1].removeprefix(f"  {image[0]}: ")
    assert row["reason"] == ncjax.LayoutStatus.LOW_CONFIDENCE.reason


def test_the_demo_adapts_as_reconstruct_does_by_default():
    """``ncjax demo`` and ``ncjax reconstruct`` share their programs only if their settings, adaptation included,
    are the same."""
    args = build_parser().parse_args(["reconstruct", "room.png", "--rc", "0", "--out", "out"])
    assert args.adapt and demo.ADAPT == AdaptConfig(max_rc=args.adapt_max_rc)


def test_the_network_adapts_to_panoramas_by_default_and_each_record_says_whether_it_did(tmp_path, fake, capsys):
    images = panoramas(tmp_path / "in", "a", "b")
    out = tmp_path / "out"
    assert reconstruct_cli(images, out, "--rc", "0") == 0
    assert fake.adapt == [AdaptConfig()] * 2  # reconstruct_batch decides per panorama (min_loss, max_rc)
    assert all(json.loads((out / f"{name}.json").read_text())["adapted"] is True for name in "ab")
    assert (
        capsys.readouterr().out.rstrip().endswith("; 2 read by the network adapted to their own flat floor and ceiling")
    )
    for options in (["--rc", "0", "--no-adapt"], []):  # not asked to, or a rig's panoramas (rc 0.5)
        assert reconstruct_cli(images, out, *options) == 0
        assert fake.adapt[-1] == (None if options else AdaptConfig())
        assert all(json.loads((out / f"{name}.json").read_text())["adapted"] is False for name in "ab")
        assert "adapted" not in capsys.readouterr().out
    # the rig's panoramas too when asked; a negative radius is one line, with nothing written
    assert reconstruct_cli(images, out, "--adapt-max-rc", "inf") == 0
    assert fake.adapt[-1] == AdaptConfig(max_rc=np.inf)
    assert reconstruct_cli(images, tmp_path / "none", "--adapt-max-rc", "-1") == 2
    assert error_lines(capsys.readouterr().err)[-1] == "ncjax reconstruct: error: --adapt-max-rc must be >= 0, got -1.0"
    assert not (tmp_path / "none").exists()


# ----------------------------------------------------------------------------- Ctrl-C


def test_ctrl_c_writes_the_summary_of_the_images_done(tmp_path, fake, capsys):
    images = panoramas(tmp_path / "in", "a", "b", "c", "d")
    out = tmp_path / "out"
    fake.interrupt_on_call = 3  # after a (alone, the run's first image) and the batch of b and c
    assert reconstruct_cli(images, out, "--batch", "2") == 130
    stderr = capsys.readouterr().err
    assert error_lines(stderr) == [f"interrupted: 3 of 4 images done; {out / 'summary.csv'} lists them"]
    assert "Traceback" not in stderr
    assert [row["name"] for row in summary_rows(out)] == ["a", "b", "c"]
    assert all((out / f"{name}.json").exists() for name in "abc")
    assert not any(name.startswith(("d", ".")) for name in os.listdir(out))


def test_ctrl_c_lets_the_batch_in_progress_finish(tmp_path, fake, capsys):
    images = panoramas(tmp_path / "in", "a", "b", "c", "d")
    out = tmp_path / "out"
    fake.signal_on_call = 2  # Ctrl-C while the batch of b and c is computed (a, the run's first image, went alone)
    handler = signal.getsignal(signal.SIGINT)
    assert reconstruct_cli(images, out, "--batch", "2") == 130
    assert signal.getsignal(signal.SIGINT) is handler
    assert fake.calls == [1, 2]
    assert error_lines(capsys.readouterr().err) == [
        f"interrupted: 3 of 4 images done; {out / 'summary.csv'} lists them"
    ]
    assert [row["result"] for row in summary_rows(out)] == ["ok", "ok", "ok"]
    assert (out / "c.json").exists() and not (out / "d.json").exists()


def test_ctrl_c_elsewhere_is_one_line(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(demo, "run_demo", interrupted)
    assert cli.main(["demo"]) == 130
    assert capsys.readouterr().err == "ncjax demo: interrupted\n"


# ----------------------------------------------------------------------------- paths and files that do not work


def test_an_unwritable_output_folder_is_one_line_before_the_model_loads(tmp_path, fake, monkeypatch, capsys):
    def no_model(*args):
        raise AssertionError("the model was loaded")

    monkeypatch.setattr(ncjax.network.predict, "default_model", no_model)
    images = panoramas(tmp_path / "in", "room")
    (tmp_path / "file").write_text("a file")
    unwritable = [tmp_path / "file" / "sub"]  # under a regular file: no one can create it, root included
    if os.geteuid() != 0:  # chmod does not restrict root
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        unwritable.append(locked)
    for out in unwritable:
        assert reconstruct_cli(images, out) == 2
        error = capsys.readouterr().err
        assert len(error.strip().splitlines()) == 1 and f"--out {out} is not a folder ncjax can write in" in error
    assert fake.calls == []


@pytest.mark.parametrize("model", ["folder", "missing", "not a model"])
def test_a_model_that_does_not_load_is_one_line_and_creates_no_output_folder(tmp_path, fake, capsys, model):
    path = {"folder": tmp_path, "missing": tmp_path / "missing.safetensors", "not a model": tmp_path / "m.txt"}[model]
    (tmp_path / "m.txt").write_text("not a model")
    out = tmp_path / "new" / "out"
    assert reconstruct_cli(panoramas(tmp_path / "in", "room"), out, "--model", str(path)) == 2
    error = capsys.readouterr().err
    assert error.startswith(f"ncjax reconstruct: error: --model {path}")
    assert len(error.strip().splitlines()) == 1 and "os error" not in error
    if model == "folder":
        assert f"{path} is a folder, not a model file" in error
    assert not (tmp_path / "new").exists() and fake.calls == []


@pytest.mark.parametrize(
    "content", [pickle.dumps({"weights": np.zeros(3)}), bytes(range(256)) * 8, b""], ids=["pickle", "bytes", "empty"]
)
def test_a_file_that_is_not_a_model_is_one_line(tmp_path, fake, capsys, content):
    model = tmp_path / "model.safetensors"
    model.write_bytes(content)
    with pytest.raises(ValueError, match="is not an ncjax .safetensors model") as error:
        load_model(model)
    assert "\n" not in str(error.value)
    assert reconstruct_cli(panoramas(tmp_path / "in", "room"), tmp_path / "out", "--model", str(model)) == 2
    stderr = capsys.readouterr().err
    assert stderr.startswith(f"ncjax reconstruct: error: --model {model} is not an ncjax .safetensors model: ")
    assert len(stderr.strip().splitlines()) == 1 and fake.calls == []


def test_demo_into_a_file_is_one_line(tmp_path, capsys):
    target = tmp_path / "results.txt"
    target.write_text("mine")
    assert cli.main(["demo", "--out", str(target)]) == 2
    error = capsys.readouterr().err
    assert error == f"ncjax demo: error: --out {target} exists and is not a folder\n"
    assert target.read_text() == "mine"


def test_an_os_error_at_the_end_is_one_line(tmp_path, fake, monkeypatch, capsys):
    def refused(path, rows):
        raise PermissionError(13, "Permission denied", path)

    monkeypatch.setattr(reconstruct, "update_summary", refused)
    out = tmp_path / "out"
    assert reconstruct_cli(panoramas(tmp_path / "in", "room"), out) == 1
    assert error_lines(capsys.readouterr().err) == [
        f"ncjax reconstruct: error: {out / 'summary.csv'}: Permission denied"
    ]


# ----------------------------------------------------------------------------- summary.csv of several runs


def test_two_runs_into_one_folder_merge_their_summaries(tmp_path, fake):
    images = panoramas(tmp_path / "in", "a", "b", "c")
    out = tmp_path / "out"
    assert reconstruct_cli(images[:2], out) == 0
    fake.layout = failed_layout()
    assert reconstruct_cli(images[1:], out) == 1
    rows = summary_rows(out)
    assert [(row["name"], row["result"]) for row in rows] == [("a", "ok"), ("b", "no layout"), ("c", "no layout")]
    assert rows[0]["room_height_m"] == "2.5000"


def test_a_summary_csv_of_something_else_stops_the_run(tmp_path, fake, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.csv").write_text("date,amount\n2024-01-01,3\n")
    assert reconstruct_cli(panoramas(tmp_path / "in", "room"), out) == 2
    error = capsys.readouterr().err
    assert "is not a summary of ncjax reconstruct" in error and len(error.strip().splitlines()) == 1
    assert (out / "summary.csv").read_text() == "date,amount\n2024-01-01,3\n" and fake.calls == []


def test_merged_summaries_keep_untouched_rows_in_place():
    def row(name, result):
        return {"file": f"{name}.png", "name": name, "result": result}

    earlier = [row("a", "ok"), row("b", "error"), row("c", "ok")]
    merged = summary.merge_summary(earlier, [row("d", "ok"), row("b", "ok")])
    assert [(r["name"], r["result"]) for r in merged] == [("a", "ok"), ("b", "ok"), ("c", "ok"), ("d", "ok")]


# ----------------------------------------------------------------------------- the command line


def test_train_without_data_prints_its_help(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["train"]) == 2
    printed = capsys.readouterr()
    assert printed.out.startswith("usage: ncjax train") and "--data" in printed.out
    assert printed.err == "ncjax train: error: give --data (dataset folders, synth:SEED:N or painted)\n"
    assert os.listdir(tmp_path) == []


def test_one_flag_name_per_idea():
    from ncjax.network.predict import DEFAULT_VIEWS

    commands = subcommands()
    train = commands["train"]
    assert train.parse_args(["--data", "painted", "--batch", "8"]).batch_size == 8
    assert train.parse_args(["--data", "painted", "--batch-size", "8"]).batch_size == 8
    assert commands["evaluate"].parse_args([]).views == DEFAULT_VIEWS
    assert commands["reconstruct"].parse_args(["room.png", "--rc", "0", "--out", "o"]).views == DEFAULT_VIEWS


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    return next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction)).choices


def test_help_shows_every_default():
    for name, parser in subcommands().items():
        formatter = DefaultsHelpFormatter(name)
        for action in parser._actions:
            if not action.option_strings or action.nargs == 0 or action.required or action.help == argparse.SUPPRESS:
                continue  # flags, positionals, required options and hidden (renamed) ones have no default
            text = formatter._get_help_string(action)
            assert "default" in text or text.startswith("required"), (name, action.option_strings)
    reconstruct_help = " ".join(subcommands()["reconstruct"].format_help().split())
    assert (
        "--batch BATCH panoramas per call of the geometry's programs (a smaller last batch is padded: any number "
        "of images runs the same programs) (default: 1)"
    ) in reconstruct_help
    train_help = " ".join(subcommands()["train"].format_help().split())
    assert "--batch N, --batch-size N images per step (default: 4)" in train_help
    assert "--checkpoint-every CHECKPOINT_EVERY steps between checkpoints (default: 250)" in train_help


# ----------------------------------------------------------------------------- overlay legend


def test_the_overlay_names_its_colours():
    cam = ncjax.NonCentralPanorama(1024, 512, rc=0.6)
    image = np.full((512, 1024, 3), 90, np.uint8)
    layout = make_layout(RECTANGLE, inserted=(1,))
    rows = np.full(1024, 150.0), np.full(1024, 380.0), np.zeros(1024)
    drawn = overlay.draw_overlay(image, layout, cam, *rows)
    entries = overlay.legend_entries(layout, True, True)
    assert [label for label, _ in entries] == [
        "network boundaries",
        "layout",
        "inserted wall (unseen)",
        "corner probability (bottom)",
    ]
    top, bottom, left, right = overlay.legend_box([label for label, _ in entries], 512, 1024)
    assert top == 0 and right == 1024 and 40 < bottom < 100 and 700 < left < 900
    box = drawn[top:bottom, left:right].reshape(-1, 3).astype(int)
    for _, colour in entries:
        assert np.min(np.abs(box - colour).max(axis=1)) < 10, colour  # its swatch
    assert np.all(drawn[bottom + 2 : bottom + 8, left:] == 90)  # the box ends there
    assert overlay.legend_entries(failed_layout(), False, False) == []
    bare = overlay.draw_overlay(image, failed_layout(), cam)
    assert np.all(bare[:100, 700:] == 90)  # nothing drawn, no legend
