"""The command line entry point."""

import subprocess
import sys

import pytest

from ncjax import cli


def test_info_prints_versions_model_cache_folders_and_conventions(capsys):
    from ncjax.network.predict import DEFAULT_MODEL_PATH
    from ncjax.programs import user_cache_directory, user_program_directory

    assert cli.main(["info"]) == 0
    out = capsys.readouterr().out
    assert "ncjax 0.1.0" in out and "azimuth" in out
    assert f"model      lite0-1024 (the default, {DEFAULT_MODEL_PATH}); also shipped: compact1024" in out
    assert f"programs   {user_program_directory()} " in out and f"compiled   {user_cache_directory()} " in out


def test_unknown_command_fails_cleanly():
    with pytest.raises(SystemExit) as excinfo:
        cli.main(["frobnicate"])
    assert excinfo.value.code == 2


@pytest.mark.slow
def test_console_script_runs():
    result = subprocess.run([sys.executable, "-m", "ncjax.cli", "--version"], capture_output=True, text=True)
    assert result.returncode == 0 and "ncjax" in result.stdout


def test_edge_snap_is_on_unless_asked_off():
    import argparse

    from ncjax import EdgeSnap
    from ncjax.cli.reconstruct import add_reconstruct_arguments

    parser = argparse.ArgumentParser()
    add_reconstruct_arguments(parser)
    base = ["room.png", "--rc", "0.5", "--out", "out"]
    assert parser.parse_args(base).edge_snap == EdgeSnap()
    assert parser.parse_args([*base, "--no-edge-snap"]).edge_snap is None


@pytest.mark.slow
def test_fine_tuning_from_another_architecture_is_refused(tmp_path, capsys):
    import ncjax

    tiny = ncjax.HorizonNetConfig(depth=10, width=8, input_height=64, input_width=128, lstm_hidden=16, lstm_layers=1)
    ncjax.save_model(ncjax.network.init_model(tiny), tmp_path / "tiny.safetensors")
    checkpoints = tmp_path / "checkpoints"
    code = cli.main(
        [
            "train",
            "--data",
            "painted",
            "--steps",
            "1",
            "--corner-base",
            "0.8",
            "--checkpoint-dir",
            str(checkpoints),
            "--init-from",
            str(tmp_path / "tiny.safetensors"),
        ]
    )
    assert code == 2 and "cannot start" in capsys.readouterr().err and not checkpoints.exists()


def _parser(add_arguments):
    import argparse

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser


def test_every_setting_is_an_option_with_its_default_and_help():
    import dataclasses

    import ncjax
    from ncjax.cli.options import attribute_help
    from ncjax.cli.reconstruct import add_reconstruct_arguments
    from ncjax.cli.train import add_train_arguments

    for defaults, add_arguments, skipped in (
        (
            ncjax.NETWORK_PIPELINE_CONFIG,
            add_reconstruct_arguments,
            {"--prior-room-height"},
        ),  # the prior's route sets it
        (ncjax.TrainConfig(), add_train_arguments, {"--total-steps"}),  # set by --steps
    ):
        help_text = " ".join(_parser(add_arguments).format_help().split())
        configurations = [(defaults, "--")]
        for config, prefix in configurations:
            documented = attribute_help(type(config))
            for field in dataclasses.fields(config):
                option = prefix + field.name.replace("_", "-")
                if option in skipped:
                    continue
                assert documented.get(field.name), f"{type(config).__name__}.{field.name} has no docstring line"
                value = getattr(config, field.name)
                if dataclasses.is_dataclass(value):  # its fields are options --field-inner-field
                    configurations.append((value, option + "-"))
                    continue
                assert option in help_text, option
                assert f"(default: {value})" in help_text


def test_options_replace_only_the_settings_given(capsys):
    import ncjax
    from ncjax.cli.options import config_from_options
    from ncjax.cli.reconstruct import add_reconstruct_arguments
    from ncjax.cli.train import add_train_arguments

    base = ["room.png", "--rc", "0.5", "--out", "out"]
    parser = _parser(add_reconstruct_arguments)
    assert config_from_options(parser.parse_args(base), ncjax.NETWORK_PIPELINE_CONFIG) is ncjax.NETWORK_PIPELINE_CONFIG
    args = parser.parse_args(
        [*base, "--corners-threshold", "0.5", "--no-uncertainty-covariance", "--checks-max-height-uncertainty", "inf"]
    )
    config = config_from_options(args, ncjax.NETWORK_PIPELINE_CONFIG)
    expected = ncjax.NETWORK_PIPELINE_CONFIG.replace(
        corners={"threshold": 0.5}, uncertainty={"covariance": False}, checks={"max_height_uncertainty": float("inf")}
    )
    assert config == expected
    with pytest.raises(SystemExit):  # an internal setting of the height prior's route, not an option
        parser.parse_args([*base, "--prior-room-height", "3"])
    for old, new in (
        (["--corner-threshold", "0.5"], "--corners-threshold"),
        (["--no-covariance"], "--no-uncertainty-covariance"),
    ):
        with pytest.raises(SystemExit):  # a setting's name before the settings were grouped by stage
            parser.parse_args([*base, *old])
        assert new in capsys.readouterr().err
    train_args = _parser(add_train_arguments).parse_args(["--learning-rate", "3e-4", "--no-flip"])
    train_config = config_from_options(train_args, ncjax.TrainConfig(total_steps=10))
    assert (train_config.peak_learning_rate, train_config.flip, train_config.total_steps) == (3e-4, False, 10)
    train_args = _parser(add_train_arguments).parse_args(
        ["--preset", "lite0-1024", "--backbone-learning-rate-scale", "0.25", "--head-learning-rate-scale", "0"]
    )
    train_config = config_from_options(train_args, ncjax.TrainConfig())
    assert train_config == ncjax.TrainConfig(backbone_learning_rate_scale=0.25, head_learning_rate_scale=0.0)
    assert ncjax.HorizonNetConfig.preset(train_args.preset).backbone == "efficientnet_lite0"
    train_args = _parser(add_train_arguments).parse_args(
        ["--no-photometric", "--augment-jpeg-quality", "5", "30", "--augment-seam-count", "2"]
    )
    train_config = config_from_options(train_args, ncjax.TrainConfig())
    augment = ncjax.synth.AugmentConfig(jpeg_quality=(5.0, 30.0), seam_count=2)
    assert train_config == ncjax.TrainConfig(photometric=False, augment=augment)


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--ransac-sample-size", "2"], "--ransac-sample-size must be >= 3"),
        (["--corners-threshold", "2"], "--corners-threshold must be in [0, 1"),
        (["--corners-threshold", "-1"], "--corners-threshold must be in [0, 1"),
        (["--corners-fallback-threshold", "1.5"], "--corners-fallback-threshold must be in [0, 1"),
        (["--checks-min-finite-fraction", "2"], "--checks-min-finite-fraction must be in [0, 1"),
        (["--checks-max-room-height", "0"], "--checks-max-room-height must be > 0"),
        (["--corners-min-corners", "40"], "--corners-min-corners must be in [0, 16]"),
        (["--capacity", "2"], "--capacity must be >= 4"),
    ],
)
def test_a_bad_setting_is_one_line_naming_its_option_before_any_work(tmp_path, capsys, option, message):
    out = tmp_path / "out"
    code = cli.main(["reconstruct", str(tmp_path / "missing.png"), "--rc", "0.5", "--out", str(out), *option])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"ncjax reconstruct: error: {message}") and err.count("\n") == 1, err
    assert not out.exists()
