"""The dataset files (authors' layout plus ours), the reader, the split and ``ncjax synth``."""

import dataclasses
import filecmp
import json
import os
import shutil

import numpy as np
import pytest
from _synth import CLI_ARGS, HEIGHT, WIDTH

import ncjax
from ncjax import cli

N = 6


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("synth") / "data")
    assert cli.main(["synth", "--n", str(N), "--out", out, "--seed", "7"] + CLI_ARGS) == 0
    return out


@pytest.mark.extended
def test_written_files_are_mutually_consistent(dataset):
    names = ncjax.synth.list_samples(dataset)
    assert len(names) == N
    for name in names:
        with open(os.path.join(dataset, "json", f"{name}.json")) as file:
            meta = json.load(file)
        assert meta["rc"] == pytest.approx(ncjax.synth.rc_from_name(name), abs=1e-6)
        cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=meta["rc"])
        points = np.load(os.path.join(dataset, "3D_gt", f"{name}.npy"))
        pose = np.load(os.path.join(dataset, "cam_pose", f"{name}.npy"))
        label_cor = np.loadtxt(os.path.join(dataset, "label_cor", f"{name}.txt"), dtype=int, ndmin=2)
        assert pose.shape == (1, 3) and points.shape[1] == 3 and len(points) == len(label_cor)
        assert np.all(np.diff(label_cor[:, 0]) >= 0)  # sorted by x
        assert np.all(label_cor[0::2, 0] == label_cor[1::2, 0])  # ceiling/floor pairs share x
        n = len(points) // 2
        # label_cor alternates ceiling and floor; 3D_gt holds the N ceiling corners then the N floor ones.
        ordered = np.stack([points[:n], points[n:]], 1).reshape(-1, 3)
        local = ordered - pose
        # Both ncjax.geometry.project and the formulas of docs/design.md section 2 written out here.
        numpy_u = (np.pi - np.arctan2(local[:, 1], local[:, 0])) / (2 * np.pi) * WIDTH - 0.5
        numpy_v = (
            np.pi / 2 - np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1]) - meta["rc"])
        ) / np.pi * HEIGHT - 0.5
        for u, v in (ncjax.geometry.project(cam, local), (numpy_u, numpy_v)):
            du = np.abs(np.asarray(u) - label_cor[:, 0])
            du = np.minimum(du, WIDTH - du)
            assert np.all(du <= 1.0) and np.all(np.abs(np.asarray(v) - label_cor[:, 1]) <= 1.0)
        assert np.allclose(points[:n, 2], meta["room_height"], atol=1e-5) and np.allclose(points[n:, 2], 0.0, atol=1e-5)
        assert pose[0, 2] == pytest.approx(meta["camera_height"], abs=1e-6)
        assert meta["world"] in ("manhattan", "atlanta") and name.startswith(meta["world"])


@pytest.mark.slow
def test_reader_round_trip(dataset):
    for sample in ncjax.synth.read_dataset(dataset):
        assert sample.image.shape == (HEIGHT, WIDTH, 3) and sample.image.dtype == np.uint8
        assert sample.depth.shape == sample.semantic.shape == (HEIGHT, WIDTH)
        assert sample.ceiling_v.shape == sample.floor_v.shape == (WIDTH,)
        assert np.all(sample.ceiling_v < sample.floor_v)
        # The depth of the ceiling pixels right above the boundary is the distance to the wall-ceiling edge.
        assert np.all((sample.depth > 0.3) & (sample.depth < 40))
        assert sample.rc == sample.metadata["rc"]
        np.testing.assert_allclose(sample.ceiling_corners, np.asarray(sample.metadata["ceiling_corners"]), atol=1e-5)


