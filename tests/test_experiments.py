"""The noise sweep runs end to end in its small version and writes its outputs."""

import dataclasses
import pathlib
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _scripts import script_module

import ncjax
from ncjax.network import HorizonNetConfig


def experiment(name: str):
    """The module of ``experiments/<name>.py``."""
    return script_module("experiments", name)


@pytest.mark.extended
def test_noise_sweep_small(tmp_path):
    module = experiment("noise_sweep")
    results, rc_results, ablation = module.main(["--small", "--out", str(tmp_path)])
    for name in ("noise_sweep.csv", "noise_sweep.png", "rc_sweep.csv", "rc_sweep.png"):
        assert (tmp_path / name).stat().st_size > 0
    for name in ("manhattan", "atlanta"):
        assert np.nanmax(results[name]["depth"][0]) < 1e-3  # sigma = 0: exact
    # the baseline too, but lines seen by few columns are ill-conditioned in float32 (see RESULTS.md)
    assert np.nanmedian(results["baseline"]["depth"][0]) < 1e-3
    # the paper's finding: the proposed solvers beat the baseline in depth at every sigma > 0
    # (medians: at 256 px, 2 px of noise is 2.8 degrees and the Manhattan fit has rare outliers)
    for i in range(1, len(results["baseline"]["depth"])):
        for name in ("manhattan", "atlanta"):
            assert np.nanmedian(results[name]["depth"][i]) < np.nanmedian(results["baseline"]["depth"][i])
    # the refined (maximum-likelihood) layout beats the paper's constrained and the unconstrained null vector
    for other in ("paper", "null_vector"):
        assert ablation["manhattan/refined"]["corner"] < ablation[f"manhattan/{other}"]["corner"]


@pytest.mark.extended
def test_pipeline_table_small(tmp_path):
    module = experiment("pipeline_table")
    rows = module.main(["--small", "--out", str(tmp_path)])
    assert (tmp_path / "pipeline_table_small.md").stat().st_size > 0
    exact = rows[0]
    assert exact[-1] < 50.0 and exact[5] < 0.01  # failure rate (%), CE (m) on exact boundaries


@pytest.mark.slow
def test_the_papers_solvers_route_recovers_a_box_room_from_its_exact_rows():
    """The tables' "Solvers" route (walls split at the corner peaks, each fitted alone, then the layout solver) on
    the exact rows and corner target of a four-wall Manhattan room gives its four corners."""
    common = script_module("experiments", "common")
    config = ncjax.RoomConfig(world="manhattan", occlusion="none", rc_range=(0.5, 0.5), min_walls=4, max_walls=4)
    room = ncjax.synth.random_room(jax.random.key(3), config)
    cam = room.camera(common.WIDTH, common.HEIGHT)
    label = ncjax.synth.room_labels(room, cam)
    layout = jax.jit(common.solvers_only, static_argnums=4)(
        label.ceiling_v, label.floor_v, label.corner_target, cam, "manhattan"
    )
    assert bool(layout["ok"]) and int(jnp.sum(layout["mask"])) == 4
    found = np.asarray(layout["floor_corners"])[np.asarray(layout["mask"])][:, :2]
    truth = np.asarray(label.floor_corners)[np.asarray(label.corner_mask)][:, :2]
    distance = np.linalg.norm(found[:, None] - truth[None], axis=-1)
    assert distance.min(1).max() < 1e-2, distance


def test_calibrate_uncertainty_reads_the_shipped_setting_back_into_the_shipped_config():
    module = experiment("calibrate_uncertainty")
    from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

    assert module.with_setting(module.shipped_setting(), scale_test=True) == NETWORK_PIPELINE_CONFIG
    assert module.with_setting((0.0, 0.0, 0.0), scale_test=False) != NETWORK_PIPELINE_CONFIG


