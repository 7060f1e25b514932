"""The noise sweep runs end to end in its small version and writes its outputs."""

import importlib.util
from pathlib import Path

import numpy as np


def test_noise_sweep_small(tmp_path):
    path = Path(__file__).parents[1] / "experiments" / "noise_sweep.py"
    spec = importlib.util.spec_from_file_location("noise_sweep", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    results, rc_results, ablation = module.main(["--small", "--out", str(tmp_path)])
    for name in ("noise_sweep.csv", "noise_sweep.png", "rc_sweep.csv", "rc_sweep.png"):
        assert (tmp_path / name).stat().st_size > 0
    for res in results.values():
        assert np.nanmax(res["depth"][0]) < 1e-3  # sigma = 0: exact
    # the refined (maximum-likelihood) layout beats the paper's constrained and the unconstrained null vector
    for other in ("paper", "null_vector"):
        assert ablation["manhattan/refined"]["corner"] < ablation[f"manhattan/{other}"]["corner"]