@pytest.mark.slow
def test_reader_reads_the_authors_layout(dataset, tmp_path):
    """Without json/depth/semantic (the authors' release) rc comes from the file
    name and the boundaries are recomputed from 3D_gt; they match ours."""
    authors = tmp_path / "authors"
    for folder in ("img", "label_cor", "3D_gt", "cam_pose"):
        shutil.copytree(os.path.join(dataset, folder), authors / folder)
    names = ncjax.synth.list_samples(str(authors))
    assert names == ncjax.synth.list_samples(dataset)
    for name in names:
        ours, theirs = ncjax.synth.read_sample(dataset, name), ncjax.synth.read_sample(str(authors), name)
        assert theirs.metadata is None and theirs.depth is None and theirs.rc == pytest.approx(ours.rc, abs=1e-9)
        np.testing.assert_array_equal(theirs.image, ours.image)
        for mine, recomputed in ((ours.ceiling_v, theirs.ceiling_v), (ours.floor_v, theirs.floor_v)):
            assert np.mean(np.abs(mine - recomputed) < 1e-2) >= 0.99
    # A name without _R<rc> needs an explicit rc.
    renamed = authors / "img" / "room.png"
    os.rename(authors / "img" / f"{names[0]}.png", renamed)
    for folder, ext in (("label_cor", ".txt"), ("3D_gt", ".npy"), ("cam_pose", ".npy")):
        os.rename(authors / folder / f"{names[0]}{ext}", authors / folder / f"room{ext}")
    with pytest.raises(ValueError, match="rc"):
        ncjax.synth.read_sample(str(authors), "room")
    assert ncjax.synth.read_sample(str(authors), "room", rc=0.5).rc == 0.5


@pytest.mark.slow
def test_split_never_shares_a_layout(dataset):
    split = ncjax.synth.read_split(dataset)
    assert set(split) == {"train", "valid", "test"}
    everything = [name for names in split.values() for name in names]
    assert sorted(everything) == ncjax.synth.list_samples(dataset) and len(set(everything)) == len(everything)
    layouts = {}
    for part, names in split.items():
        for name in names:
            layout = tuple(np.round(np.load(os.path.join(dataset, "3D_gt", f"{name}.npy")), 3).ravel())
            assert layouts.setdefault(layout, part) == part


@pytest.mark.slow
def test_same_seed_same_bytes(dataset, tmp_path):
    again = str(tmp_path / "again")
    assert cli.main(["synth", "--n", str(N), "--out", again, "--seed", "7"] + CLI_ARGS) == 0
    for folder in ("img", "label_cor", "3D_gt", "cam_pose", "depth", "semantic", "json"):
        files = sorted(os.listdir(os.path.join(dataset, folder)))
        assert files == sorted(os.listdir(os.path.join(again, folder)))
        _, mismatch, errors = filecmp.cmpfiles(
            os.path.join(dataset, folder), os.path.join(again, folder), files, shallow=False
        )
        assert not mismatch and not errors
    assert filecmp.cmp(os.path.join(dataset, "split.json"), os.path.join(again, "split.json"), shallow=False)
    assert not any(name.startswith(".") for name in os.listdir(os.path.join(again, "img")))  # no temporary files left


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--n", "0"], "--n"),
        (["--size", "64x127"], "--size"),
        (["--size", "big"], "--size"),
        (["--rc", "1.0:0.5"], "--rc"),
        (["--rc=-1:0"], "--rc"),
        (["--supersampling", "2"], "odd"),
        (["--photoreal", "--spp", "0"], "--spp"),
        (["--kind", "synth-decor-attic"], "--kind must be one of synth, synth-decor,"),
        (["--kind", "synth-decor-hall", "--decor", "--rc", "0:0"], "leave out --rc, --decor"),
        (["--kind", "synth-decor-hall", "--spp", "4"], "--kind synth-decor-hall is ray-cast"),
    ],
)
def test_bad_arguments_give_clear_errors_and_write_nothing(tmp_path, capsys, arguments, message):
    out = tmp_path / "never"
    base = ["synth", "--n", "2", "--out", str(out)]
    assert cli.main(base + arguments) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_a_training_source_kind_writes_the_rooms_that_training_renders(tmp_path):
    from PIL import Image

    from ncjax.synth.dataset import rendered_samples, rendering_rgb8
    from ncjax.training.data import SYNTH_SOURCES

    out = tmp_path / "hall"
    arguments = ["--kind", "synth-decor-hall", "--size", f"{HEIGHT}x{WIDTH}", "--batch", "2"]
    assert cli.main(["synth", "--n", "2", "--out", str(out), "--seed", "3"] + arguments) == 0
    config = dataclasses.replace(SYNTH_SOURCES["synth-decor-hall"], height=HEIGHT, width=WIDTH)
    names = ncjax.synth.list_samples(str(out))
    for name, (_, scene, rendering, _) in zip(names, rendered_samples(2, 3, config, batch_size=2), strict=True):
        assert ncjax.synth.rc_from_name(name) == 0.0 and float(scene.room.rc) == 0.0
        written = np.asarray(Image.open(out / "img" / f"{name}.png"))
        np.testing.assert_array_equal(written, rendering_rgb8(rendering))


