"""Joint layout solvers (paper Sections 4.2 "Manhattan layout solver" and 4.3
"Atlanta layout solver").

Inputs are per image column: the ceiling and floor Plücker rays (W, 6), the
index of the wall the column sees (W,) int (-1: none), and per wall (fixed
capacity K, DESIGN.md section 4) a mask plus either a Manhattan label or a
known direction. Masked-out walls get a pinning row ``d_k = 0`` so that the
null space stays the one of the present walls; a wall in the mask that no
column sees makes ``ok`` False.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._linalg import scaled_null_space
from ._plucker import horizontal_wall_line, intersect_coplanar_lines, safe_norm
from ._wall import (
    canonical_orientation,
    constrained_null_vector,
    heights_of,
    masked_rays,
    side_coefficients,
    wall_rows,
)


class WallLayout(eqx.Module):
    """The walls of a room with shared ceiling and floor heights.

    All fields are traced arrays; ``K`` is the wall capacity.

    Attributes:
        directions: unit wall directions (K, 2), canonical sign (camera on the left).
        distances: signed distances (K,) along ``(-uy, ux)`` (<= 0).
        ceiling_height: ``h_c``.
        floor_height: ``h_f``.
        ceiling_lines: Plücker ceiling lines (K, 6).
        floor_lines: Plücker floor lines (K, 6).
        mask: which walls were solved (present in the input mask and seen by some column).
        ok: False when the solver failed (values finite but meaningless).
    """

    directions: Float[Array, "*batch K 2"]
    distances: Float[Array, "*batch K"]
    ceiling_height: Float[Array, "*batch"]
    floor_height: Float[Array, "*batch"]
    ceiling_lines: Float[Array, "*batch K 6"]
    floor_lines: Float[Array, "*batch K 6"]
    mask: Bool[Array, "*batch K"]
    ok: Bool[Array, "*batch"]


def _make_layout(directions, distances, h_c, h_f, mask, ok) -> WallLayout:
    directions, distances = canonical_orientation(directions, distances)
    return WallLayout(
        directions=directions,
        distances=distances,
        ceiling_height=h_c,
        floor_height=h_f,
        ceiling_lines=horizontal_wall_line(directions, distances, jnp.broadcast_to(h_c, distances.shape)),
        floor_lines=horizontal_wall_line(directions, distances, jnp.broadcast_to(h_f, distances.shape)),
        mask=mask,
        ok=ok,
    )


def _column_bookkeeping(wall_index: Array, wall_mask: Array) -> tuple[Array, Array, Array, Array]:
    """``(column_used (W,), one_hot (W, K), present (K,), all_seen ())``."""
    capacity = wall_mask.shape[0]
    one_hot = jax.nn.one_hot(wall_index, capacity, dtype=bool)  # -1 gives a zero row
    column_used = jnp.any(one_hot & wall_mask[None, :], axis=1)
    seen = jnp.any(one_hot & column_used[:, None], axis=0)
    present = wall_mask & seen
    return column_used, one_hot & column_used[:, None], present, jnp.all(seen | ~wall_mask)


def _distance_columns(a_d: Array, one_hot: Array, present: Array) -> tuple[Array, Array]:
    """The ``d_k`` columns of the ray rows, and the pinning rows ``d_k = 0`` of absent walls."""
    columns = a_d[:, None] * one_hot.astype(a_d.dtype)
    pins = jnp.diag(jnp.where(present, 0.0, 1.0).astype(a_d.dtype))
    return columns, pins


def quarter_turn(ray: Float[Array, "*batch 6"]) -> Float[Array, "*batch 6"]:
    """Rotate a Plücker line by -90 degrees about z: ``(x, y, z) -> (y, -x, z)`` for both halves.

    ``side(quarter_turn(ray), line(u, d, h)) = side(ray, line(u_perp, d, h))``
    with ``u_perp = (-uy, ux)``: this turns eqs. manx/many into manPx/manPy.
    """
    return jnp.stack([ray[..., 1], -ray[..., 0], ray[..., 2], ray[..., 4], -ray[..., 3], ray[..., 5]], -1)


def ray_in_wall_frame(ray: Float[Array, "*batch 6"], direction: Float[Array, "*batch 2"]) -> Float[Array, "*batch 6"]:
    """A ray in the wall's reference system ``{e1, e2, e3}`` (Section 4.3, rays ``Xi'``).

    With ``e1 = (ux, uy, 0)``, ``e2 = (-uy, ux, 0)``, ``e3 = z``: both halves of
    the Plücker vector become ``(e1 . x, e2 . x, x_3)`` (a rotation about z by
    minus the wall's angle).
    """
    ux, uy = direction[..., 0:1], direction[..., 1:2]

    def rotate(x):
        return jnp.concatenate([ux * x[..., 0:1] + uy * x[..., 1:2], ux * x[..., 1:2] - uy * x[..., 0:1], x[..., 2:3]], -1)

    return jnp.concatenate([rotate(ray[..., :3]), rotate(ray[..., 3:])], -1)


def solve_manhattan_layout(
    ceiling_rays: Float[Array, "W 6"],
    floor_rays: Float[Array, "W 6"],
    wall_index: Int[Array, " W"],
    wall_mask: Bool[Array, " K"],
    labels: Int[Array, " K"],
    parallel_constraint: bool = True,
) -> WallLayout:
    """Manhattan layout solver (Section 4.2): ``A (u, v, w, d_1..d_K) = 0``.

    Walls labelled 0 have direction ``u`` and contribute eqs. manx/many;
    walls labelled 1 have ``u_perp = (-uy, ux)`` and contribute
    eqs. manPx/manPy (the same rows for the ray turned by -90 degrees,
    :func:`quarter_turn`). The two smallest (equilibrated) null vectors and
    the parallelism quadratics give the solution as for one wall
    (:func:`ncjax.solve_wall`); any yaw of the room is fine.

    Args:
        ceiling_rays: per-column ceiling rays.
        floor_rays: per-column floor rays.
        wall_index: the wall each column sees, -1 for none.
        wall_mask: which of the K walls exist.
        labels: per wall, 0 for ``u`` and 1 for ``u_perp``.
        parallel_constraint: static; False keeps the least-squares null vector.

    Returns:
        The :class:`WallLayout` (canonical orientation per wall).
    """
    column_used, one_hot, present, all_seen = _column_bookkeeping(wall_index, wall_mask)
    turned = labels[jnp.maximum(wall_index, 0)] == 1
    rows = []
    for rays in (ceiling_rays, floor_rays):
        rays = masked_rays(rays, column_used)
        rays = jnp.where(turned[:, None], quarter_turn(rays), rays)
        rows.append(rays)
    ceiling, floor = wall_rows(*rows)
    ceiling_d, pins = _distance_columns(ceiling[:, 6], one_hot, present)
    floor_d, _ = _distance_columns(floor[:, 6], one_hot, present)
    a = jnp.concatenate(
        [
            jnp.concatenate([ceiling[:, :6], ceiling_d], 1),
            jnp.concatenate([floor[:, :6], floor_d], 1),
            jnp.concatenate([jnp.zeros((pins.shape[0], 6), pins.dtype), pins], 1),
        ]
    )
    basis = scaled_null_space(a, 2)
    if parallel_constraint:
        vector, ok = constrained_null_vector(basis)
    else:
        vector, ok = basis[:, 0], jnp.array(True)
    norm, h_c, h_f = heights_of(vector)
    safe = jnp.where(norm > 0, norm, 1.0)
    u = jnp.where(norm > 0, vector[0:2] / safe, jnp.array([1.0, 0.0], vector.dtype))
    u_perp = jnp.stack([-u[1], u[0]])
    directions = jnp.where((labels == 1)[:, None], u_perp, u)
    ok = ok & all_seen & (norm > 0) & (h_c > h_f) & jnp.any(present)
    return _make_layout(directions, vector[6:] / safe, h_c, h_f, present, ok)


def solve_atlanta_layout(
    ceiling_rays: Float[Array, "W 6"],
    floor_rays: Float[Array, "W 6"],
    wall_index: Int[Array, " W"],
    wall_mask: Bool[Array, " K"],
    directions: Float[Array, "K 2"],
) -> WallLayout:
    """Atlanta layout solver (Section 4.3): ``A (1, h_c, h_f, d_1..d_K) = 0`` for known directions.

    Each ray is first expressed in its wall's frame (:func:`ray_in_wall_frame`);
    eqs. genx/geny are then eq. iter1/iter2 with ``u = (1, 0)``:
    ``xibar'_1 + h_c xi'_2 - d xi'_3 = 0``. The (equilibrated) least-squares
    null vector is scaled so that its first entry is 1.

    Args:
        ceiling_rays: per-column ceiling rays.
        floor_rays: per-column floor rays.
        wall_index: the wall each column sees, -1 for none.
        wall_mask: which of the K walls exist.
        directions: per-wall horizontal directions (any length and sign).

    Returns:
        The :class:`WallLayout`; output directions are the inputs normalised
        and oriented canonically (camera on the left).
    """
    column_used, one_hot, present, all_seen = _column_bookkeeping(wall_index, wall_mask)
    norm = safe_norm(directions)
    units = jnp.where((norm > 0)[:, None], directions / jnp.where(norm > 0, norm, 1.0)[:, None], jnp.array([1.0, 0.0], directions.dtype))
    column_direction = units[jnp.maximum(wall_index, 0)]
    blocks = []
    for height_column, rays in ((0, ceiling_rays), (1, floor_rays)):
        a_u, a_h, a_d = side_coefficients(ray_in_wall_frame(masked_rays(rays, column_used), column_direction))
        heights = jnp.zeros((rays.shape[0], 2), rays.dtype).at[:, height_column].set(a_h[:, 0])
        d_columns, pins = _distance_columns(a_d, one_hot, present)
        blocks.append(jnp.concatenate([a_u[:, :1], heights, d_columns], 1))
    blocks.append(jnp.concatenate([jnp.zeros((pins.shape[0], 3), pins.dtype), pins], 1))
    vector = scaled_null_space(jnp.concatenate(blocks), 1)[:, 0]
    scale_ok = jnp.abs(vector[0]) > 1e3 * jnp.finfo(vector.dtype).eps * safe_norm(vector)
    vector = vector / jnp.where(scale_ok, vector[0], 1.0)
    h_c, h_f = vector[1], vector[2]
    ok = scale_ok & all_seen & (h_c > h_f) & jnp.any(present)
    return _make_layout(units, vector[3:], h_c, h_f, present, ok)


def layout_corners(lines: Float[Array, "K 6"], mask: Bool[Array, " K"]) -> Float[Array, "K 3"]:
    """Corner ``k`` = start of wall ``k`` = meeting point with the previous present wall.

    "Previous" is cyclic over the present walls in index order (for a
    counter-clockwise room with walls in order, corner ``k`` is ``P_k``).
    Uses :func:`ncjax.intersect_coplanar_lines`; masked corners are zero.

    Args:
        lines: ceiling (or floor) lines of the walls, in order.
        mask: which walls are present.
    """
    capacity = mask.shape[0]
    index = jnp.arange(capacity)
    # steps back from k to j, in 1..K (j = k itself counts K: the last resort)
    steps = (index[:, None] - index[None, :] - 1) % capacity + 1
    previous = jnp.argmin(jnp.where(mask[None, :], steps, 2 * capacity), axis=1)
    corners = intersect_coplanar_lines(lines[previous], lines)
    return jnp.where(mask[:, None], corners, 0.0)
