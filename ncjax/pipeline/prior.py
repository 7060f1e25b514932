"""Scale from a height prior: central panoramas (``rc = 0``) and radii too small to fix the scale.

A central panorama determines its room up to one scale about the camera; a
non-central one with a radius of a few centimetres determines it too weakly.
Central methods (HorizonNet, LGT-Net) fix it with a known camera height. Here
the prior fixes the two heights, the rows then fix every boundary point, and
the pipeline runs unchanged on the panorama a virtual non-central rig would
take of those points:

1. In every column both rays leave one centre in one vertical plane, so
   ``tan(phi_c) / tan(phi_f) = h_c / h_f`` whatever the walls (the ratio of
   step 0, :func:`ncjax.pipeline.floor_check.ceiling_floor_ratio`); the
   panorama's median ratio and the prior give ``h_c`` and ``h_f``
   (:func:`prior_heights`).
2. Each row is then a 3D boundary point at horizontal range
   ``t = h / tan(phi)`` from its column's centre, ``rc + t`` from the axis
   (:func:`ncjax.geometry.reprojection.boundary_ranges`).
3. A virtual rig of radius ``rc'`` (half the nearest points' range: strong
   parallax) sees those points at the rows of :func:`virtual_rows`; the
   geometric pipeline (both worlds, occlusions, the adjustment) runs on them,
   its RANSAC walls at the prior's two heights (plan lines through the
   boundary points, :func:`ncjax.solvers.wall_at_heights.solve_wall_at_heights`: a
   wall's few noisy rows fix two unknowns far better than four), its walls
   brought to the prior's room height before the final adjustment
   (:func:`ncjax.pipeline.run.at_room_height`: the virtual parallax of noisy
   rows can put them far off), and its layout is scaled so that the prior's
   height holds exactly (:func:`ncjax.pipeline.run.finish`). The image's
   own central rays cannot tell a room from a scaled copy, so the scaling
   changes no reprojection.

Exact on exact rows (the tests reproduce rendered rooms). The covariances are
those of the fit on the virtual rows given that the prior is right: the heights'
carried through the rescaling (:func:`rescale_to_prior`), so that the height the
prior states has none; the prior's own error scales every length and is not in them.
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..geometry.camera import NonCentralPanorama, angles_to_pixel
from ..geometry.reprojection import boundary_ranges
from .floor_check import ceiling_floor_ratio
from .types import Layout, LayoutStatus

# What a prior can give: the camera's height above the floor (HorizonNet's 1.6 m), the ceiling's height
# above the camera (``h_c``, :attr:`ncjax.Layout.ceiling_height`), or the room's floor-to-ceiling height.
PRIOR_KINDS = ("camera_height", "ceiling_height", "room_height")
DEFAULT_CAMERA_HEIGHT = 1.6

# The virtual rig's radius as a fraction of the near boundary points' range (their 5% quantile): large for
# parallax, and every point stays outside the circle; rows nearer than VIRTUAL_MARGIN times the radius are dropped.
VIRTUAL_RADIUS_FRACTION = 0.5
VIRTUAL_MARGIN = 1.2
# How far a prior's height may be from the truth, relative, at one standard deviation: the default camera height of
# 1.6 m stands for hand-held and tripod cameras of about 1.35-1.85 m (:func:`scale_conflict`).
PRIOR_RELATIVE_SIGMA = 0.15


class HeightPrior(eqx.Module):
    """A known height that fixes the scale (``kind`` static, ``value`` traced, metres, > 0).

    Attributes:
        kind: one of :data:`PRIOR_KINDS`.
        value: the height; ``jax.vmap`` adds batch axes (one prior per panorama).
    """

    kind: str = eqx.field(static=True)
    value: Float[Array, "*batch"]

    def __init__(self, kind: str, value: Float[ArrayLike, "*batch"]):
        if kind not in PRIOR_KINDS:
            raise ValueError(f"the height prior must be one of {PRIOR_KINDS}, got {kind!r}")
        self.kind = kind
        if isinstance(value, jax.Array):  # a tracer too
            self.value = jnp.asarray(value, jnp.float32)
        else:  # copied as float32: jnp.asarray would compile a conversion, in every new process
            self.value = jax.device_put(np.float32(value))

    def __check_init__(self):
        if isinstance(self.value, jax.core.Tracer):  # traced (inside jit or vmap): the caller's job
            return
        value = np.asarray(self.value)
        if not value.min() > 0 or not np.all(np.isfinite(value)):
            raise ValueError(f"the {self.kind.replace('_', ' ')} must be a finite height > 0 in metres")


def prior_heights(ratio: Float[ArrayLike, ""], prior: HeightPrior) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """``(h_c, h_f)`` from the ratio ``h_c / h_f`` (negative) and the prior.

    ``camera_height`` H: ``h_f = -H``; ``ceiling_height`` C: ``h_c = C``;
    ``room_height`` R: ``h_c - h_f = R``; the other height from ``h_c = ratio h_f``.
    """
    value = prior.value
    if prior.kind == "camera_height":
        floor_height = -value
    elif prior.kind == "ceiling_height":
        floor_height = value / ratio
    else:
        floor_height = value / (ratio - 1.0)
    return ratio * floor_height, floor_height


def virtual_rows(
    cam: NonCentralPanorama,
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    ceiling_height: Float[ArrayLike, ""],
    floor_height: Float[ArrayLike, ""],
) -> tuple[NonCentralPanorama, Float[Array, " W"], Float[Array, " W"]]:
    """The camera and rows of a virtual non-central rig that sees the same boundary points (steps 2-3).

    Returns:
        ``(virtual_cam, ceiling_v, floor_v)``: same size and fields of view as ``cam``, radius
        :data:`VIRTUAL_RADIUS_FRACTION` of the near points' range; rows NaN where missing or too near.
    """
    azimuth, ceiling_range = boundary_ranges(cam, ceiling_v, ceiling_height)
    _, floor_range = boundary_ranges(cam, floor_v, floor_height)
    near = jnp.nanquantile(jnp.concatenate([ceiling_range, floor_range]), 0.05)
    virtual = dataclasses.replace(cam, rc=VIRTUAL_RADIUS_FRACTION * jnp.nan_to_num(near, nan=1.0))

    def rows(ranges, height):
        outside = ranges > VIRTUAL_MARGIN * virtual.rc
        elevation = jnp.arctan2(height, jnp.where(outside, ranges - virtual.rc, jnp.nan))
        return angles_to_pixel(virtual, azimuth, elevation)[1]

    return virtual, rows(ceiling_range, ceiling_height), rows(floor_range, floor_height)


def prior_rows(
    cam: NonCentralPanorama, ceiling_v: Float[Array, " W"], floor_v: Float[Array, " W"], prior: HeightPrior
) -> tuple[NonCentralPanorama, Float[Array, " W"], Float[Array, " W"], tuple[Float[Array, ""], Float[Array, ""]]]:
    """Steps 1-3: the virtual rig and its rows for a panorama whose scale ``prior`` fixes, and the heights
    ``(h_c, h_f)`` the prior gives (the virtual rows' own)."""
    ratio = ceiling_floor_ratio(cam, ceiling_v, floor_v)
    ceiling_height, floor_height = prior_heights(ratio, prior)
    return *virtual_rows(cam, ceiling_v, floor_v, ceiling_height, floor_height), (ceiling_height, floor_height)


def rescale_to_prior(layout: Layout, prior: HeightPrior) -> Layout:
    """``layout`` scaled so that the height ``prior`` states holds exactly (unchanged if it has no such height).

    The heights' covariance is carried through the rescaling ``h -> h p / q(h)`` to first order (``q`` the prior's
    quantity, :func:`prior_quantity`; ``p`` its value): the covariance of the heights given the prior, in which the
    height the prior states has none and the other keeps only the uncertainty of their ratio. The corners' covariances
    are scaled with the lengths, the share of the scale's uncertainty in them kept (the layout holds no covariance
    between corners and heights to take it out).
    """
    heights = jnp.stack([layout.ceiling_height, layout.floor_height])
    measured = prior_quantity(prior.kind, heights[0], heights[1])
    usable = measured > 0
    scaled = scale_layout(layout, jnp.where(usable, prior.value / jnp.where(usable, measured, 1.0), 1.0))

    def rescaled(h):
        return h * prior.value / prior_quantity(prior.kind, h[0], h[1])

    jacobian = jax.jacfwd(rescaled)(jnp.where(usable, heights, jnp.array([1.0, -1.0], heights.dtype)))
    given_prior = jacobian @ layout.height_covariance @ jacobian.T
    # an unbounded covariance (rows that leave the heights free) stays unbounded
    known = usable & jnp.all(jnp.isfinite(layout.height_covariance))
    return dataclasses.replace(scaled, height_covariance=jnp.where(known, given_prior, scaled.height_covariance))


def prior_quantity(kind: str, ceiling_height: Float[ArrayLike, "*b"], floor_height: Float[ArrayLike, "*b"]):
    """The height a prior of ``kind`` states, measured on a layout's heights."""
    if kind == "camera_height":
        return -floor_height
    if kind == "ceiling_height":
        return ceiling_height
    return ceiling_height - floor_height


def scale_conflict(geometry: Layout, prior: HeightPrior) -> Float[Array, ""]:
    """How many standard deviations apart the height a non-central layout's own parallax measured and a prior are.

    ``z = |log(q / p)| / sqrt((sigma_q / q)^2 + s^2)``: ``q`` the prior's quantity (:func:`prior_quantity`)
    on the geometry's layout, ``sigma_q`` its first-order standard deviation from the layout's height
    covariance, ``p`` the prior's value and ``s`` :data:`PRIOR_RELATIVE_SIGMA`, both errors relative (a
    scale is wrong by a factor). Rows of one room seen by the rig give a ``q`` near the truth or a large
    ``sigma_q`` (a radius small for the room: the scale is free); rows that are not one room, such as
    boundaries through doorways or along desks, can give a confident ``q`` far from any real room. Where the
    geometry measured no height (``q <= 0`` or a NaN or infinite covariance) ``z`` is 0: no evidence either way.

    Args:
        geometry: one layout with the scale the rows' parallax gave (any status; its heights and covariance).
        prior: one height prior.

    Returns:
        ``z`` (>= 0), in standard deviations.
    """
    quantity = functools.partial(prior_quantity, prior.kind)
    measured = quantity(geometry.ceiling_height, geometry.floor_height)
    gradient = jnp.stack(jax.grad(quantity, argnums=(0, 1))(geometry.ceiling_height, geometry.floor_height))
    variance = gradient @ geometry.height_covariance @ gradient
    usable = (measured > 0) & jnp.isfinite(variance)
    safe = jnp.where(usable, measured, 1.0)
    spread = jnp.sqrt(jnp.where(usable, variance, 0.0) / safe**2 + PRIOR_RELATIVE_SIGMA**2)
    return jnp.where(usable, jnp.abs(jnp.log(safe / prior.value)) / spread, 0.0)


def scale_layout(layout: Layout, factor: Float[ArrayLike, ""]) -> Layout:
    """``layout`` scaled about the camera by ``factor``: lengths times it, covariances times its square.

    Plücker lines ``(u, m)`` keep their direction and scale their moment.
    """
    factor = jnp.asarray(factor)

    def lines(x):
        return jnp.concatenate([x[..., :3], factor * x[..., 3:]], -1)

    return dataclasses.replace(
        layout,
        ceiling_corners=factor * layout.ceiling_corners,
        floor_corners=factor * layout.floor_corners,
        ceiling_height=factor * layout.ceiling_height,
        floor_height=factor * layout.floor_height,
        wall_distances=factor * layout.wall_distances,
        ceiling_lines=lines(layout.ceiling_lines),
        floor_lines=lines(layout.floor_lines),
        corner_covariance=factor**2 * layout.corner_covariance,
        height_covariance=factor**2 * layout.height_covariance,
    )


def flag_scale_conflicts(
    layout: Layout,
    geometry: Layout,
    prior: HeightPrior,
    max_scale_conflict: Float[ArrayLike, ""],
) -> Layout:
    """``layout`` with ``SCALE_CONFLICT`` where an ``OK`` layout took its scale from ``prior`` because its
    ``geometry`` was ``UNCERTAIN_SCALE`` (only a non-central one can be: a central one is ``NO_SCALE``), and that
    geometry's height lies more than ``max_scale_conflict`` standard deviations from the prior's
    (:func:`~ncjax.pipeline.prior.scale_conflict`).

    Args:
        layout: the layouts written, B leading.
        geometry: the layouts with the scale each panorama's geometry measured, B leading.
        prior: the height prior (a scalar value or one per panorama).
        max_scale_conflict: the flag's threshold (``PriorConfig.max_scale_conflict``).

    Returns:
        ``layout`` with those panoramas' status ``SCALE_CONFLICT`` and ``ok`` false; the rest unchanged.
    """
    prior = jax.tree.map(lambda x: jnp.broadcast_to(x, geometry.status.shape), prior)
    conflict = jax.vmap(scale_conflict)(geometry, prior)
    flagged = (
        (geometry.status == LayoutStatus.UNCERTAIN_SCALE)
        & (layout.status == LayoutStatus.OK)
        & (conflict > max_scale_conflict)
    )
    return dataclasses.replace(
        layout, status=jnp.where(flagged, LayoutStatus.SCALE_CONFLICT, layout.status), ok=layout.ok & ~flagged
    )