def test_network_table_bins_rooms_by_their_narrowest_wall():
    module = experiment("network_table")

    def room(width, corners):
        return SimpleNamespace(image=np.zeros((width // 2, width, 3)), metadata={"corner_u": corners})

    assert module.narrowest_wall(room(1024, [1000.0, 10.0, 500.0])) == 34.0  # the wall across the seam
    assert module.narrowest_wall(room(512, [5.0, 10.0, 300.0])) == 10.0  # columns of a 1024-wide panorama
    per_room = [
        {
            "returned": not failed,
            "written": not failed,
            "failed": failed,
            "ce": 0.1,
            "ce_median": 0.1,
            "cen": 0.01,
            "iou3d": 0.9,
            "iou3d_up_to_scale": 0.9,
            "height_error": 0.0,
        }
        for failed in (True, False, False)
    ]
    bins = module.by_narrowest_wall(per_room, np.array([4.0, 20.0, 40.0]))
    assert [b["rooms"] for b in bins] == [1, 1, 1] and bins[0]["failed"] == 100.0 and bins[2]["failed"] == 0.0
    assert bins[2]["high"] is None


def test_render_scores_summarise_every_returned_layout_also_with_another_corner_count():
    module = experiment("common")
    scored = {"ce": 0.1, "cen": 0.01, "iou3d_up_to_scale": 0.9, "height_error": 0.0}
    per_room = [
        {"returned": True, "written": True, "failed": False, **scored, "iou3d": 0.9},  # the true corner count
        {
            "returned": True,
            "written": True,
            "failed": True,
            **scored,
            "ce": float("nan"),
            "iou3d": 0.7,
        },  # a merged corner: no CE
        {"returned": False, "written": False, "failed": True},  # no layout
        {"returned": False, "written": True, "failed": True, **scored, "iou3d": 0.4},  # flagged UNCERTAIN_SCALE
    ]
    s = module.scores_summary(per_room)
    assert s["failed"] == pytest.approx(75.0) and s["iou3d"] == pytest.approx(90.0)
    assert s["iou3d_all"] == pytest.approx(22.5)  # only the room with the true corner count scores
    assert s["returned"] == pytest.approx(50.0)
    assert s["iou3d_returned"] == pytest.approx(80.0) and s["iou3d_returned_median"] == pytest.approx(80.0)
    assert s["iou3d_all_returned"] == pytest.approx(40.0)
    assert s["flagged"] == pytest.approx(25.0) and s["iou3d_flagged"] == pytest.approx(40.0)
    assert s["iou3d_all_written"] == pytest.approx(50.0)


def test_render_scores_score_the_geometry_of_uncertain_scale_layouts_but_count_them_failed():
    module = experiment("common")
    square = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])
    truth = {
        "ceiling_corners": np.hstack([square, np.full((4, 1), 1.0)]),
        "floor_corners": np.hstack([square, np.full((4, 1), -1.5)]),
    }

    def layout(ok, status):
        return {**truth, "ok": ok, "status": status, "mask": np.ones(4, bool)}

    ok, flagged, failed = module.layout_scores(
        [
            layout(True, 0),
            layout(False, int(ncjax.LayoutStatus.UNCERTAIN_SCALE)),
            layout(False, int(ncjax.LayoutStatus.DEGENERATE_LAYOUT)),
        ],
        [truth] * 3,
    )
    assert ok["returned"] and ok["written"] and not ok["failed"] and ok["iou3d"] == pytest.approx(1.0)
    assert (
        not flagged["returned"] and flagged["written"] and flagged["failed"] and flagged["iou3d"] == pytest.approx(1.0)
    )
    assert not failed["written"] and failed["failed"] and "iou3d" not in failed


@pytest.mark.slow
def test_robustness_degradations_keep_the_image_format():
    module = experiment("robustness")
    image = np.random.default_rng(0).integers(0, 256, (16, 32, 3), dtype=np.uint8)
    for name, (operation, _) in module.DEGRADATIONS.items():
        degraded = operation(image)
        assert degraded.shape == image.shape and degraded.dtype == np.uint8, name
        assert np.array_equal(degraded, image) == (name == "none"), name
    grey = module.DEGRADATIONS["greyscale"][0](image)
    assert np.array_equal(grey[..., 0], grey[..., 2])


def test_resolution_shrinks_by_pixel_area_averaging():
    module = experiment("resolution")
    image = np.random.default_rng(0).integers(0, 256, (8, 16, 3), dtype=np.uint8)
    half = module.shrunk(image, 8)
    blocks = image.reshape(4, 2, 8, 2, 3).astype(float).mean(axis=(1, 3))
    assert half.shape == (4, 8, 3) and half.dtype == np.uint8
    assert np.abs(half.astype(float) - blocks).max() <= 0.5
    assert module.shrunk(image, 16) is image


def test_tuning_row_errors_compare_each_boundary_with_its_true_rows():
    module = experiment("tune_network_pipeline")
    true_rows = np.stack([np.full((2, 4), 100.0), np.full((2, 4), 400.0)])
    data = {
        "ceiling_v": true_rows[0] + [[0.0, 0.0, 0.5, 0.5], [0.0, 0.0, 0.0, -0.5]],
        "floor_v": true_rows[1] + [[0.0, 4.0, -8.0, 0.5], [0.0, 0.0, -2.0, 1.5]],
        "true_rows": true_rows,
    }
    # ceiling |errors| 0 x 5, 0.5 x 3; floor 0 x 3, 0.5, 1.5, 2, 4, 8
    assert module.row_errors(data) == (
        "ceiling 0.19 / 0.00 px, 100% within 1 px; floor 2.00 / 1.00 px, 50% within 1 px"
    )


def test_tuning_refuses_a_missing_model_before_any_work(tmp_path):
    module = experiment("tune_network_pipeline")
    with pytest.raises(SystemExit) as raised:
        module.main(["--model", str(tmp_path / "missing.safetensors"), "--out", str(tmp_path / "out")])
    assert raised.value.code == 2 and not (tmp_path / "out").exists()


def test_tuning_caches_are_named_by_the_model_file_and_its_content(tmp_path):
    module = experiment("common")
    model = tmp_path / "mine.safetensors"
    model.write_bytes(b"weights of one run")
    first = module.model_suffix(model)
    model.write_bytes(b"weights of another run")
    assert first.startswith("_mine_") and module.model_suffix(model) != first
    # the shipped model too: its rows cached before new weights replaced it are not reused
    assert module.model_suffix(None).startswith(f"_{module.DEFAULT_MODEL_PATH.stem}_")


def test_central_renders_refuses_a_missing_model_or_setting_before_any_work(tmp_path, monkeypatch):
    module = experiment("central_renders")

    def render(*args):
        raise AssertionError("rendered before checking its options")

    monkeypatch.setattr(module, "photo_like_rows", render)
    for options in (["--model", str(tmp_path / "missing.safetensors")], ["--settings", "auto,sideways"]):
        with pytest.raises(SystemExit) as raised:
            module.main(options)
        assert raised.value.code == 2


def test_settings_by_their_flat_names_land_in_their_stages():
    common = experiment("common")
    config = common.network_config(corner_threshold=0.35, manhattan_margin=0.15, capacity=24)
    assert config.corners.threshold == 0.35 and config.branches.manhattan_margin == 0.15 and config.capacity == 24
    assert common.network_setting("corner_threshold") == common.NETWORK_PIPELINE_CONFIG.corners.threshold
    # every setting the experiments compare is one the pipeline has
    tuning, central = experiment("tune_network_pipeline"), experiment("central_renders")
    for settings in [*tuning.CONFIGS.values(), *tuning.MARGIN_CONFIGS.values()]:
        common.network_config(**settings)
    for _, settings in central.SETTINGS.values():
        common.network_config(**settings)


@pytest.mark.slow
def test_central_renders_scores_exact_rows_as_the_true_room():
    """Exact rows of central rooms (what the cache holds for a perfect network): the default setting returns the true
    room, and the raw polygon of exact rows is the room up to its per-column sampling."""
    import jax

    module = experiment("central_renders")
    width = 256
    config = ncjax.RoomConfig(world="manhattan", occlusion="none", rc_range=(0.0, 0.0), max_walls=6)
    rooms = jax.vmap(lambda k: ncjax.synth.random_room(k, config))(jax.random.split(jax.random.key(5), 3))
    labels = jax.vmap(lambda room: ncjax.synth.room_labels(room, ncjax.NonCentralPanorama(width, width // 2, rc=0.0)))(
        rooms
    )
    data = {
        "ceiling_v": np.asarray(labels.ceiling_v),
        "floor_v": np.asarray(labels.floor_v),
        "corner_prob": np.asarray(labels.corner_target),
        "ceiling_corners": np.asarray(labels.ceiling_corners),
        "floor_corners": np.asarray(labels.floor_corners),
        "corner_count": np.asarray(labels.corner_mask).sum(1),
    }
    scores = module.setting_scores(data, *module.SETTINGS["auto"])
    assert scores["returned"].all()
    np.testing.assert_allclose(scores["iou"], 1.0, atol=1e-3)
    np.testing.assert_allclose(scores["ce"], 0.0, atol=2e-3)
    assert np.all(module.raw_ious(data) > 0.9)
    line = module.table_line("auto", scores, module.raw_ious(data))
    assert line.startswith("| auto | 100.0% | 100.0% / 100.0% |") and line.endswith("| 3 of 3 |")


def test_corners_or_rows_scores_a_layout_against_its_label_and_no_layout_as_zero(tmp_path):
    from test_export import L_SHAPE, make_layout

    from ncjax.io.formats import format_path, write_layout_formats
    from ncjax.io.formats_read import read_layout

    module = experiment("corners_or_rows")
    cam = ncjax.NonCentralPanorama(1024, 512, rc=0.0)
    layout = make_layout(L_SHAPE)
    write_layout_formats(tmp_path / "label", layout, cam, "label_cor")
    label = read_layout(format_path(tmp_path / "label", "label_cor"), 1024, 512)
    assert module.layout_iou(layout, cam, label, tmp_path) == pytest.approx(1.0, abs=1e-3)
    failed = make_layout(L_SHAPE, status=int(ncjax.LayoutStatus.SOLVER_FAILED))
    assert module.layout_iou(failed, cam, label, tmp_path) == 0.0
    stretched = make_layout([(1.3 * x, y) for x, y in L_SHAPE])
    assert 0.5 < module.layout_iou(stretched, cam, label, tmp_path) < 0.95


def test_frozen_backbone_rolls_each_map_by_its_stride_and_the_labels_alike():
    module = experiment("frozen_backbone")
    width = module.WIDTH
    maps = [
        jnp.broadcast_to(
            jnp.arange(width // stride, dtype=jnp.float32)[None, None, :, None], (1, 2, width // stride, 3)
        )
        for stride in module.FEATURE_STRIDES
    ]
    labels = [jnp.arange(width, dtype=jnp.float32)[None]]
    rolled_maps, rolled_labels = module._rolled(maps, labels, jnp.asarray(3))
    for rolled, stride in zip(rolled_maps, module.FEATURE_STRIDES, strict=True):
        columns = width // stride
        expected = (np.arange(columns) - 3 * 32 // stride) % columns
        np.testing.assert_array_equal(rolled[0, 0, :, 0], expected)
    np.testing.assert_array_equal(rolled_labels[0][0], (np.arange(width) - 96) % width)


def test_frozen_backbone_refuses_a_source_it_cannot_render_before_any_work(tmp_path, capsys):
    module = experiment("frozen_backbone")
    assert module.main(["--data", str(tmp_path), "--export", str(tmp_path / "m.safetensors")]) == 2
    assert "not a rendered source" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "option, setting, message",
    [
        ("--room", "colour_range=1:2", "not a range of RoomConfig"),
        ("--room", "size_range=big", "expected size_range=LOW:HIGH"),
        ("--room", "camera_height_range=1:2.5", "the camera must stay below the ceiling"),
        ("--scene", "furniture_slots=0", "not a probability of SceneConfig"),
        ("--scene", "furniture_probability=none", "expected furniture_probability=P"),
        ("--scene", "furniture_probability=1.5", "a probability is in [0, 1]"),
    ],
)
def test_frozen_backbone_refuses_a_room_or_scene_setting_before_any_work(tmp_path, capsys, option, setting, message):
    module = experiment("frozen_backbone")
    export = str(tmp_path / "m.safetensors")
    assert module.main(["--data", "synth-decor-home:1:2", option, setting, "--export", export]) == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_frozen_backbone_scene_settings_reach_the_rooms():
    common = experiment("common")
    home = common.SYNTH_SOURCES["synth-decor-home"]
    empty = common.source_config("synth-decor-home", {}, common.scene_probabilities(["furniture_probability=0"]))
    assert empty.scene.furniture_probability == 0.0 and home.scene.furniture_probability > 0.0
    assert empty.scene.neutral_paint_probability == home.scene.neutral_paint_probability
    assert empty.room == home.room


def test_frozen_backbone_statistics_noise_moves_each_image_by_the_batchs_spread():
    module = experiment("frozen_backbone")
    rng = np.random.default_rng(0)
    one = rng.normal(size=(1, 4, 8, 3)).astype(np.float32)
    alike = [jnp.asarray(np.repeat(one, 4, axis=0))]  # no spread over the batch: nothing to move by
    np.testing.assert_allclose(module.perturbed_statistics(jax.random.key(0), alike, 1.0)[0], alike[0], atol=1e-5)
    varied = [jnp.asarray(rng.normal(size=(4, 4, 8, 3)) * [[[[1.0]]], [[[2.0]]], [[[0.5]]], [[[3.0]]]] + 1.0)]
    np.testing.assert_array_equal(module.perturbed_statistics(jax.random.key(0), varied, 0.0)[0], varied[0])
    moved = np.asarray(module.perturbed_statistics(jax.random.key(0), varied, 1.0)[0])
    assert not np.allclose(moved.mean(axis=(1, 2)), np.asarray(varied[0]).mean(axis=(1, 2)))
    # within each image and channel only the mean and the scale change: the pattern stays
    for image in range(4):
        for channel in range(3):
            before, after = np.asarray(varied[0])[image, ..., channel].ravel(), moved[image, ..., channel].ravel()
            assert abs(np.corrcoef(before, after)[0, 1]) == pytest.approx(1.0, abs=1e-5)


def test_capture_geometry_reads_a_rooms_proportions_in_camera_heights():
    module = experiment("capture_geometry")
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    ceiling, distance, size = module.proportions(square, 0.6)
    assert ceiling == 0.6 and size == pytest.approx(2.0)
    assert 1.0 < distance < np.sqrt(2.0)  # between a wall's foot and a corner
    fixed = {"camera_height_range": (1.5, 1.5), "height_range": (2.5, 2.5)}
    rooms = module.render_proportions("synth-decor-home", 8, fixed)
    np.testing.assert_allclose(rooms[:, 0], 1.0 / 1.5, rtol=1e-5)  # 1 m of ceiling above a 1.5 m camera


def test_boundary_fusion_reads_one_distance_off_both_exact_rows_and_keeps_the_straighter_boundary():
    from ncjax.evaluation.panorama_labels import boundary_rows, central_camera, wall_distances
    from ncjax.geometry.camera import angles_to_pixel

    module = experiment("boundary_fusion")
    width = 1024
    cam = central_camera(width, width // 2)
    plan = np.array([[-1.5, -1.2], [2.0, -1.2], [2.0, 1.8], [-1.5, 1.8]])  # camera height 1
    ceiling_height = 0.65
    azimuth, _ = module.pixel_angles(cam, np.arange(width), np.zeros(width))
    true_distance = wall_distances(plan, azimuth)
    ceiling_v, floor_v = boundary_rows(true_distance, ceiling_height, cam)
    from_floor, from_ceiling, ratio = module.row_distances(cam, ceiling_v, floor_v)
    assert ratio == pytest.approx(ceiling_height, rel=1e-6)
    np.testing.assert_allclose(from_floor, true_distance, rtol=1e-6)
    np.testing.assert_allclose(from_ceiling, true_distance, rtol=1e-6)
    # a doorway: over 40 columns the floor row follows the next room's floor, 1 m beyond the wall
    doorway = slice(500, 540)
    through = true_distance.copy()
    through[doorway] += 1.0
    _, floor_through = boundary_rows(through, ceiling_height, cam)
    from_floor, from_ceiling, _ = module.row_distances(cam, ceiling_v, floor_through, ratio)
    assert not np.allclose(from_floor[doorway], true_distance[doorway])
    corner_columns, _ = angles_to_pixel(cam, np.arctan2(plan[:, 1], plan[:, 0]), np.zeros(len(plan)))
    chosen = module.straighter(cam, from_floor, from_ceiling, np.asarray(corner_columns), 0.03)
    np.testing.assert_allclose(chosen, true_distance, rtol=1e-4)


def test_see_through_classifier_is_circular_and_takes_the_ceiling_only_where_told():
    from flax import nnx

    from ncjax.evaluation.panorama_labels import boundary_rows, central_camera, pixel_angles, wall_distances

    module = experiment("see_through")
    classifier = module.ColumnClassifier(6, 4, nnx.Rngs(0), hidden=8)
    features = jnp.asarray(np.random.default_rng(0).normal(size=(2, 32, 6)), jnp.float32)
    logits = classifier(features)
    assert logits.shape == (2, 128)
    np.testing.assert_allclose(classifier(jnp.roll(features, 5, axis=1)), jnp.roll(logits, 20, axis=1), atol=1e-5)

    width = 1024
    cam = central_camera(width, width // 2)
    plan = np.array([[-1.5, -1.2], [2.0, -1.2], [2.0, 1.8], [-1.5, 1.8]])
    azimuth, _ = pixel_angles(cam, np.arange(width), np.zeros(width))
    distance = wall_distances(plan, azimuth)
    ceiling_v, floor_v = boundary_rows(distance, 0.65, cam)
    through = distance.copy()
    through[500:540] += 1.0  # a doorway's floor line, 1 m beyond the wall
    _, floor_through = boundary_rows(through, 0.65, cam)
    panorama = SimpleNamespace(width=width, height=width // 2, floor_v=floor_v, plan=plan, ceiling_height=0.65)
    nowhere = module.fused_scores(panorama, ceiling_v, floor_through, np.zeros(width, bool))
    assert nowhere[1] == pytest.approx(nowhere[0], rel=1e-4) and nowhere[0] > 0.5  # 40 columns ~20 px off
    assert nowhere[3] == pytest.approx(nowhere[2], abs=1e-4) and nowhere[5] == 0.0
    everywhere = module.fused_scores(panorama, ceiling_v, floor_through, np.ones(width, bool))
    assert everywhere[1] < 0.01 and everywhere[3] > nowhere[3]  # the ceiling's wall, nearer, taken in the doorway
    assert everywhere[5] >= 39 / width  # at least the doorway (elsewhere the two agree but for rounding)


@pytest.mark.slow
def test_frozen_backbone_trains_the_head_and_leaves_the_backbone_as_it_was():
    from flax import nnx

    from ncjax.network.model import stage_channels

    module = experiment("frozen_backbone")
    model = module.frozen_model("imagenet", "lite0-1024")
    backbone = jax.tree.map(np.asarray, nnx.state(model.backbone))
    head = jax.tree.map(np.asarray, nnx.state(model.head))
    train_config = module.head_training(1e-3, total_steps=10, warmup=0)
    module.set_train_mode(model, train_config)
    optimizer = module.head_optimizer(model, train_config)
    rng = np.random.default_rng(0)
    height, width = module.HEIGHT, module.WIDTH
    maps = [
        jnp.asarray(rng.normal(size=(2, height // s, width // s, c)), jnp.float16)
        for s, c in zip(module.FEATURE_STRIDES, stage_channels(model.config), strict=True)
    ]
    labels = [jnp.full((2, width), 150.0), jnp.full((2, width), 380.0), jnp.zeros((2, width))]
    losses = [float(module.train_step(model, optimizer, maps, labels, jax.random.key(i))) for i in range(4)]
    assert losses[-1] < losses[0]
    assert jax.tree.all(jax.tree.map(np.array_equal, backbone, jax.tree.map(np.asarray, nnx.state(model.backbone))))
    assert not jax.tree.all(jax.tree.map(np.array_equal, head, jax.tree.map(np.asarray, nnx.state(model.head))))


@pytest.mark.slow
def test_frozen_backbone_deepest_stages_give_the_backbones_coarsest_map_and_train_alone():
    from flax import nnx

    module = experiment("frozen_backbone")
    model = module.frozen_model("shipped", "lite0-1024")
    model.eval()
    images = jnp.asarray(np.random.default_rng(1).uniform(size=(2, module.HEIGHT, module.WIDTH, 3)), jnp.float32)
    maps = model.backbone_features(images)
    recomputed = module.head_inputs(model, maps, deepest=True)
    np.testing.assert_allclose(recomputed[-1], maps[-1], atol=1e-4)

    deepest = set(module.deepest_stages(model))
    assert deepest == {5, 6}  # Lite0: the stages after the stride-16 map

    def stage_params():
        flat = nnx.to_flat_state(nnx.state(model.backbone.stages, nnx.Param))
        return {path: np.asarray(value.get_value()) for path, value in flat}

    before = stage_params()
    train_config = module.head_training(1e-3, total_steps=10, warmup=0, backbone_scale=0.3)
    module.set_train_mode(model, train_config)
    optimizer = module.head_optimizer(model, train_config)
    labels = [jnp.full((2, module.WIDTH), 150.0), jnp.full((2, module.WIDTH), 380.0), jnp.zeros((2, module.WIDTH))]
    half = [m.astype(jnp.float16) for m in maps]
    for i in range(2):
        module.train_step(model, optimizer, half, labels, jax.random.key(i), deepest=True)
    after = stage_params()
    changed = {path[0] for path in before if not np.array_equal(before[path], after[path])}
    assert changed == deepest


def test_plan_layouts_recovers_a_turned_manhattan_room_from_its_exact_rows(tmp_path):
    from test_export import L_SHAPE, make_layout

    from ncjax.evaluation.central_metrics import evaluate_corners, room_geometry, surface_classes
    from ncjax.io.formats import format_path, write_layout_formats
    from ncjax.io.formats_read import read_layout
    from ncjax.synth.labels import corner_target

    module = experiment("plan_layouts")
    cam = ncjax.NonCentralPanorama(1024, 512, rc=0.0)
    turn = np.radians(25.0)
    rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    write_layout_formats(tmp_path / "label", make_layout(np.asarray(L_SHAPE) @ rotation.T), cam, "label_cor")
    label = read_layout(format_path(tmp_path / "label", "label_cor"), 1024, 512)
    classes = surface_classes(room_geometry(label, metric=False), 1024, 512)
    ceiling_v = np.sum(classes == 0, axis=0) - 0.5
    floor_v = 512 - np.sum(classes == 2, axis=0) - 0.5
    corner_prob = np.asarray(corner_target(label.floor[:, 0], np.ones(len(label.floor), bool), 1024))
    corners = module.plan_layout(ceiling_v, floor_v, corner_prob, cam)
    assert len(corners.floor) == len(L_SHAPE)
    assert evaluate_corners(corners, label)["iou3d"] > 0.97
    assert module.rows_explained(corners, ceiling_v, floor_v, 3.0) > 0.95
    assert module.rows_explained(corners, ceiling_v + 20.0, floor_v, 3.0) < 0.55


def test_doorway_rows_classes_each_column_by_what_stands_just_above_its_floor_line():
    from ncjax.synth.render import Semantic

    module = experiment("doorway_rows")
    semantic = np.full((8, 4), Semantic.WALL)
    semantic[6:] = Semantic.FLOOR
    semantic[2:6, 1] = Semantic.OPENING  # a doorway in column 1
    semantic[4:6, 2] = Semantic.OBJECT  # a cabinet low in column 2
    floor_v = np.array([6.0, 6.0, 6.0, 2.0])  # column 3: its line near the top, 3 rows above it is row 0
    classes = module.column_classes(semantic, floor_v)
    assert classes.tolist() == [Semantic.WALL, Semantic.OPENING, Semantic.WALL, Semantic.WALL]
    semantic[3, 2] = Semantic.OBJECT
    assert module.column_classes(semantic, floor_v)[2] == Semantic.OBJECT
    signed = np.array([1.0, -20.0, 3.0, -5.0])
    errors = {"class": classes, "floor": signed, "ceiling": np.zeros(4)}
    lines = module.table_lines("renders", errors)
    assert lines[0] == "| renders, doorway | 25.0% | 20.0 / 100.0% | -20.0 / -20.0 | 0.0 / 0.0% |"
    assert lines[1] == "| renders, wall | 75.0% | 3.0 / 0.0% | -0.3 / +1.0 | 0.0 / 0.0% |"


def test_doorway_rows_sheet_draws_the_true_rows_green_and_the_predicted_red_at_half_size():
    module = experiment("doorway_rows")
    image = np.full((64, 128, 3), 128, np.uint8)
    true_rows = (np.full(128, 10.0), np.full(128, 50.0))
    predicted = (np.full(128, 10.0), np.full(128, 30.0))
    tile = module.drawn_rows(image, true_rows, predicted).astype(int)  # BGR, half size
    assert tile.shape == (32, 64, 3)
    blue, green, red = tile[25, 32]  # the true floor line, row 50 at half size
    assert green > red + 40 and green > blue + 40
    blue, green, red = tile[15, 32]  # the predicted one
    assert red > green + 40 and red > blue + 40
    assert tile[5, 32, 1] > tile[5, 32, 2] + 40  # where both lie, the true row is drawn over the predicted
    assert np.all(np.abs(tile[20, 32] - 128) <= 2)  # nothing elsewhere


def test_photoreal_stage_arms_differ_only_in_how_the_home_rooms_are_rendered(tmp_path):
    module = experiment("photoreal_stage")
    from ncjax.cli.main import build_parser

    commands = {arm: module.arm_command(arm, tmp_path / "out", tmp_path / "work", smoke=False) for arm in module.ARMS}
    photoreal, raycast = commands["photoreal"], commands["raycast"]
    assert len(photoreal) == len(raycast)
    differing = [(a, b) for a, b in zip(photoreal, raycast, strict=True) if a != b]
    assert differing[0] == ("synth-photoreal-home:91:1000", "synth-decor-home:91:1000")
    # Everything else that differs is where each arm writes.
    assert all("photoreal" in a and "raycast" in b for a, b in differing[1:])
    for command in commands.values():
        args = build_parser().parse_args(command[command.index("train") :])
        assert args.micro_batches == 1 and args.batch_size == 16
        assert args.head_learning_rate_scale == 0 and args.backbone_learning_rate_scale > 0
        assert args.render_cache and args.render_budget < args.time_budget <= 540
        assert pathlib.Path(args.render_cache).is_relative_to(tmp_path / "work")
        assert pathlib.Path(args.export).parent == tmp_path / "out"


def test_photoreal_stage_runs_both_arms_and_fails_when_one_does(tmp_path, monkeypatch, capsys):
    module = experiment("photoreal_stage")
    started = []

    class FakeProcess:
        def __init__(self, command, stdout, stderr, env):
            started.append((command, env["XLA_PYTHON_CLIENT_MEM_FRACTION"]))
            self.code = 1 if "synth-decor-home:91:16" in command else 0

        def wait(self):
            return self.code

    monkeypatch.setattr(module.subprocess, "Popen", FakeProcess)
    assert (
        module.main(["--smoke", "--out", str(tmp_path), "--work", str(tmp_path / "work"), "--micro-batches", "4"]) == 1
    )
    assert [fraction for _, fraction in started] == ["0.45", "0.45"]
    assert all(command[command.index("--micro-batches") + 1] == "4" for command, _ in started)
    assert "raycast failed" in capsys.readouterr().err
    assert (tmp_path / "photoreal.log").exists() and (tmp_path / "raycast.log").exists()


def test_photoreal_factors_change_one_setting_of_the_quarter_renders_at_a_time():
    module = experiment("photoreal_factors")
    quarter = module.SOURCES["photoreal-quarter"].photoreal
    shipped = module.PHOTOREAL.photoreal
    assert (quarter.trace_scale, quarter.trace.samples_per_pixel) == (4, 4)
    assert dataclasses.replace(quarter, trace_scale=shipped.trace_scale, trace=shipped.trace) == shipped
    changed = {
        "matte": ("trace", "floor_specular", 0.0),
        "no-sun": (None, "sun", False),
        "flat-windows": (None, "sun", False),
        "direct": ("trace", "bounces", 1),
        "six-bounces": ("trace", "bounces", 6),
        "local-tone": ("camera", "local_compression", (0.4, 0.8)),
    }
    for variant, (part, field, value) in changed.items():
        config = module.SOURCES[f"photoreal-{variant}"].photoreal
        if part in ("trace", "camera"):
            inner = dataclasses.replace(getattr(quarter, part), **{field: value})
            assert config == dataclasses.replace(quarter, **{part: inner})
        else:
            assert config == dataclasses.replace(quarter, **{field: value})
    views = module.flat_window_views()
    assert views.shape == module.window_views().shape and np.all(views == views[:, :1, :1])
    # what a variant replaces while it renders is the renderer module's own (mock.patch.object needs it there)
    for _, replaced in module.VARIANTS.values():
        assert all(callable(getattr(module.render_module, name)) for name in replaced)


def test_weight_interpolation_draws_the_line_between_two_networks_of_one_architecture():
    module = experiment("weight_interpolation")
    config = HorizonNetConfig()
    start = module.ModelWeights(config, {"a": np.array([0.0, 2.0], np.float16), "b": np.array([4.0], np.float32)})
    end = module.ModelWeights(config, {"a": np.array([1.0, 0.0], np.float16), "b": np.array([0.0], np.float32)})
    for weight, expected_a, expected_b in (
        (0.0, [0.0, 2.0], [4.0]),
        (1.0, [1.0, 0.0], [0.0]),
        (0.25, [0.25, 1.5], [3.0]),
    ):
        line = module.interpolated(start, end, weight)
        np.testing.assert_allclose(line.tensors["a"], expected_a)
        np.testing.assert_allclose(line.tensors["b"], expected_b)
        assert line.tensors["a"].dtype == np.float32
    with pytest.raises(ValueError, match="not the same architecture"):
        module.interpolated(start, module.ModelWeights(config, {"a": end.tensors["a"]}), 0.5)


def test_weight_interpolation_moves_only_the_parts_asked_for():
    module = experiment("weight_interpolation")
    names = [
        "model/backbone/stem/conv/kernel",
        "model/backbone/stem/norm/mean",
        "model/compressions/0/norms/0/var",
        "model/compressions/0/convs/0/bias",
        "model/lstm/forward/0/cell/dense_i/kernel",
        "model/head/kernel",
    ]
    start = module.ModelWeights(HorizonNetConfig(), {name: np.zeros(2, np.float32) for name in names})
    end = module.ModelWeights(HorizonNetConfig(), {name: np.ones(2, np.float32) for name in names})
    for parts, moved in (
        (("backbone",), names[:2]),
        (("statistics",), names[1:3]),
        (("compressions", "lstm", "head"), names[2:]),
        (module.PARTS, names),
        (None, names),
    ):
        swapped = module.interpolated(start, end, 1.0, parts)
        assert [name for name in names if swapped.tensors[name][0] == 1.0] == moved, parts
    # The shipped network's tensors: each in exactly one of the four layers' parts.
    layers = ("backbone", "compressions", "lstm", "head")
    for name in module.read_weights("lite0-1024").tensors:
        assert sum(module.in_parts(name, (layer,)) for layer in layers) == 1, name


def test_weight_interpolation_refuses_a_weight_off_the_line_and_writes_nothing(tmp_path, capsys):
    module = experiment("weight_interpolation")
    out = tmp_path / "out"
    assert module.main(["--start", "lite0-1024", "--end", "lite0-1024", "--weights", "1.5", "--out", str(out)]) == 2
    assert "--weights must lie in [0, 1]" in capsys.readouterr().err
    assert not out.exists()


def test_plan_fallback_settings_differ_only_in_the_plan(tmp_path, capsys):
    module = experiment("plan_fallback")
    branches, fallback, everywhere = (module.SETTINGS[name] for name in ("branches", "fallback", "plan everywhere"))
    assert (branches.plan.fallback, fallback.plan.fallback, everywhere.plan.fallback) == (False, True, True)
    assert everywhere.checks.min_explained_fraction == 1.0
    assert fallback == ncjax.reconstruction.NETWORK_PIPELINE_CONFIG
    with pytest.raises(SystemExit):
        module.main(["--data", str(tmp_path / "missing")])
    assert "no folder" in capsys.readouterr().err


def test_stretched_views_map_rows_back_and_move_a_ring_to_its_stretched_elevation():
    module = experiment("stretched_views")
    rows = np.linspace(0.0, 511.0, 37)
    for factor in (0.8, 1.25, 1.6):
        # a room stretched by k then by 1 / k is the room itself
        back = module.stretched_rows(module.stretched_rows(rows, 512, factor), 512, 1 / factor)
        np.testing.assert_allclose(back, rows, atol=1e-3)
    np.testing.assert_allclose(module.stretched_rows(rows, 512, 1.0), rows, atol=1e-3)
    image = np.zeros((64, 128, 3), np.uint8)
    image[40] = 255  # a horizontal ring below the horizon
    stretched = module.stretch_image(image, 1.6)
    # walls farther for their height: the ring comes nearer the horizon, where stretched_rows of its new row is 40
    row = int(np.argmax(stretched[:, 0, 0]))
    assert 32 <= row < 40
    assert abs(module.stretched_rows(np.array([row]), 64, 1.6)[0] - 40) < 1.0


def test_parallax_budget_rooms_are_the_synth_rooms_and_other_scales_move_the_rows_more_the_larger_the_rig():
    module = experiment("parallax_budget")
    truth = module.true_room(5.0)
    width, depth = 5.0, module.ASPECT * 5.0
    dx, dy = module.CAMERA_OFFSET[0] * width, module.CAMERA_OFFSET[1] * depth
    # the same rectangle as a synth room (counter-clockwise, its centre at (dx, -dy)): its exact labels
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [width / 2, depth / 2] + [dx, -dy]
    room = ncjax.synth.Room(
        corners=jnp.asarray(corners, jnp.float32),
        mask=jnp.ones(4, bool),
        ceiling_height=jnp.float32(truth[5]),
        floor_height=jnp.float32(truth[6]),
        rc=jnp.float32(0.3),
        camera_position=jnp.zeros(3),
        is_atlanta=jnp.asarray(False),
        status=jnp.asarray(0),
    )
    cam = ncjax.NonCentralPanorama(128, 64, 0.3)
    labels = ncjax.synth.room_labels(room, cam)
    with jax.enable_x64(True):
        ceiling_v, floor_v = (np.asarray(x) for x in module.room_rows(cam, jnp.asarray(truth)))
        np.testing.assert_allclose(ceiling_v, np.asarray(labels.ceiling_v), atol=2e-3)
        np.testing.assert_allclose(floor_v, np.asarray(labels.floor_v), atol=2e-3)
        errors = [module.refit_error(ncjax.NonCentralPanorama(128, 64, rc), truth, 1.25, "both") for rc in (0.1, 0.4)]
    # a rig's parallax grows with its radius: a quarter too large a room is further from the rows of a larger one
    assert 0 < errors[0] < errors[1]


def test_rig_tilt_rows_of_a_tilted_rig_come_back_nearly_level_when_levelled():
    module = experiment("rig_tilt")
    boundaries = module.exact_boundaries(jax.tree.map(lambda x: x[0], module.generate_rooms(1, 0.6)))
    rng = np.random.default_rng(0)
    untilted = module.room_rows(boundaries, 0.0, rng)
    for name in ("tilted", "levelled"):  # no tilt: the dense points' rows are the level rig's
        for mine, level in zip(untilted[name], untilted["level"], strict=True):
            assert np.abs(mine - level).max() < 0.05
    rows = module.room_rows(boundaries, 1.0, rng)

    def rms(name):
        return np.sqrt(np.mean([(a - b) ** 2 for a, b in zip(rows[name], rows["level"], strict=True)]))

    # a degree moves the rows by about 2.8 px; levelled, what is left is the centres' rc / range of it
    assert rms("tilted") > 1.5 and rms("levelled") < 0.25 * rms("tilted"), (rms("tilted"), rms("levelled"))
