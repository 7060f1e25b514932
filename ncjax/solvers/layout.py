"""Joint layout solvers (paper Sections 4.2 "Manhattan layout solver" and 4.3
"Atlanta layout solver").

Inputs are per image column: the ceiling and floor Plücker rays (W, 6), the
index of the wall the column sees (W,) int (-1: none), and per wall (fixed
capacity K, docs/design.md section 4) a mask plus either a Manhattan label or a
known direction. The default ("refined") solvers share
:mod:`ncjax.solvers.wall_fit` with the single-wall solver (linear solve with the
distances eliminated, then the maximum-likelihood fit); the paper's literal
matrices (``method="paper"``) get a pinning row ``d_k = 0`` per masked-out
wall so that the null space stays the one of the present walls. A wall in the
mask that no column sees makes ``ok`` False.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..geometry.linalg import divide_if_significant, scaled_null_space
from ..geometry.plucker import cross_2d, horizontal_wall_line, intersect_coplanar_lines, safe_norm
from .wall import (
    canonical_orientation,
    check_method,
    constrained_null_vector,
    masked_rays,
    side_coefficients,
    wall_rows,
)
from .wall_fit import FitRows, heights_of, linear_walls, refine_walls, search_scale, yaw_parameters


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


# camera heights above the floor (m) at which the "refined" Atlanta solver tries the room's shape
# (:func:`ncjax.solvers.wall_fit.search_scale`): a bracket for the search, not a prior (the cost decides)
FLOOR_DEPTHS = tuple(float(x) for x in np.geomspace(0.2, 20.0, 33))


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
    """``(column_used (W,), column_wall (W,), present (K,), all_seen ())``; ``column_wall`` is -1 where unused."""
    capacity = wall_mask.shape[0]
    column_used = (wall_index >= 0) & (wall_index < capacity) & wall_mask[jnp.clip(wall_index, 0, capacity - 1)]
    column_wall = jnp.where(column_used, wall_index, -1)
    seen = (
        jax.ops.segment_sum(column_used.astype(jnp.int32), jnp.where(column_used, wall_index, capacity), capacity + 1)[
            :capacity
        ]
        > 0
    )
    present = wall_mask & seen
    return column_used, column_wall, present, jnp.all(seen | ~wall_mask)


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
        return jnp.concatenate(
            [ux * x[..., 0:1] + uy * x[..., 1:2], ux * x[..., 1:2] - uy * x[..., 0:1], x[..., 2:3]], -1
        )

    return jnp.concatenate([rotate(ray[..., :3]), rotate(ray[..., 3:])], -1)


def _manhattan_matrix(ceiling_rays, floor_rays, column_used, turned):
    """Rows of eqs. manx/many (label 0) and manPx/manPy (label 1): ``(shared (2W, 6), distance (2W,))``."""
    rows = [
        jnp.where(turned[:, None], quarter_turn(r), r)
        for r in (masked_rays(ceiling_rays, column_used), masked_rays(floor_rays, column_used))
    ]
    a = jnp.concatenate(wall_rows(*rows))
    return a[:, :6], a[:, 6]


def _full_matrix(shared, distance, row_wall, present):
    """``[shared | d_k columns]`` plus a pinning row ``d_k = 0`` per absent wall (the paper's literal ``A``)."""
    columns = distance[:, None] * jax.nn.one_hot(row_wall, present.shape[0], dtype=distance.dtype)  # -1: a zero row
    pins = jnp.diag(jnp.where(present, 0.0, 1.0).astype(distance.dtype))
    return jnp.concatenate(
        [
            jnp.concatenate([shared, columns], 1),
            jnp.concatenate([jnp.zeros((pins.shape[0], shared.shape[1]), pins.dtype), pins], 1),
        ]
    )


def _stacked(ceiling, floor):
    return jnp.concatenate([ceiling, floor])


def solve_manhattan_layout(
    ceiling_rays: Float[Array, "W 6"],
    floor_rays: Float[Array, "W 6"],
    wall_index: Int[Array, " W"],
    wall_mask: Bool[Array, " K"],
    labels: Int[Array, " K"],
    method: str = "refined",
) -> WallLayout:
    """Manhattan layout solver (Section 4.2): ``A (u, v, w, d_1..d_K) = 0``.

    Walls labelled 0 have direction ``u`` and contribute eqs. manx/many;
    walls labelled 1 have ``u_perp = (-uy, ux)`` and contribute
    eqs. manPx/manPy (the same rows for the ray turned by -90 degrees,
    :func:`quarter_turn`); any yaw of the room is fine. Methods as for
    :func:`ncjax.solvers.solve_wall`: ``"refined"`` (default; the linear solution
    with the distances eliminated, then the maximum-likelihood fit of the yaw,
    ``h_c``, ``h_f`` and all ``d_k``), ``"paper"`` (two smallest singular
    vectors of the equilibrated ``A`` and the parallelism quadratics) or
    ``"null_vector"`` (the least-squares null vector alone).

    Args:
        ceiling_rays: per-column ceiling rays.
        floor_rays: per-column floor rays.
        wall_index: the wall each column sees, -1 for none.
        wall_mask: which of the K walls exist.
        labels: per wall, 0 for ``u`` and 1 for ``u_perp``.
        method: static, see above.

    Returns:
        The :class:`WallLayout` (canonical orientation per wall).
    """
    check_method(method)
    column_used, column_wall, present, all_seen = _column_bookkeeping(wall_index, wall_mask)
    turned = labels[jnp.maximum(wall_index, 0)] == 1
    shared, distance = _manhattan_matrix(ceiling_rays, floor_rays, column_used, turned)
    row_wall = _stacked(column_wall, column_wall)
    if method == "refined":
        x, d = linear_walls(shared, distance, row_wall, wall_mask.shape[0])
        params, ok = yaw_parameters(jnp.concatenate([x, d]))
        base = jnp.where(turned[:, None], jnp.array([0.0, 1.0], shared.dtype), jnp.array([1.0, 0.0], shared.dtype))
        is_floor = jnp.arange(2 * ceiling_rays.shape[0]) >= ceiling_rays.shape[0]
        rows = FitRows(_stacked(ceiling_rays, floor_rays), _stacked(base, base), row_wall, is_floor)
        params = refine_walls(params, rows, refine_yaw=True)
        u = jnp.stack([jnp.cos(params[0]), jnp.sin(params[0])])
        h_c, h_f, distances = params[1], params[2], params[3:]
        ok = ok & jnp.all(jnp.isfinite(params))
    else:
        basis = scaled_null_space(_full_matrix(shared, distance, row_wall, present), 2)
        if method == "paper":
            vector, ok = constrained_null_vector(basis)
        else:
            vector, ok = basis[:, 0], jnp.array(True)
        norm, h_c, h_f = heights_of(vector)
        safe = jnp.where(norm > 0, norm, 1.0)
        u = jnp.where(norm > 0, vector[0:2] / safe, jnp.array([1.0, 0.0], vector.dtype))
        distances = vector[6:] / safe
        ok = ok & (norm > 0)
    u_perp = jnp.stack([-u[1], u[0]])
    directions = jnp.where((labels == 1)[:, None], u_perp, u)
    ok = ok & all_seen & (h_c > h_f) & jnp.any(present)
    return _make_layout(directions, jnp.where(present, distances, 0.0), h_c, h_f, present, ok)


def solve_atlanta_layout(
    ceiling_rays: Float[Array, "W 6"],
    floor_rays: Float[Array, "W 6"],
    wall_index: Int[Array, " W"],
    wall_mask: Bool[Array, " K"],
    directions: Float[Array, "K 2"],
    method: str = "refined",
    boundary_weights: Float[Array, " 2"] | None = None,
) -> WallLayout:
    """Atlanta layout solver (Section 4.3): ``A (1, h_c, h_f, d_1..d_K) = 0`` for known directions.

    Each ray is first expressed in its wall's frame (:func:`ray_in_wall_frame`);
    eqs. genx/geny are then eq. iter1/iter2 with ``u = (1, 0)``:
    ``xibar'_1 + h_c xi'_2 - d xi'_3 = 0``. Methods: ``"paper"``: the
    (equilibrated) least-squares null vector of ``A``, scaled so that its
    first entry is 1; ``"refined"`` (default): the same linear solution (with
    the distances eliminated in closed form), its scale chosen by the
    likelihood when the linear one is unreliable under noise
    (:func:`ncjax.solvers.wall_fit.search_scale`), then the maximum-likelihood fit
    of ``h_c``, ``h_f`` and the ``d_k`` (directions stay the given ones).

    Args:
        ceiling_rays: per-column ceiling rays.
        floor_rays: per-column floor rays.
        wall_index: the wall each column sees, -1 for none.
        wall_mask: which of the K walls exist.
        directions: per-wall horizontal directions (any length and sign).
        method: static, "refined" or "paper".
        boundary_weights: "refined" only: factors of the ceiling and of the floor
            rows (default 1 and 1), e.g. :func:`ncjax.pipeline.adjust.boundary_weights`: a
            noisier boundary weighted alike can carry the weakly observed metric
            scale away with it.

    Returns:
        The :class:`WallLayout`; output directions are the inputs normalised
        and oriented canonically (camera on the left).
    """
    check_method(method, ("refined", "paper"))
    if boundary_weights is not None and method != "refined":
        raise ValueError(f"boundary_weights need method='refined', got {method!r}")
    column_used, column_wall, present, all_seen = _column_bookkeeping(wall_index, wall_mask)
    norm = safe_norm(directions)
    units = jnp.where(
        (norm > 0)[:, None],
        directions / jnp.where(norm > 0, norm, 1.0)[:, None],
        jnp.array([1.0, 0.0], directions.dtype),
    )
    column_direction = units[jnp.maximum(wall_index, 0)]
    blocks, distance = [], []
    for height_column, rays in ((0, ceiling_rays), (1, floor_rays)):
        a_u, a_h, a_d = side_coefficients(ray_in_wall_frame(masked_rays(rays, column_used), column_direction))
        heights = jnp.zeros((rays.shape[0], 2), rays.dtype).at[:, height_column].set(a_h[:, 0])
        blocks.append(jnp.concatenate([a_u[:, :1], heights], 1))
        distance.append(a_d)
    shared, distance = jnp.concatenate(blocks), jnp.concatenate(distance)
    row_wall = _stacked(column_wall, column_wall)
    if method == "refined":
        is_floor = jnp.arange(2 * ceiling_rays.shape[0]) >= ceiling_rays.shape[0]
        row_weights = (
            None if boundary_weights is None else jnp.where(is_floor, boundary_weights[1], boundary_weights[0])
        )
        x, d = linear_walls(shared, distance, row_wall, wall_mask.shape[0], row_weights)
        rows = FitRows(
            _stacked(ceiling_rays, floor_rays),
            _stacked(column_direction, column_direction),
            row_wall,
            is_floor,
            row_weights,
        )
        params, scale_ok = search_scale(jnp.concatenate([x, d]), rows, jnp.asarray(FLOOR_DEPTHS, x.dtype))
        params = refine_walls(params, rows, refine_yaw=False)
        vector = params.at[0].set(1.0)
        scale_ok = scale_ok & jnp.all(jnp.isfinite(params))
    else:
        vector = scaled_null_space(_full_matrix(shared, distance, row_wall, present), 1)[:, 0]
        vector, scale_ok = divide_if_significant(vector, vector[0], safe_norm(vector))
    h_c, h_f = vector[1], vector[2]
    ok = scale_ok & all_seen & (h_c > h_f) & jnp.any(present)
    return _make_layout(units, jnp.where(present, vector[3:], 0.0), h_c, h_f, present, ok)


def layout_corners(
    lines: Float[Array, "K 6"], mask: Bool[Array, " K"], return_valid: bool = False
) -> Float[Array, "K 3"] | tuple[Float[Array, "K 3"], Bool[Array, " K"]]:
    """Corner ``k`` = start of wall ``k`` = meeting point with the previous present wall.

    "Previous" is cyclic over the present walls in index order (for a
    counter-clockwise room with walls in order, corner ``k`` is ``P_k``).
    Uses :func:`ncjax.geometry.intersect_coplanar_lines`. Two consecutive walls that
    are parallel (within ``sqrt(eps)`` radians; also a wall alone) have no
    corner: it is zero and invalid, never inf or NaN. Masked corners are
    zero and invalid.

    Args:
        lines: ceiling (or floor) lines of the walls, in order.
        mask: which walls are present.
        return_valid: static; also return which corners are valid.

    Returns:
        The corners (K, 3), and with ``return_valid`` the validity mask (K,).
    """
    capacity = mask.shape[0]
    index = jnp.arange(capacity)
    # steps back from k to j, in 1..K (j = k itself counts K: the last resort)
    steps = (index[:, None] - index[None, :] - 1) % capacity + 1
    previous = lines[jnp.argmin(jnp.where(mask[None, :], steps, 2 * capacity), axis=1)]
    sine = cross_2d(previous[:, :2], lines[:, :2]) / jnp.maximum(
        safe_norm(previous[:, :2]) * safe_norm(lines[:, :2]), jnp.finfo(lines.dtype).tiny
    )
    valid = mask & (jnp.abs(sine) > jnp.sqrt(jnp.finfo(lines.dtype).eps))
    # parallel pairs get a harmless perpendicular stand-in (double where: finite values and gradients)
    stand_in = jnp.concatenate(
        [jnp.stack([-lines[:, 1], lines[:, 0], lines[:, 2]], -1), jnp.zeros_like(lines[:, 3:])], -1
    )
    corners = intersect_coplanar_lines(jnp.where(valid[:, None], previous, stand_in), lines)
    corners = jnp.where(valid[:, None], corners, 0.0)
    return (corners, valid) if return_valid else corners
