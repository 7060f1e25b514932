"""Reflection models of the path tracer (:mod:`ncjax.synth.pathtrace`): Lambertian surfaces and the
rough-glossy floor, a GGX microfacet lobe over a Lambertian base.

Every function takes ONE direction (batch with ``jax.vmap``). Directions are unit vectors pointing AWAY from
the surface, ``outgoing`` towards the viewer and ``incoming`` towards the light, in the surface's local frame
(normal +z, see :func:`tangent_frame`) unless said otherwise.

The glossy lobe follows Heitz, "Understanding the masking-shadowing function in microfacet-based BRDFs"
(JCGT 2014: GGX distribution, height-correlated Smith masking-shadowing) and samples the distribution of
visible normals (Heitz, "Sampling the GGX distribution of visible normals", JCGT 2018), whose pdf cancels all
but ``G2 / G1`` from the sample's weight. Its Fresnel factor is 1: the specular weight of
:func:`glossy_brdf` stands for the (averaged) reflectance of the coat, so the BRDF is the convex mix
``(1 - w) albedo / pi + w f_ggx`` of two lobes that each reflect at most what they receive.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jaxtyping import Array, Float


def tangent_frame(normal: Float[Array, 3]) -> Float[Array, "3 3"]:
    """An orthonormal frame whose rows are two tangents and ``normal`` (unit): ``frame @ v`` takes a world
    vector to local coordinates, ``frame.T @ v`` back. Branchless (Duff et al., JCGT 2017), so continuous
    everywhere except across ``normal_z = 0`` where the sign flips, and never degenerate."""
    sign = jnp.where(normal[2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + normal[2])
    b = normal[0] * normal[1] * a
    tangent = jnp.stack([1.0 + sign * normal[0] ** 2 * a, sign * b, -sign * normal[0]])
    bitangent = jnp.stack([b, sign + normal[1] ** 2 * a, -normal[1]])
    return jnp.stack([tangent, bitangent, normal])


def sample_cosine(uniform: Float[Array, 2]) -> Float[Array, 3]:
    """A direction of the local upper hemisphere with pdf ``cos(theta) / pi`` (Malley's method: a uniform
    point of the unit disc lifted onto the hemisphere)."""
    radius = jnp.sqrt(uniform[0])
    angle = 2.0 * math.pi * uniform[1]
    return jnp.stack([radius * jnp.cos(angle), radius * jnp.sin(angle), jnp.sqrt(jnp.maximum(1.0 - uniform[0], 0.0))])


def ggx_distribution(half: Float[Array, 3], alpha: float) -> Float[Array, ""]:
    """The GGX (Trowbridge-Reitz) normal distribution ``D(h)`` of roughness ``alpha``: normalised so that
    ``int D(h) h_z dh = 1`` over the upper hemisphere; 0 below it."""
    scaled = (half[0] ** 2 + half[1] ** 2) / alpha**2 + half[2] ** 2
    return jnp.where(half[2] > 0, 1.0 / (math.pi * alpha**2 * scaled**2), 0.0)


def ggx_lambda(direction: Float[Array, 3], alpha: float) -> Float[Array, ""]:
    """Smith's ``Lambda`` of GGX, written with ``cos^2`` so that a grazing direction gives a large finite value,
    never NaN: ``G1 = 1 / (1 + Lambda)``."""
    cos2 = jnp.maximum(direction[2] ** 2, 1e-12)
    tan2 = jnp.maximum(1.0 - cos2, 0.0) / cos2
    return 0.5 * (jnp.sqrt(1.0 + alpha**2 * tan2) - 1.0)


def _half_vector(outgoing: Float[Array, 3], incoming: Float[Array, 3]) -> Float[Array, 3]:
    total = outgoing + incoming
    return total / jnp.maximum(jnp.linalg.norm(total), 1e-12)


def ggx_brdf(outgoing: Float[Array, 3], incoming: Float[Array, 3], alpha: float) -> Float[Array, ""]:
    """The GGX lobe ``D G2 / (4 cos_o cos_i)`` (Fresnel 1, height-correlated Smith ``G2``); 0 unless both
    directions are above the surface."""
    above = (outgoing[2] > 0) & (incoming[2] > 0)
    shadowing = 1.0 / (1.0 + ggx_lambda(outgoing, alpha) + ggx_lambda(incoming, alpha))
    value = ggx_distribution(_half_vector(outgoing, incoming), alpha) * shadowing
    return jnp.where(above, value / jnp.maximum(4.0 * outgoing[2] * incoming[2], 1e-12), 0.0)


def ggx_sample(outgoing: Float[Array, 3], alpha: float, uniform: Float[Array, 2]) -> Float[Array, 3]:
    """A reflected direction from the GGX visible normals seen from ``outgoing`` (above the surface): the
    microfacet normal is drawn with pdf ``G1(o) max(0, o.h) D(h) / cos_o`` (Heitz 2018, listing 1) and
    ``outgoing`` mirrored about it. The result may point below the surface (then the path ends)."""
    # The view in the hemisphere configuration (roughness stretched out), a frame around it, and a point of
    # the projected disc warped towards the visible half.
    view = jnp.stack([alpha * outgoing[0], alpha * outgoing[1], outgoing[2]])
    view = view / jnp.linalg.norm(view)
    length2 = view[0] ** 2 + view[1] ** 2
    inverse = 1.0 / jnp.sqrt(jnp.maximum(length2, 1e-30))
    tangent = jnp.where(length2 > 1e-14, jnp.stack([-view[1] * inverse, view[0] * inverse, 0.0]), jnp.eye(3)[0])
    bitangent = jnp.cross(view, tangent)
    radius = jnp.sqrt(uniform[0])
    angle = 2.0 * math.pi * uniform[1]
    t1, t2 = radius * jnp.cos(angle), radius * jnp.sin(angle)
    s = 0.5 * (1.0 + view[2])
    t2 = (1.0 - s) * jnp.sqrt(jnp.maximum(1.0 - t1**2, 0.0)) + s * t2
    normal = t1 * tangent + t2 * bitangent + jnp.sqrt(jnp.maximum(1.0 - t1**2 - t2**2, 0.0)) * view
    half = jnp.stack([alpha * normal[0], alpha * normal[1], jnp.maximum(normal[2], 0.0)])
    half = half / jnp.maximum(jnp.linalg.norm(half), 1e-12)
    return 2.0 * jnp.dot(outgoing, half) * half - outgoing


def ggx_pdf(outgoing: Float[Array, 3], incoming: Float[Array, 3], alpha: float) -> Float[Array, ""]:
    """The solid-angle pdf of :func:`ggx_sample`: ``G1(o) D(h) / (4 cos_o)`` with ``h`` the half vector (the
    mirror's Jacobian ``1 / (4 o.h)`` cancels the ``o.h`` of the visible normals). It integrates to 1 over the
    whole sphere; the part below the surface is the chance that a sample is lost."""
    half = _half_vector(outgoing, incoming)
    visible = (jnp.dot(outgoing, half) > 0) & (outgoing[2] > 0)
    masking = 1.0 / (1.0 + ggx_lambda(outgoing, alpha))
    value = masking * ggx_distribution(half, alpha) / jnp.maximum(4.0 * outgoing[2], 1e-12)
    return jnp.where(visible, value, 0.0)


def glossy_brdf(
    outgoing: Float[Array, 3], incoming: Float[Array, 3], albedo: Float[Array, 3], alpha: float, weight: float
) -> Float[Array, 3]:
    """The floor's BRDF: ``(1 - weight) albedo / pi + weight f_ggx``, 0 unless both directions are above."""
    above = (outgoing[2] > 0) & (incoming[2] > 0)
    diffuse = jnp.where(above, (1.0 - weight) / math.pi, 0.0) * albedo
    return diffuse + weight * ggx_brdf(outgoing, incoming, alpha)


def glossy_pdf(outgoing: Float[Array, 3], incoming: Float[Array, 3], alpha: float, weight: float) -> Float[Array, ""]:
    """The solid-angle pdf of :func:`sample_glossy`: the lobes' pdfs mixed by their selection chances."""
    cosine = jnp.where(incoming[2] > 0, incoming[2] / math.pi, 0.0)
    return (1.0 - weight) * cosine + weight * ggx_pdf(outgoing, incoming, alpha)


def sample_glossy(
    outgoing: Float[Array, 3], albedo: Float[Array, 3], alpha: float, weight: float, uniform: Float[Array, 3]
) -> tuple[Float[Array, 3], Float[Array, 3]]:
    """Sample the floor's BRDF: the GGX lobe with chance ``weight``, the cosine lobe otherwise.

    Returns:
        ``(incoming, throughput)``: the local direction and ``f cos / pdf`` with the mixed pdf of both lobes
        (one-sample MIS over the lobes, so that neither lobe's rare directions make fireflies); 0 when the
        direction points below the surface.
    """
    specular = uniform[2] < weight
    incoming = jnp.where(specular, ggx_sample(outgoing, alpha, uniform[:2]), sample_cosine(uniform[:2]))
    pdf = glossy_pdf(outgoing, incoming, alpha, weight)
    value = glossy_brdf(outgoing, incoming, albedo, alpha, weight) * jnp.maximum(incoming[2], 0.0)
    return incoming, jnp.where(pdf > 0, value / jnp.maximum(pdf, 1e-12), 0.0)
