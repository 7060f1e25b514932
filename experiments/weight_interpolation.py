"""Networks on the straight line between two trained networks' weights (WiSE-FT, Wortsman et al. 2022).

    uv run python experiments/weight_interpolation.py --start FILE --end FILE --weights 0.25 0.5 0.75 --out DIR

A network fine-tuned from another (here: the shipped one, trained further on other renders) often lies in the
same basin, so the networks between them work too and can keep part of what each one reads well. Each weight
``t`` writes ``DIR/interpolated_<t>.safetensors`` (float16) holding ``(1 - t) * start + t * end`` for every
parameter and batch-norm statistic; score them with ``benchmarks/real_panoramas.py --model FILE``. Both files must
hold the same architecture. Bad input is one line on stderr and exit code 2, with nothing written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ncjax.network.checkpoint import model_from_weights, save_model
from ncjax.network.weights import ModelWeights, read_weights


def interpolated(start: ModelWeights, end: ModelWeights, weight: float) -> ModelWeights:
    """``(1 - weight) * start + weight * end``, tensor by tensor, in float32."""
    if start.config != end.config or set(start.tensors) != set(end.tensors):
        raise ValueError("the two networks are not the same architecture")
    tensors = {
        name: ((1.0 - weight) * np.asarray(value, np.float32) + weight * np.asarray(end.tensors[name], np.float32))
        for name, value in start.tensors.items()
    }
    return ModelWeights(start.config, tensors)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--start", required=True, help="the network at weight 0 (a file or a shipped model's name)")
    parser.add_argument("--end", required=True, help="the network at weight 1")
    parser.add_argument("--weights", type=float, nargs="+", required=True, help="where on the line, 0..1")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:
        if any(not 0.0 <= weight <= 1.0 for weight in args.weights):
            raise ValueError(f"--weights must lie in [0, 1], got {args.weights}")
        start, end = read_weights(args.start), read_weights(args.end)
        models = {weight: model_from_weights(interpolated(start, end, weight)) for weight in args.weights}
    except (FileNotFoundError, ValueError) as error:
        print(f"weight_interpolation: {error}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    for weight, model in models.items():
        path = args.out / f"interpolated_{weight:g}.safetensors"
        save_model(model, path, dtype="float16")
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
