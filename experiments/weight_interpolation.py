"""Networks on the straight line between two trained networks' weights (WiSE-FT, Wortsman et al. 2022).

    uv run python experiments/weight_interpolation.py --start FILE --end FILE --weights 0.25 0.5 0.75 --out DIR

A network fine-tuned from another (here: the shipped one, trained further on other renders) often lies in the
same basin, so the networks between them work too and can keep part of what each one reads well. Each weight
``t`` writes ``DIR/interpolated_<t>.safetensors`` (float16) holding ``(1 - t) * start + t * end`` for every
parameter and batch-norm statistic; score them with ``benchmarks/real_panoramas.py --model FILE``. Both files must
hold the same architecture. Bad input is one line on stderr and exit code 2, with nothing written.

``--parts`` moves only some parts along the line and keeps the rest of ``start``: ``backbone``, ``compressions``
(the height compressions), ``lstm``, ``head`` (the linear head) and ``statistics`` (every batch-norm mean and
variance). At weight 1 that is a swap, which tells which part of a trained network carries what it learnt:

    uv run python experiments/weight_interpolation.py --start lite0-1024 --end FILE --weights 1 --parts backbone \
        --out DIR
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ncjax.network.checkpoint import model_from_weights, save_model
from ncjax.network.weights import ModelWeights, read_weights

PARTS = ("backbone", "compressions", "lstm", "head", "statistics")


def in_parts(name: str, parts: tuple[str, ...]) -> bool:
    """Whether the tensor ``name`` (``model/<part>/...``) belongs to one of ``parts`` (:data:`PARTS`)."""
    statistic = name.endswith(("/mean", "/var"))
    return any((part == "statistics" and statistic) or name.split("/")[1] == part for part in parts)


def interpolated(
    start: ModelWeights, end: ModelWeights, weight: float, parts: tuple[str, ...] | None = None
) -> ModelWeights:
    """``(1 - weight) * start + weight * end`` for every tensor, or those of ``parts`` (``start``'s elsewhere);
    float32."""
    if start.config != end.config or set(start.tensors) != set(end.tensors):
        raise ValueError("the two networks are not the same architecture")
    tensors = {
        name: (1.0 - weight) * np.asarray(value, np.float32) + weight * np.asarray(end.tensors[name], np.float32)
        if parts is None or in_parts(name, parts)
        else np.asarray(value, np.float32)
        for name, value in start.tensors.items()
    }
    return ModelWeights(start.config, tensors)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--start", required=True, help="the network at weight 0 (a file or a shipped model's name)")
    parser.add_argument("--end", required=True, help="the network at weight 1")
    parser.add_argument("--weights", type=float, nargs="+", required=True, help="where on the line, 0..1")
    parser.add_argument(
        "--parts", nargs="+", choices=PARTS, help="only these parts move along the line (default: every tensor)"
    )
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:
        if any(not 0.0 <= weight <= 1.0 for weight in args.weights):
            raise ValueError(f"--weights must lie in [0, 1], got {args.weights}")
        start, end = read_weights(args.start), read_weights(args.end)
        parts = None if args.parts is None else tuple(args.parts)
        models = {weight: model_from_weights(interpolated(start, end, weight, parts)) for weight in args.weights}
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