def test_non_empty_output_folder_is_refused(tmp_path, capsys):
    (tmp_path / "precious.txt").write_text("keep")
    assert cli.main(["synth", "--n", "1", "--out", str(tmp_path)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert os.listdir(tmp_path) == ["precious.txt"]


def test_unknown_world_is_an_argparse_error(tmp_path):
    with pytest.raises(SystemExit) as excinfo:
        cli.main(["synth", "--n", "1", "--out", str(tmp_path / "x"), "--world", "paris"])
    assert excinfo.value.code == 2


# ----------------------------------------------------------------------------- training data from a folder


@pytest.mark.slow
def test_folder_samples_at_the_network_size_keep_exact_labels(dataset):
    from ncjax.training.data import load_split

    for split, members in list_split_names(dataset).items():
        if not members:
            continue
        same = load_split(dataset, split, HEIGHT, WIDTH, progress=False)
        half = load_split(dataset, split, HEIGHT // 2, WIDTH // 2, progress=False)
        assert half["image"].shape == (len(members), HEIGHT // 2, WIDTH // 2, 3) and half["image"].dtype == np.uint8
        for index, name in enumerate(sorted(members)):
            sample = ncjax.synth.read_sample(dataset, name)
            # Same size: the renderer's own labels (json), computed from the true room.
            np.testing.assert_allclose(same["ceiling_v"][index], sample.ceiling_v, atol=2e-3)
            np.testing.assert_allclose(same["floor_v"][index], sample.floor_v, atol=2e-3)
            np.testing.assert_allclose(same["image"][index], sample.image)
            peaks = np.flatnonzero(same["corner_target"][index] == 1.0)
            assert set(peaks) <= set(np.round(sample.metadata["corner_u"]).astype(int))
            # Half size: the pixel-centre map of the rows, away from occlusion jumps.
            for key in ("ceiling_v", "floor_v"):
                pairs = sample.__getattribute__(key).reshape(-1, 2)
                smooth = np.abs(pairs[:, 1] - pairs[:, 0]) < 0.5
                expected = (pairs.mean(axis=1) + 0.5) / 2 - 0.5
                # Averaging two columns across a corner's kink differs from the centre value by < 0.2 px.
                np.testing.assert_allclose(half[key][index][smooth], expected[smooth], atol=0.2)
                assert np.mean(np.abs(half[key][index][smooth] - expected[smooth])) < 0.01


def list_split_names(directory):
    with open(os.path.join(directory, "split.json")) as file:
        return json.load(file)


@pytest.mark.slow
def test_folder_batches_are_reproducible_and_resumable(dataset):
    from ncjax.training.data import folder_batches, load_split

    arrays = load_split(dataset, "train", HEIGHT, WIDTH, progress=False)
    batches = folder_batches(arrays, 2, seed=3)
    from_start, resumed = batches(0), batches(2)
    first_three = [next(from_start) for _ in range(3)]
    np.testing.assert_array_equal(first_three[2]["image"], next(resumed)["image"])
    assert first_three[0]["image"].dtype == np.float32 and first_three[0]["image"].max() <= 1.0
    with pytest.raises(ValueError, match="exceeds"):
        folder_batches(arrays, len(arrays["image"]) + 1, seed=0)
    with pytest.raises(ValueError, match="split"):
        load_split(dataset, "holdout", HEIGHT, WIDTH, progress=False)


@pytest.mark.slow
def test_folders_are_pooled_in_order(dataset):
    from ncjax.training.data import load_split, training_data

    one = load_split(dataset, "train", HEIGHT, WIDTH, progress=False)
    one_valid = load_split(dataset, "valid", HEIGHT, WIDTH, progress=False)
    count, valid_count = len(one["image"]), len(one_valid["image"])
    pooled, limited = training_data([dataset, dataset], HEIGHT, WIDTH, validation_limit=valid_count + 1)
    assert pooled["image"].shape[0] == 2 * count
    np.testing.assert_array_equal(pooled["ceiling_v"][count:], one["ceiling_v"])
    assert limited["image"].shape[0] == valid_count + 1
    np.testing.assert_array_equal(limited["ceiling_v"][valid_count:], one_valid["ceiling_v"][:1])
    _, everything = training_data([dataset, dataset], HEIGHT, WIDTH, validation_limit=None)
    assert everything["image"].shape[0] == 2 * valid_count


@pytest.mark.slow
def test_evaluate_command_prints_the_network_table(dataset, tmp_path, capsys):
    config = ncjax.HorizonNetConfig(depth=10, width=8, input_height=32, input_width=64, lstm_hidden=8, lstm_layers=1)
    path = str(tmp_path / "tiny.safetensors")
    ncjax.save_model(ncjax.network.init_model(config, seed=0), path)
    out = str(tmp_path / "row.json")
    assert cli.main(["evaluate", "--data", dataset, "--split", "train", "--model", path, "--json", out]) == 0
    printed = capsys.readouterr().out
    assert "PE" in printed and "precision" in printed
    with open(out) as file:
        row = json.load(file)
    assert row["images"] == len(list_split_names(dataset)["train"]) and np.isfinite(row["pe_mean"])
    assert cli.main(["evaluate", "--data", str(tmp_path / "missing"), "--model", path]) == 2


@pytest.mark.slow
def test_rendered_splits_equal_the_written_and_read_dataset(dataset):
    from _synth import BATCH, CONFIG

    from ncjax.training.data import load_split, rendered_splits

    # At half size, so that both routes shrink the image the same way too.
    height, width = HEIGHT // 2, WIDTH // 2
    rendered = rendered_splits(7, N, height, width, batch_size=BATCH, config=CONFIG, progress=False)
    assert sum(len(arrays["image"]) for arrays in rendered.values()) == N
    for split, arrays in rendered.items():
        read = load_split(dataset, split, height, width, progress=False)

        # The folder lists samples by name, the renderer by index: match them by their pixels.
        def order(a):
            return np.argsort([image.tobytes() for image in a["image"]])

        for key in read:
            np.testing.assert_allclose(arrays[key][order(arrays)], read[key][order(read)], atol=1e-4)


@pytest.mark.slow
def test_rendered_splits_through_a_render_cache_equal_those_rendered_in_memory(tmp_path, monkeypatch):
    from _synth import BATCH, CONFIG

    from ncjax.training import data

    monkeypatch.setattr(data, "RENDER_CHUNK", 4)  # files of rooms 0-3 and 4-5
    height, width = HEIGHT // 2, WIDTH // 2
    in_memory = data.rendered_splits(7, N, height, width, batch_size=BATCH, config=CONFIG, progress=False)
    cached = data.rendered_splits(7, N, height, width, BATCH, CONFIG, progress=False, cache=tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["000000-000004.npz", "000004-000006.npz"]
    for split, arrays in in_memory.items():
        for key, value in arrays.items():
            np.testing.assert_array_equal(cached[split][key], value)


@pytest.mark.parametrize(
    "source, expected",
    [
        ("synth:11:3200", (11, 3200)),
        ("synth:-3:1", (-3, 1)),
        ("synth-decor-central:5:7", (5, 7)),
        ("synth-decor-small:8:9", (8, 9)),
        ("synth-decor-home:4:2", (4, 2)),
        ("synth-decor-open:6:3", (6, 3)),
        ("data/synth1024", None),
        ("painted", None),
    ],
)
def test_parse_synth_source(source, expected):
    from ncjax.training.data import parse_synth_source

    assert parse_synth_source(source) == expected


@pytest.mark.parametrize("source", ["synth:11", "synth:a:3", "synth:1:0", "synth:1:2:3", "synth:1:2.5"])
def test_parse_synth_source_refuses_malformed_sources(source):
    from ncjax.training.data import parse_synth_source

    with pytest.raises(ValueError, match="synth:SEED:N"):
        parse_synth_source(source)


def _counted_rooms(monkeypatch):
    """Stand-in rooms for :func:`~ncjax.training.data.rendered_splits` (each room's image holds its index, every
    third one in the valid split); the list of the ``(first, last)`` ranges rendered."""
    from ncjax.training import data

    rendered = []

    def rooms(seed, first, last, height, width, batch_size, config, bar):
        rendered.append((first, last))
        bar.update(last - first)
        indices = np.arange(first, last)
        return {
            "image": np.broadcast_to(indices[:, None, None, None], (last - first, 2, 4, 3)).astype(np.uint8),
            "split": (indices % 3 == 2).astype(np.int8),
        }

    monkeypatch.setattr(data, "_rendered_arrays", rooms)
    monkeypatch.setattr(data, "RENDER_CHUNK", 4)
    return rendered


def test_a_render_cache_is_read_back_and_a_spent_budget_keeps_what_was_rendered(tmp_path, monkeypatch):
    import time

    from ncjax.training.data import RenderingStopped, rendered_splits

    rendered = _counted_rooms(monkeypatch)
    first = rendered_splits(0, 10, 2, 4, progress=False, cache=tmp_path)
    assert rendered == [(0, 4), (4, 8), (8, 10)]
    assert first["train"]["image"][:, 0, 0, 0].tolist() == [0, 1, 3, 4, 6, 7, 9]
    assert first["valid"]["image"][:, 0, 0, 0].tolist() == [2, 5, 8]
    again = rendered_splits(0, 10, 2, 4, progress=False, cache=tmp_path, deadline=time.monotonic() - 1)
    assert rendered == [(0, 4), (4, 8), (8, 10)]  # read back, nothing rendered, the spent budget no matter
    for split in first:
        np.testing.assert_array_equal(again[split]["image"], first[split]["image"])
    # A budget spent with rooms left: the files kept, the run told to go on; nothing half-written.
    (tmp_path / "000004-000008.npz").unlink()
    with pytest.raises(RenderingStopped, match="rendered 4 of 10 rooms"):
        rendered_splits(0, 10, 2, 4, progress=False, cache=tmp_path, deadline=time.monotonic() - 1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["000000-000004.npz", "000008-000010.npz"]
    rendered_splits(0, 10, 2, 4, progress=False, cache=tmp_path)
    assert rendered[-1] == (4, 8) and len(rendered) == 4


def test_train_stops_with_a_message_when_its_budget_runs_out_while_rendering(tmp_path, monkeypatch, capsys):
    _counted_rooms(monkeypatch)
    cache, checkpoints = tmp_path / "rendered", tmp_path / "checkpoints"
    arguments = ["train", "--data", "synth:3:10", "--render-cache", str(cache), "--checkpoint-dir", str(checkpoints)]
    assert cli.main(arguments + ["--time-budget", "1e-9"]) == 0
    assert "stopped before training: rendered 0 of 10 rooms" in capsys.readouterr().out
    assert not checkpoints.exists() and not any(cache.rglob("*.npz"))


def test_rendering_in_proportion_stops_with_every_source_at_about_the_same_share(tmp_path, monkeypatch):
    from ncjax.training import data

    rendered = _counted_rooms(monkeypatch)  # files of 4 rooms
    clock = [0.0]
    counted = data._rendered_arrays

    def one_second_a_file(*args):
        clock[0] += 1
        return counted(*args)

    monkeypatch.setattr(data, "_rendered_arrays", one_second_a_file)
    monkeypatch.setattr(data.time, "monotonic", lambda: clock[0])
    sources = ["synth:0:16", "synth-decor:1:8"]
    # The source furthest behind goes next (the first on ties): 16-room's file 1, 8-room's 1, 16-room's 2.
    assert data.render_in_proportion(sources, 2, 4, tmp_path, deadline=3, progress=False) == {
        "synth:0:16": 8,
        "synth-decor:1:8": 4,
    }
    assert rendered == [(0, 4), (0, 4), (4, 8)]
    # A rerun reads the files back and renders on; with nothing left, nothing is rendered.
    assert data.render_in_proportion(sources, 2, 4, tmp_path, deadline=100, progress=False) == {
        "synth:0:16": 16,
        "synth-decor:1:8": 8,
    }
    assert rendered[3:] == [(8, 12), (4, 8), (12, 16)]  # 16-room source, 8-room, 16-room
    assert data.render_in_proportion(sources, 2, 4, tmp_path, deadline=-1, progress=False)["synth:0:16"] == 16
    assert len(rendered) == 6
    with pytest.raises(ValueError, match="not a rendered source"):
        data.render_in_proportion(["synth:0:16", "some/folder"], 2, 4, tmp_path, deadline=100)


def test_training_data_takes_the_rooms_rendered_in_proportion(tmp_path, monkeypatch):
    from ncjax.training.data import RenderingStopped, render_in_proportion, training_data

    _counted_rooms(monkeypatch)  # every third room in the valid split
    sources = ["synth:0:16", "synth-decor:1:8"]
    counts = render_in_proportion(sources, 2, 4, tmp_path, deadline=float("inf"), progress=False)
    train, valid = training_data(sources, 2, 4, None, tmp_path, rendered_rooms={"synth:0:16": 4, "synth-decor:1:8": 0})
    assert train["image"][:, 0, 0, 0].tolist() == [0, 1, 3] and valid["image"][:, 0, 0, 0].tolist() == [2]
    train, valid = training_data(sources, 2, 4, None, tmp_path, rendered_rooms=counts)
    assert len(train["image"]) + len(valid["image"]) == 24
    # A source cut short before its first valid room trains on its rooms; no valid room at all stops the command.
    train, valid = training_data(sources, 2, 4, None, tmp_path, rendered_rooms={"synth:0:16": 4, "synth-decor:1:8": 2})
    assert train["image"][:, 0, 0, 0].tolist() == [0, 1, 3, 0, 1] and len(valid["image"]) == 1
    with pytest.raises(RenderingStopped, match="no valid rooms"):
        training_data(["synth:0:16"], 2, 4, None, tmp_path, rendered_rooms={"synth:0:16": 2})


def test_train_refuses_a_render_budget_without_a_cache(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["train", "--data", "synth:3:10", "--render-budget", "60"]) == 2
    assert "--render-budget must be positive and comes with --render-cache" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def test_train_refuses_a_batch_that_does_not_split_into_its_micro_batches(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["train", "--data", "synth:3:10", "--batch", "6", "--micro-batches", "4"]) == 2
    assert "--batch 6 does not split into --micro-batches 4" in capsys.readouterr().err
    assert cli.main(["train", "--data", "synth:3:10", "--micro-batches", "0"]) == 2
    assert "--micro-batches must be >= 1, got 0" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def test_train_stops_with_a_message_when_its_render_budget_leaves_no_rooms(tmp_path, monkeypatch, capsys):
    _counted_rooms(monkeypatch)
    cache, checkpoints = tmp_path / "rendered", tmp_path / "checkpoints"
    arguments = ["train", "--data", "synth:3:10", "--render-cache", str(cache), "--checkpoint-dir", str(checkpoints)]
    assert cli.main(arguments + ["--render-budget", "1e-9"]) == 0
    printed = capsys.readouterr().out
    assert "render budget spent: training on 0 of 10 rooms of synth:3:10" in printed
    assert "stopped before training: no train rooms" in printed
    assert not checkpoints.exists() and not any(cache.rglob("*.npz"))


def test_render_cache_folders_are_named_by_source_size_and_configuration(tmp_path):
    from ncjax.training.data import render_cache_folder

    home = render_cache_folder(tmp_path, "synth-decor-home:5:100", 512, 1024)
    assert home == render_cache_folder(tmp_path, "synth-decor-home:5:900", 512, 1024)  # N does not matter
    assert home.name.startswith("synth-decor-home_5_512x1024_")
    others = [
        render_cache_folder(tmp_path, "synth-decor-home:6:100", 512, 1024),
        render_cache_folder(tmp_path, "synth-decor-home:5:100", 256, 512),
        render_cache_folder(tmp_path, "synth-photoreal-home:5:100", 512, 1024),
    ]
    assert home not in others and len(set(others)) == 3


def test_training_data_refuses_a_malformed_source_before_reading_the_others(tmp_path):
    from ncjax.training.data import training_data

    with pytest.raises(ValueError, match="synth:SEED:N"):
        training_data([str(tmp_path / "not_a_dataset"), "synth:1:x"], HEIGHT, WIDTH, 4)
