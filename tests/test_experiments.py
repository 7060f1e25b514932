"""The noise sweep runs end to end in its small version and writes its outputs."""

import importlib.util
from pathlib import Path


def test_noise_sweep_small(tmp_path):
    path = Path(__file__).parents[1] / "experiments" / "noise_sweep.py"
    spec = importlib.util.spec_from_file_location("noise_sweep", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    results, rc_results, ablation = module.main(["--small", "--out", str(tmp_path)])
    for name in ("noise_sweep.csv", "noise_sweep.png", "rc_sweep.csv", "rc_sweep.png"):
        assert (tmp_path / name).stat().st_size > 0
    for res in results.values():
        assert res["depth"][0].max() < 1e-3  # sigma = 0: exact
    assert ablation["manhattan/constrained"]["direction"] < ablation["manhattan/unconstrained"]["direction"]


def test_pipeline_table_small(tmp_path):
    path = Path(__file__).parents[1] / "experiments" / "pipeline_table.py"
    spec = importlib.util.spec_from_file_location("pipeline_table", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    rows = module.main(["--small", "--out", str(tmp_path)])
    assert (tmp_path / "pipeline_table_small.md").stat().st_size > 0
    exact = rows[0]
    assert exact[-1] < 50.0 and exact[5] < 0.01  # failure rate (%), CE (m) on exact boundaries
