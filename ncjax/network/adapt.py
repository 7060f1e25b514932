"""Test-time adaptation: the network fitted to one panorama's own flat floor and ceiling, without labels.

A room's floor and ceiling are flat and level, so a panorama's column sees its wall's foot and top at the same
distance: ``tan(ceiling elevation) / tan(-floor elevation)`` is the room's ``h_c / h_f`` in every column whose
rows lie on the wall. This holds for the rig's non-central panoramas as well: a column's rays leave one optical
centre at one azimuth (docs/design.md), and its elevations are measured from that centre. Rows that run through a
doorway into the next room's floor, onto a counter or along a ceiling fan break it. :func:`adapt_to_panorama` takes
a few gradient steps of the backbone's batch-norm scales and offsets (TENT, Wang et al. 2021, "Tent: fully test-time
adaptation by entropy minimization", with :func:`flatness_loss` in place of the entropy) on one panorama, read in one
view without edge snapping; the rest of the network and every batch-norm statistic stay as trained. On the real
photographs it brings the rows 2-3 px nearer their labels (experiments/RESULTS.md, "Real photographs");
``ncjax reconstruct --adapt`` and :func:`~ncjax.reconstruct_batch`'s ``adapt`` use it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jaxtyping import Array, Float, Shaped

from .config import AdaptConfig
from .model import HorizonNet
from .predict import network_input

# the backbone's batch-norm scales and offsets (its ConvNorm layers' ``norm``; the height compressions' ``norms`` stay)
ADAPTED = nnx.All(nnx.Param, nnx.PathContains("backbone"), nnx.PathContains("norm"))
_LEVEL = 1e-3  # radians kept between a boundary and the horizon or a pole, where tan is 0 or infinite


def flatness_loss(
    ceiling_elevation: Float[Array, " W"], floor_elevation: Float[Array, " W"], huber: float
) -> Float[Array, ""]:
    """The Huber loss of each column's ``log(tan(ceiling elevation) / tan(-floor elevation))`` about their median
    (held fixed): 0 when every column's rows see one flat, level floor and ceiling, whatever the room's shape.

    Args:
        ceiling_elevation, floor_elevation: (W,) radians, one panorama's boundaries (central or not).
        huber: the loss's threshold, in the log ratio.
    """
    ceiling = jnp.clip(ceiling_elevation, _LEVEL, jnp.pi / 2 - _LEVEL)
    floor = jnp.clip(-floor_elevation, _LEVEL, jnp.pi / 2 - _LEVEL)
    log_ratio = jnp.log(jnp.tan(ceiling)) - jnp.log(jnp.tan(floor))
    centre = jax.lax.stop_gradient(jnp.median(log_ratio))
    return jnp.mean(optax.huber_loss(log_ratio - centre, delta=huber))


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
    adapted, losses = _adapt_model(model, jnp.asarray(image), config)
    return adapted, [float(value) for value in losses]


_adapt_model = nnx.jit(adapt_model, static_argnames=("config",))
