"""The single-line baseline [bermudez2016line] of paper Section 5.3: one horizontal 3D line from its own rays.

Each ceiling or floor line is fitted alone, with eq. iter1 of one line (the rows of
:func:`ncjax.solvers.wall.side_coefficients`) and the Plücker constraint of a horizontal line
(the quadratic quad_v, :func:`ncjax.solvers.wall.parallel_quadratic`); the paper's wall solvers
(:mod:`ncjax.solvers.wall`) fit a wall's two lines together.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ..geometry.linalg import scaled_null_space, segment_scaled_null_spaces
from ..geometry.plucker import horizontal_wall_line, safe_norm
from .wall import (
    canonical_orientation,
    masked_rays,
    parallel_quadratic,
    quadratic_root_angles,
    side_coefficients,
    unit_direction,
)


class HorizontalLine(eqx.Module):
    """One horizontal 3D line ``(ux, uy, 0, -h uy, h ux, -d)`` (the [bermudez2016line] baseline).

    Attributes:
        direction: unit ``(ux, uy)``, canonical sign (``d <= 0``).
        distance: signed distance ``d`` of its vertical plane along ``(-uy, ux)``.
        height: ``h``.
        line: the Plücker line (6,).
        ok: False when the fit failed (fields finite but meaningless).
    """

    direction: Float[Array, "*batch 2"]
    distance: Float[Array, "*batch"]
    height: Float[Array, "*batch"]
    line: Float[Array, "*batch 6"]
    ok: Bool[Array, "*batch"]


def solve_horizontal_line(
    rays: Float[Array, "n 6"], mask: Bool[Array, " n"], parallel_constraint: bool = True
) -> HorizontalLine:
    """One horizontal 3D line from its own rays: the baseline [bermudez2016line] of Section 5.3.

    The line ``(ux, uy, 0, -h uy, h ux, -d)`` is a line parallel to the known
    horizontal plane (4 dof). ``side(ray, line) = 0`` is linear in
    ``(u, v = h u, d)`` (eq. iter1 for one line): 5 unknowns, rows
    ``(xibar_1, xibar_2, xi_2, -xi_1, -xi_3)``. Of the two smallest right
    singular vectors ``W(t) = cos t W0 + sin t W1``, the Plücker (Klein)
    constraint of a horizontal line, ``cross(u, v) = 0`` (the quadratic
    quad_v), keeps two roots; the one nearest ``W0`` (smallest algebraic
    residual) is the answer. ``h`` is then ``u.v/|u|^2`` and ``d`` the last
    unknown over ``|u|``.

    Args:
        rays: the projecting rays of the line's image.
        mask: which rays are used.
        parallel_constraint: static; False keeps ``W0`` (no Plücker constraint).
    """
    basis = scaled_null_space(_horizontal_line_rows(masked_rays(rays, mask)), 2)
    return _horizontal_line_from_basis(basis, jnp.sum(mask), parallel_constraint)


def solve_horizontal_lines(
    rays: Float[Array, "n 6"], line_index: Int[Array, " n"], capacity: int, parallel_constraint: bool = True
) -> HorizontalLine:
    """Every line of a labelled boundary at once, each from its own rays (the baseline, batched over lines).

    Equal to ``jax.vmap(solve_horizontal_line, (None, 0))(rays, line_index == arange(capacity)[:, None])``
    but each ray is reduced once, into its own line's null space
    (:func:`ncjax.geometry.linalg.segment_scaled_null_spaces`), instead of once per line.

    Args:
        rays: the projecting rays of one boundary (e.g. the ceiling), one per column.
        line_index: the line each ray belongs to, -1 (or ``>= capacity``) for none.
        capacity: static number of lines ``K``.
        parallel_constraint: static, as in :func:`solve_horizontal_line`.

    Returns:
        A :class:`HorizontalLine` with a leading ``K`` axis.
    """
    basis = segment_scaled_null_spaces(_horizontal_line_rows(rays), line_index, capacity, 2)
    counts = jnp.sum(line_index[None, :] == jnp.arange(capacity)[:, None], 1)
    return jax.vmap(lambda b, c: _horizontal_line_from_basis(b, c, parallel_constraint))(basis, counts)


def _horizontal_line_rows(rays: Float[Array, "n 6"]) -> Float[Array, "n 5"]:
    a_u, a_h, a_d = side_coefficients(rays)
    return jnp.concatenate([a_u, a_h, a_d[:, None]], -1)


def _horizontal_line_from_basis(
    basis: Float[Array, "5 2"], count: Int[Array, ""], parallel_constraint: bool
) -> HorizontalLine:
    """The line of :func:`solve_horizontal_line` from the two smallest null vectors of its ``count`` rows."""
    w0, w1 = basis[:, 0], basis[:, 1]
    if parallel_constraint:
        theta = quadratic_root_angles(parallel_quadratic(w0[0:2], w1[0:2], w0[2:4], w1[2:4]))
        theta = theta[jnp.argmin(jnp.abs(jnp.sin(theta)))]
        vector = jnp.cos(theta) * w0 + jnp.sin(theta) * w1
    else:
        vector = w0
    u = vector[0:2]
    norm = safe_norm(u)
    safe = jnp.where(norm > 0, norm, 1.0)
    height = jnp.dot(u, vector[2:4]) / (safe * safe)
    direction, distance = canonical_orientation(unit_direction(u, norm), vector[4] / safe)
    ok = (count >= 4) & (norm > 0)
    return HorizontalLine(direction, distance, height, horizontal_wall_line(direction, distance, height), ok)
