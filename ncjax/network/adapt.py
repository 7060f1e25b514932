"""Test-time adaptation: the network fitted to one panorama's own flat floor and ceiling, without labels.

:func:`adapt_model` takes a few gradient steps of the backbone's batch-norm scales and offsets (TENT, Wang et al.
2021, "Tent: fully test-time adaptation by entropy minimization", with the geometric
:func:`~ncjax.network.flatness.flatness_loss` in place of the entropy: rows that see one flat, level floor and
ceiling cost nothing) on one panorama, read in one view without edge snapping; the rest of the network and every
batch-norm statistic stay as trained. On the real photographs it brings the rows 2-3 px nearer their labels
(experiments/RESULTS.md, "Real photographs"); ``ncjax reconstruct`` (central panoramas whose rows are not flat) and
:func:`~ncjax.reconstruct_batch`'s ``adapt`` use it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jaxtyping import Array, Float, Shaped

from .config import AdaptConfig
from .flatness import flatness_loss
from .model import HorizonNet
from .predict import network_input

# the backbone's batch-norm scales and offsets (its ConvNorm layers' ``norm``; the height compressions' ``norms`` stay)
ADAPTED = nnx.All(nnx.Param, nnx.PathContains("backbone"), nnx.PathContains("norm"))


def adapt_model(
    model: HorizonNet, image: Shaped[Array, "H W 3"], config: AdaptConfig = AdaptConfig()
) -> tuple[HorizonNet, Float[Array, " steps"]]:
    """A copy of ``model`` whose backbone's batch-norm scales and offsets took ``config.steps`` Adam steps on
    :func:`flatness_loss` of one RGB uint8 panorama (H, W, 3), and the loss before each step. Traceable: the steps
    are one ``lax.scan``, and ``model``'s parameters may be traced (``ncjax.reconstruct_batch`` saves this program
    with the weights as its arguments)."""
    copy = nnx.clone(model)
    copy.eval()
    graphdef, adapted, rest = nnx.split(copy, ADAPTED, ...)
    pixels = network_input(copy, jnp.asarray(image)[None])[1]
    optimiser = optax.adam(config.learning_rate)

    def loss(params):
        prediction = nnx.merge(graphdef, params, rest, copy=True)(pixels)  # fresh variables in this trace
        return flatness_loss(prediction.ceiling_elevation[0], prediction.floor_elevation[0], config.huber)

    def step(carry, _):
        params, state = carry
        value, grads = jax.value_and_grad(loss)(params)
        updates, state = optimiser.update(grads, state, params)
        return (optax.apply_updates(params, updates), state), value

    (adapted, _), losses = jax.lax.scan(step, (adapted, optimiser.init(adapted)), length=config.steps)
    return nnx.merge(graphdef, adapted, rest, copy=True), losses


def adapt_to_panorama(
    model: HorizonNet, image: Shaped[np.ndarray, "H W 3"], config: AdaptConfig = AdaptConfig()
) -> tuple[HorizonNet, list[float]]:
    """:func:`adapt_model` compiled (once per network and image size): a copy of ``model`` fitted to one RGB uint8
    panorama (H, W, 3), and the loss before each step. ``model`` itself is left as it is; read the panorama's rows
    with the copy (:func:`~ncjax.network.predict.predict_boundaries`)."""
    adapted, losses = _adapt_model(model, jnp.asarray(image), config.traced())
    return adapted, [float(value) for value in losses]


_adapt_model = nnx.jit(adapt_model, static_argnames=("config",))
