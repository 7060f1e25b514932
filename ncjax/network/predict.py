"""``ncjax.predict_boundaries``: per-column boundaries of RGB panoramas with the shipped model.

The image is resized to the model's input size (``jax.image.resize``,
bilinear with antialiasing when shrinking), the network runs in eval mode,
and its per-column outputs are resampled back to the input width
(wrap-aware linear interpolation) with the elevations converted to rows of
the input height. Rows and columns follow docs/design.md (pixel centres at
integers, row 0 at the top). The corner probability is the network's
``corner_base**d`` estimate (``HorizonNetConfig.corner_base``) with ``d`` in
columns of the *model* width, stretched to the input width. The pipeline
uses only its peaks, which any encoding of ``d`` keeps in place.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float, Shaped

from .checkpoint import load_model
from .config import DEFAULT_VIEWS, check_views
from .denoise import denoise_for_network
from .edges import EdgeSnap, snap_to_edges
from .model import HorizonNet, predict_views, prediction_to_rows
from .weights import DEFAULT_MODEL_PATH


@functools.cache
def _load_cached(path: str) -> HorizonNet:
    return load_model(path)


def default_model() -> HorizonNet:
    """The shipped model (``ncjax/models/lite0-1024.safetensors``), loaded once."""
    if not DEFAULT_MODEL_PATH.is_file():
        raise FileNotFoundError(
            f"the default network weights are missing ({DEFAULT_MODEL_PATH}); train a model with "
            "`ncjax train ... --export PATH` and copy it there, or pass "
            "model=ncjax.load_model(path)"
        )
    return _load_cached(str(DEFAULT_MODEL_PATH))


def image_boundaries(
    model: HorizonNet, images: Shaped[Array, "B H W 3"], views: int = 1, edge_snap: EdgeSnap | None = None
) -> tuple[Float[Array, "B W"], Float[Array, "B W"], Float[Array, "B W"]]:
    """Traced core of :func:`predict_boundaries`: noise brought down to the network's training range
    (:func:`~ncjax.network.denoise.denoise_for_network`), resize, network (over ``views``), rows of the input
    image, snapped to its edges unless ``edge_snap`` is None."""
    height, width = images.shape[1:3]
    pixels, resized = network_input(model, images)
    ceiling_v, floor_v, corner_prob = prediction_to_rows(predict_views(model, resized, views), height, width)
    if edge_snap is not None:
        snap = jax.vmap(snap_to_edges, in_axes=(0, 0, 0, None))
        ceiling_v, floor_v = snap(pixels, ceiling_v, floor_v, edge_snap)
    return ceiling_v, floor_v, corner_prob


def network_input(
    model: HorizonNet, images: Shaped[Array, "B H W 3"]
) -> tuple[Float[Array, "B H W 3"], Float[Array, "B h w 3"]]:
    """RGB uint8 panoramas as the network reads them: in [0, 1] with their noise brought down to the network's
    training range (:func:`~ncjax.network.denoise.denoise_for_network`), at their own size and at the network's."""
    size = (images.shape[0], model.config.input_height, model.config.input_width, 3)
    pixels = denoise_for_network(jnp.asarray(images).astype(jnp.float32) / 255.0)
    return pixels, jax.image.resize(pixels, size, method="linear")


_predict = nnx.jit(image_boundaries, static_argnames=("views", "edge_snap"))


def predict_boundaries(
    image: Shaped[np.ndarray, "*batch H W 3"],
    model: HorizonNet | None = None,
    views: int = DEFAULT_VIEWS,
    edge_snap: EdgeSnap | None = EdgeSnap(),
) -> tuple[Float[np.ndarray, "*batch W"], Float[np.ndarray, "*batch W"], Float[np.ndarray, "*batch W"]]:
    """Ceiling row, floor row and corner probability per column of RGB panoramas.

    A panorama noisier than the network's training data is first blurred down to
    it (:func:`~ncjax.network.denoise.denoise_for_network`); a clean one is used as it is.

    Args:
        image: RGB uint8, (H, W, 3) or a batch (B, H, W, 3), any size.
        model: a :class:`HorizonNet` (put in eval mode here); None for the
            shipped default model.
        views: the output is averaged over this many rolled and mirrored
            views of the panorama (1, or even; see
            :func:`~ncjax.network.model.predict_views`): more is more accurate and
            proportionally slower.
        edge_snap: how the network's rows are moved onto the image's own
            edges (:func:`~ncjax.network.edges.snap_to_edges`); None keeps the
            network's rows.

    Returns:
        ``(ceiling_v, floor_v, corner_prob)``, numpy float32 arrays of shape
        (W,) (or (B, W)): sub-pixel rows in the input image and probabilities.
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (3, 4) or image.shape[-1] != 3:
        raise ValueError(f"expected an RGB uint8 image (H, W, 3) or batch (B, H, W, 3), got {image.dtype}{image.shape}")
    check_views(views)
    model = default_model() if model is None else model
    model.eval()
    batch = image if image.ndim == 4 else image[None]
    rows = _predict(model, jnp.asarray(batch), views=views, edge_snap=edge_snap)
    rows = tuple(np.asarray(r) for r in rows)
    return rows if image.ndim == 4 else tuple(r[0] for r in rows)
