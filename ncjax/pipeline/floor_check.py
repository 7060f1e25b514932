"""Step 0: floor rows the ceiling row of their column contradicts (not in the paper)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from ..geometry.camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles
from ..solvers.settings import scaled


def column_height_ratios(
    cam: NonCentralPanorama, ceiling_v: Float[Array, " W"], floor_v: Float[Array, " W"]
) -> Float[Array, " W"]:
    """Each column's ``tan(phi_c) / tan(phi_f)``: ``h_c / h_f`` (negative) as that column's rows give it.

    A column's rays all leave one centre on the circle, in one vertical plane
    (paper eq. pluckerray), so they meet the wall at one horizontal range
    ``t``: ``tan(phi_c) = h_c / t`` and ``tan(phi_f) = h_f / t``, whatever the
    walls. NaN where a row is missing.
    """
    columns = jnp.arange(ceiling_v.shape[0], dtype=ceiling_v.dtype)
    _, ceiling_elevation = pixel_to_angles(cam, columns, ceiling_v)
    _, floor_elevation = pixel_to_angles(cam, columns, floor_v)
    return jnp.tan(ceiling_elevation) / jnp.tan(floor_elevation)


def ceiling_floor_ratio(
    cam: NonCentralPanorama, ceiling_v: Float[Array, " W"], floor_v: Float[Array, " W"]
) -> Float[Array, ""]:
    """The panorama's median of :func:`column_height_ratios` over its columns: ``h_c / h_f`` (negative). Columns
    with a missing row are left out (NaN if all are)."""
    return jnp.nanmedian(column_height_ratios(cam, ceiling_v, floor_v))


def ceiling_consistent_floor(
    cam: NonCentralPanorama, ceiling_v: Float[Array, " W"], floor_v: Float[Array, " W"], threshold: Float[ArrayLike, ""]
) -> tuple[Float[Array, " W"], Bool[Array, " W"]]:
    """Floor rows that contradict their column's ceiling row, replaced by the row it implies (step 0).

    ``tan(phi_c) / tan(phi_f) = h_c / h_f`` in every column
    (:func:`ceiling_floor_ratio`): the panorama's median ratio gives each
    column's floor elevation from its ceiling one. The ratio is the image's own, not a
    prior; the metric scale still comes from the rows' non-central parallax.

    Args:
        cam: the camera.
        ceiling_v, floor_v: boundary rows (pixels; NaN = missing).
        threshold: pixels (at 512 rows); inf keeps every row.

    Returns:
        ``(floor_v, replaced)``: the rows, and which were replaced.
    """
    columns = jnp.arange(ceiling_v.shape[0], dtype=ceiling_v.dtype)
    _, ceiling_elevation = pixel_to_angles(cam, columns, ceiling_v)
    azimuth, _ = pixel_to_angles(cam, columns, floor_v)
    ratio = ceiling_floor_ratio(cam, ceiling_v, floor_v)
    _, implied = angles_to_pixel(cam, azimuth, jnp.arctan(jnp.tan(ceiling_elevation) / ratio))
    replaced = jnp.abs(floor_v - implied) > scaled(threshold, cam.height, 512)
    # a ceiling row below the horizon (an outlier) implies nothing about the floor's
    replaced = replaced & jnp.isfinite(implied) & (ratio < 0) & (ceiling_elevation > 0)
    return jnp.where(replaced, implied, floor_v), replaced
