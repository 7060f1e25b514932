"""Single-wall solvers (paper Section 4.1 "Vertical wall extraction"): over-determined (:func:`solve_wall`) and
minimal (:func:`solve_wall_minimal`, for RANSAC). The rows below also serve the single-line baseline
[bermudez2016line] of Section 5.3 (:mod:`ncjax.solvers.horizontal_line`) and a wall at known heights
(:mod:`ncjax.solvers.wall_at_heights`, not in the paper: a height prior's).

A wall (docs/design.md section 3) is the pair of horizontal lines
``L = (ux, uy, 0, -h_c uy, h_c ux, -d)`` (ceiling) and ``M`` (same with the
floor height ``h_f``) in the vertical plane of unit direction ``u`` at signed
distance ``d`` along ``e2 = (-uy, ux, 0)``.

Derivation of the rows (from :func:`ncjax.geometry.side`, tested in
``tests/test_wall.py``): for a ray ``Xi = (xi, xibar)``

    side(Xi, L) = xibar_1 ux + xibar_2 uy + h (xi_2 ux - xi_1 uy) - d xi_3    (eq. iter1)
                = xibar_1 ux + xibar_2 uy + xi_2 vx - xi_1 vy - d xi_3         (eq. manx)

with ``v = h_c u``; the floor row (eq. many) is the same with ``w = h_f u``
and ``+ chibar_2 u_y`` (the paper prints ``-``, a typo).

Canonical orientation. The wall plane fixes ``u`` only up to sign; ncjax picks
the sign that puts the camera axis on the LEFT of the directed wall, i.e.
``d < 0``. For a room given as a counter-clockwise polygon with the camera
inside, wall ``i`` from corner ``P_i`` to ``P_i+1`` then has
``u = (P_i+1 - P_i) / |...|`` and ``d = P_i . e2 < 0`` (e2 points into the room).

Null space. With exact rays from a non-central camera (``rc > 0``) the
matrix of eqs. manx/many has a ONE-dimensional null space (the rays of a
horizontal line also all meet the z axis, whose Plücker vector has no
component among the unknowns). The paper's over-determined solver takes the
two smallest right singular vectors ``W = W0 + lambda W1`` and imposes
``u || v`` and ``u || w`` (eqs. lambda_uv, lambda_uw), which give the two
quadratics quad_v and quad_w. We write them from ``cross(u, v) = 0`` and
``cross(u, w) = 0`` directly (the printed quad_w mixes ``v`` and ``w``; the
printed coefficients of quad_v are another arrangement of the same
condition) and solve them homogeneously in ``(cos t, sin t)`` so that no root
is at infinity.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ..geometry.linalg import divide_if_significant, null_space, scaled_null_space
from ..geometry.plucker import cross_2d as _cross2
from ..geometry.plucker import horizontal_wall_line
from .wall_fit import FitRows, heights_of, linear_walls, refine_walls, yaw_parameters


class Wall(eqx.Module):
    """A vertical wall: two horizontal lines in one vertical plane (paper Fig. wallDef).

    All fields are traced arrays (no static fields); a batch of walls (from
    ``jax.vmap``) carries leading batch dimensions on every field.

    Attributes:
        direction: unit ``u = (ux, uy)``, canonical sign (camera on the left, ``d <= 0``).
        distance: signed distance ``d`` of the plane from the z axis along ``e2 = (-uy, ux)``.
        ceiling_height: ``h_c`` (metres above the plane of optical centres).
        floor_height: ``h_f``.
        ceiling_line: Plücker ``(ux, uy, 0, -h_c uy, h_c ux, -d)``.
        floor_line: Plücker ``(ux, uy, 0, -h_f uy, h_f ux, -d)``.
        ok: False when the solver failed; the other fields are then finite but meaningless.
    """

    direction: Float[Array, "*batch 2"]
    distance: Float[Array, "*batch"]
    ceiling_height: Float[Array, "*batch"]
    floor_height: Float[Array, "*batch"]
    ceiling_line: Float[Array, "*batch 6"]
    floor_line: Float[Array, "*batch 6"]
    ok: Bool[Array, "*batch"]


# --------------------------------------------------------------------------
# Rows (eqs. iter1/iter2, manx/many)
# --------------------------------------------------------------------------


def side_coefficients(
    ray: Float[Array, "*batch 6"],
) -> tuple[Float[Array, "*batch 2"], Float[Array, "*batch 2"], Float[Array, "*batch"]]:
    """Coefficients of ``side(ray, wall line)`` in the wall unknowns (eq. iter1).

    ``side(ray, horizontal_wall_line(u, d, h)) = a_u . u + a_h . (h u) + a_d d``.

    Returns:
        ``(a_u, a_h, a_d) = ((xibar_1, xibar_2), (xi_2, -xi_1), -xi_3)``.
    """
    a_u = ray[..., 3:5]
    a_h = jnp.stack([ray[..., 1], -ray[..., 0]], -1)
    return a_u, a_h, -ray[..., 2]


def wall_rows(
    ceiling_rays: Float[Array, "n 6"], floor_rays: Float[Array, "m 6"]
) -> tuple[Float[Array, "n 7"], Float[Array, "m 7"]]:
    """Rows of eq. manx (ceiling) and eq. many (floor) for ``W = (u, v, w, d)``."""
    a_u, a_h, a_d = side_coefficients(ceiling_rays)
    ceiling = jnp.concatenate([a_u, a_h, jnp.zeros_like(a_h), a_d[:, None]], -1)
    a_u, a_h, a_d = side_coefficients(floor_rays)
    floor = jnp.concatenate([a_u, jnp.zeros_like(a_h), a_h, a_d[:, None]], -1)
    return ceiling, floor


# the finite fields of a wall whose solution is not finite: direction (1, 0), distance 0, heights 0
_NOT_A_WALL = (1.0, 0.0, 0.0, 0.0, 0.0)


def masked_rays(rays: Float[Array, "n 6"], mask: Bool[Array, " n"]) -> Float[Array, "n 6"]:
    """Zero the rows that are masked out (they then add zero rows; NaNs there are harmless)."""
    return jnp.where(mask[:, None], rays, 0.0)


def distinct_azimuths(rays: Float[Array, "n 6"], mask: Bool[Array, " n"], tolerance: float = 1e-6) -> Int[Array, ""]:
    """How many different horizontal directions the used, finite rays have (azimuths ``tolerance`` rad apart).

    A panorama's rays of one column share their azimuth: this counts the columns a line is seen in.
    Copies of one ray, or rays of one column, make a rank-deficient system whose null vector is
    arbitrary, so a solver needs three distinct azimuths per line, not three rows.
    """
    finite = mask & jnp.all(jnp.isfinite(rays), axis=-1)
    ordered = jnp.sort(jnp.where(finite, jnp.arctan2(rays[:, 1], rays[:, 0]), jnp.inf))
    later = jnp.isfinite(ordered[1:]) & (jnp.diff(ordered) > tolerance)
    return jnp.any(finite).astype(jnp.int32) + jnp.sum(later)


# --------------------------------------------------------------------------
# Parallelism constraint (eqs. lambda_uv, lambda_uw, quad_v, quad_w)
# --------------------------------------------------------------------------


def _wrap_half_turn(angle: Array) -> Array:
    """Angle modulo pi, in [-pi/2, pi/2] (``W`` and ``-W`` are the same solution)."""
    return angle - math.pi * jnp.round(angle / math.pi)


def parallel_quadratic(
    a0: Float[Array, 2], a1: Float[Array, 2], b0: Float[Array, 2], b1: Float[Array, 2]
) -> Float[Array, 3]:
    """Quadratic form of ``cross(a, b)`` on ``(a, b) = alpha (a0, b0) + beta (a1, b1)`` (eqs. quad_v, quad_w).

    ``u || v`` (eq. lambda_uv) is ``cross(u, v) = 0``, i.e.
    ``p alpha^2 + r alpha beta + t beta^2 = 0``; the paper divides by
    ``alpha`` (``lambda = beta / alpha``). Use ``b = v`` for quad_v and
    ``b = w`` for quad_w.

    Returns:
        ``(p, r, t)``.
    """
    return jnp.stack([_cross2(a0, b0), _cross2(a0, b1) + _cross2(a1, b0), _cross2(a1, b1)])


def quadratic_root_angles(coefficients: Float[Array, 3]) -> Float[Array, 2]:
    """The two roots of ``p a^2 + r a b + t b^2 = 0`` as angles ``atan2(b, a)`` modulo pi.

    Stable form (no cancellation, no root at infinity): with
    ``q = -(r + sign(r) sqrt(r^2 - 4 p t)) / 2`` the roots are ``(a, b) ~ (q, p)``
    and ``(t, q)``. A negative discriminant (noise) is clamped to zero: the
    double root is the best real approximation.
    """
    p, r, t = coefficients
    discriminant = r * r - 4.0 * p * t
    positive = discriminant > 0
    root = jnp.where(positive, jnp.sqrt(jnp.where(positive, discriminant, 1.0)), 0.0)
    q = -0.5 * (r + jnp.where(r >= 0, 1.0, -1.0) * root)
    a = jnp.stack([q, t])
    b = jnp.stack([p, q])
    degenerate = (a == 0) & (b == 0)
    angles = jnp.arctan2(jnp.where(degenerate, 0.0, b), jnp.where(degenerate, 1.0, a))
    return _wrap_half_turn(angles)


def pair_roots(theta_v: Float[Array, 2], theta_w: Float[Array, 2]) -> Float[Array, 2]:
    """Pair the roots of quad_v with those of quad_w and average each pair (Section 4.1).

    Exact data make one root of each quadratic coincide (the true wall); the
    pairing with the smaller total angular distance is kept and each pair is
    replaced by its angular midpoint.
    """

    def distance(a, b):
        return jnp.sum(jnp.abs(_wrap_half_turn(a - b)))

    straight = distance(theta_v, theta_w) <= distance(theta_v, theta_w[::-1])
    partner = jnp.where(straight, theta_w, theta_w[::-1])
    return theta_v + 0.5 * _wrap_half_turn(partner - theta_v)


def constrained_null_vector(basis: Float[Array, "n 2"]) -> tuple[Float[Array, " n"], Bool[Array, ""]]:
    """The paper's constrained solution in the span of two null vectors (Section 4.1).

    ``W(t) = cos t W0 + sin t W1`` for the roots ``t`` of quad_v and quad_w,
    paired (:func:`pair_roots`); a pair is valid when it gives ``h_c > h_f``
    (the paper's choice) and ``u != 0``; among valid pairs the one nearest the
    least-squares vector ``W0`` (smallest algebraic residual) wins.

    Args:
        basis: columns ``W0, W1`` (``W0`` the least-squares null vector); rows
            ``(ux, uy, vx, vy, wx, wy, ...)``.

    Returns:
        ``(W, ok)``.
    """
    w0, w1 = basis[:, 0], basis[:, 1]
    theta_v = quadratic_root_angles(parallel_quadratic(w0[0:2], w1[0:2], w0[2:4], w1[2:4]))
    theta_w = quadratic_root_angles(parallel_quadratic(w0[0:2], w1[0:2], w0[4:6], w1[4:6]))
    theta = pair_roots(theta_v, theta_w)
    candidates = jnp.cos(theta)[:, None] * w0 + jnp.sin(theta)[:, None] * w1
    norm, h_c, h_f = jax.vmap(heights_of)(candidates)
    valid = (h_c > h_f) & (norm > jnp.finfo(basis.dtype).tiny)
    best = jnp.argmin(jnp.where(valid, jnp.abs(jnp.sin(theta)), jnp.inf))
    return candidates[best], valid[best]


# --------------------------------------------------------------------------
# Walls from solution vectors
# --------------------------------------------------------------------------


def canonical_orientation(
    direction: Float[Array, "*batch 2"], distance: Float[Array, "*batch"]
) -> tuple[Float[Array, "*batch 2"], Float[Array, "*batch"]]:
    """Flip ``(u, d)`` to ``(-u, -d)`` where ``d > 0`` (camera on the left of the wall)."""
    sign = jnp.where(distance > 0, -1.0, 1.0)
    return direction * sign[..., None], distance * sign


def make_wall(
    direction: Float[Array, "*batch 2"],
    distance: Float[Array, "*batch"],
    ceiling_height: Float[Array, "*batch"],
    floor_height: Float[Array, "*batch"],
    ok: Bool[Array, "*batch"],
) -> Wall:
    """A :class:`Wall` in canonical orientation, with its two Plücker lines."""
    direction, distance = canonical_orientation(direction, distance)
    return Wall(
        direction=direction,
        distance=distance,
        ceiling_height=ceiling_height,
        floor_height=floor_height,
        ceiling_line=horizontal_wall_line(direction, distance, ceiling_height),
        floor_line=horizontal_wall_line(direction, distance, floor_height),
        ok=ok,
    )


def unit_direction(u: Array, norm: Array) -> Array:
    """``u / norm``, or ``(1, 0)`` where ``norm`` is 0."""
    return jnp.where(norm > 0, u / jnp.where(norm > 0, norm, 1.0), jnp.array([1.0, 0.0], u.dtype))


# --------------------------------------------------------------------------
# Public solvers
# --------------------------------------------------------------------------


SOLVER_METHODS = ("refined", "paper", "null_vector")


def check_method(method: str, allowed: tuple[str, ...] = SOLVER_METHODS) -> None:
    """ValueError for an unknown ``method`` (a static Python argument)."""
    if method not in allowed:
        raise ValueError(f"method must be one of {allowed}, got {method!r}")


def solve_wall(
    ceiling_rays: Float[Array, "n 6"],
    floor_rays: Float[Array, "m 6"],
    ceiling_mask: Bool[Array, " n"],
    floor_mask: Bool[Array, " m"],
    method: str = "paper",
) -> Wall:
    """One vertical wall from the projecting rays of its ceiling and floor lines (Section 4.1).

    Builds ``A W = 0`` from eqs. manx and many, ``W = (u, v, w, d)``. Methods:

    - ``"paper"`` (default): the paper's two smallest singular vectors of the
      equilibrated ``A`` and the parallelism quadratics quad_v / quad_w
      (:func:`constrained_null_vector`).
    - ``"refined"``: the least-squares null vector (distance eliminated,
      :func:`ncjax.solvers.wall_fit.linear_walls`) gives the yaw of ``u``, ``h_c``,
      ``h_f`` and ``d``; Gauss-Newton on the angular (row) residuals then
      fits the exact 4-dof wall (:func:`ncjax.solvers.wall_fit.refine_walls`), the
      maximum-likelihood wall under row noise.
    - ``"null_vector"``: the unconstrained least-squares null vector ``W0``
      (the ablation of Section 5.3).

    All three are exact on exact rays. For ONE wall under noise the scale is
    only weakly observable (through ``rc``) and the maximum-likelihood fit
    has a heavier tail than the paper's constrained solution, which is the
    best of the three there (experiments/RESULTS.md); for layouts the shared
    heights make "refined" by far the best, see :func:`ncjax.solvers.solve_manhattan_layout`.

    Args:
        ceiling_rays: Plücker rays of the ceiling boundary (fixed capacity).
        floor_rays: Plücker rays of the floor boundary.
        ceiling_mask: which ceiling rays are used (others add zero rows).
        floor_mask: which floor rays are used.
        method: static, see above.

    Returns:
        The :class:`Wall` (canonical orientation); ``ok`` is False when a line has
        rays in fewer than 3 distinct azimuths (:func:`distinct_azimuths`: copies of
        one ray, or one column, fix no wall), when the solution is not finite, or
        when it does not put the camera between ceiling and floor (``h_c > 0 > h_f``).
        A wall that is not ok has finite fields of no meaning.
    """
    check_method(method)
    ceiling, floor = wall_rows(masked_rays(ceiling_rays, ceiling_mask), masked_rays(floor_rays, floor_mask))
    rows = jnp.concatenate([ceiling, floor])
    if method == "refined":
        row_wall = jnp.where(jnp.concatenate([ceiling_mask, floor_mask]), 0, -1)
        x, d = linear_walls(rows[:, :6], rows[:, 6], row_wall, 1)
        params, ok = yaw_parameters(jnp.concatenate([x, d]))
        rays = jnp.concatenate([ceiling_rays, floor_rays])
        is_floor = jnp.arange(rays.shape[0]) >= ceiling_rays.shape[0]
        base = jnp.broadcast_to(jnp.array([1.0, 0.0], rays.dtype), (rays.shape[0], 2))
        params = refine_walls(params, FitRows(rays, base, row_wall, is_floor), refine_yaw=True)
        yaw, h_c, h_f, distance = params
        direction = jnp.stack([jnp.cos(yaw), jnp.sin(yaw)])
        ok = ok & jnp.all(jnp.isfinite(params))
    else:
        basis = scaled_null_space(rows, 2)
        if method == "paper":
            vector, ok = constrained_null_vector(basis)
        else:
            vector, ok = basis[:, 0], jnp.array(True)
        norm, h_c, h_f = heights_of(vector)
        ok = ok & (norm > 0)
        distance = vector[6] / jnp.where(norm > 0, norm, 1.0)
        direction = unit_direction(vector[0:2], norm)
    # the paper's over-determined case: 3 rays per line, from 3 different columns
    enough = (distinct_azimuths(ceiling_rays, ceiling_mask) >= 3) & (distinct_azimuths(floor_rays, floor_mask) >= 3)
    finite = jnp.all(jnp.isfinite(direction)) & jnp.isfinite(distance) & jnp.isfinite(h_c) & jnp.isfinite(h_f)
    ok = ok & enough & finite & (h_c > 0) & (h_f < 0)
    fields = jnp.where(finite, jnp.concatenate([direction, jnp.stack([distance, h_c, h_f])]), jnp.asarray(_NOT_A_WALL))
    return make_wall(fields[:2], fields[2], fields[3], fields[4], ok)


# --------------------------------------------------------------------------
# Minimal solver (2 + 2 rays)
# --------------------------------------------------------------------------


def _known_direction_matrix(
    ceiling_rays: Float[Array, "2 6"], floor_rays: Float[Array, "2 6"], direction: Float[Array, 2]
) -> Float[Array, "4 4"]:
    """Rows of eqs. iter1/iter2 in ``(1, h_c, h_f, d)`` for a KNOWN direction ``u``."""

    def rows(rays, column):
        a_u, a_h, a_d = side_coefficients(rays)
        heights = jnp.zeros((rays.shape[0], 2), rays.dtype).at[:, column].set(a_h @ direction)
        return jnp.concatenate([(a_u @ direction)[:, None], heights, a_d[:, None]], -1)

    return jnp.concatenate([rows(ceiling_rays, 0), rows(floor_rays, 1)])


def _real_cubic_roots(coefficients: Float[Array, 4]) -> tuple[Float[Array, 3], Bool[Array, 3]]:
    """Real roots of ``c3 t^3 + c2 t^2 + c1 t + c0`` (``c3 != 0``), closed form.

    Returns the three roots (Viète's trigonometric form) when all are real,
    else the one real root (Cardano) in slot 0; the mask says which are real.
    """
    c3, c2, c1, c0 = coefficients
    a, b, c = c2 / c3, c1 / c3, c0 / c3
    p = b - a * a / 3.0
    q = 2.0 * a**3 / 27.0 - a * b / 3.0 + c
    discriminant = (q / 2.0) ** 2 + (p / 3.0) ** 3
    one_real = discriminant > 0
    root = jnp.sqrt(jnp.where(one_real, discriminant, 0.0))
    cardano = jnp.cbrt(-q / 2.0 + root) + jnp.cbrt(-q / 2.0 - root)
    radius = jnp.sqrt(jnp.maximum(-p / 3.0, 0.0))
    cosine = jnp.clip((-q / 2.0) / jnp.where(radius > 0, radius**3, 1.0), -1.0, 1.0)
    phase = jnp.arccos(cosine) / 3.0
    viete = 2.0 * radius * jnp.cos(phase - 2.0 * math.pi * jnp.arange(3) / 3.0)
    roots = jnp.where(one_real, jnp.stack([cardano, cardano, cardano]), viete) - a / 3.0
    return roots, jnp.stack([jnp.array(True), ~one_real, ~one_real])


def solve_wall_minimal(
    ceiling_rays: Float[Array, "2 6"], floor_rays: Float[Array, "2 6"]
) -> tuple[Wall, Bool[Array, 3]]:
    """Minimal wall solver: 2 ceiling + 2 floor rays (Section 4.1, for RANSAC).

    The 4 rows of eqs. manx/many leave a 3-dimensional null space
    ``W0 + l1 W1 + l2 W2``; quad_v and quad_w are two conics in ``(l1, l2)``
    with 4 intersections (Bezout), as the paper says. One of them is ALWAYS
    the point where ``u = 0`` (both ``cross(u, v)`` and ``cross(u, w)``
    vanish there), which is no wall. The others are found without the conics:
    for a fixed direction ``u = (cos t, sin t)`` the rows are linear in
    ``(1, h_c, h_f, d)`` (eqs. iter1/iter2), a 4 x 4 matrix ``M(t)``, and a
    wall exists iff ``det M(t) = 0`` -- a homogeneous cubic in
    ``(cos t, sin t)``, so at most 3 walls. The cubic is interpolated exactly
    from 4 evaluations in a frame where its leading coefficient is the
    largest of 4 probes, solved in closed form, and each root's wall is the
    null vector of ``M(t)``.

    Args:
        ceiling_rays: two ceiling rays.
        floor_rays: two floor rays.

    Returns:
        ``(walls, valid)``: a :class:`Wall` batched over the 3 candidates, and
        which of them are real solutions with ``h_c > h_f``.
    """

    def det(direction):
        return jnp.linalg.det(_known_direction_matrix(ceiling_rays, floor_rays, direction))

    # Frame: t -> u = e(theta0) + t e(theta0 + pi/2); det is a cubic in t whose
    # leading coefficient is det at e(theta0 + pi/2) -- pick the largest.
    probes = math.pi / 4 * jnp.arange(4, dtype=ceiling_rays.dtype)

    def unit(angle):
        return jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)

    theta0 = probes[jnp.argmax(jnp.abs(jax.vmap(det)(unit(probes + math.pi / 2))))]
    samples = jnp.array([-1.0, 0.0, 1.0, 2.0], ceiling_rays.dtype)
    values = jax.vmap(lambda t: det(unit(theta0) + t * unit(theta0 + math.pi / 2)))(samples)
    vandermonde = samples[:, None] ** jnp.arange(3, -1, -1, dtype=samples.dtype)[None, :]
    roots, real = _real_cubic_roots(jnp.linalg.solve(vandermonde, values))
    theta = theta0 + jnp.arctan(roots)

    def wall_at(angle):
        direction = unit(angle)
        vector = null_space(_known_direction_matrix(ceiling_rays, floor_rays, direction), 1)[:, 0]
        (_, h_c, h_f, distance), scale_ok = divide_if_significant(vector, vector[0], 1.0)  # a unit null vector
        return make_wall(direction, distance, h_c, h_f, scale_ok & (h_c > h_f))

    walls = jax.vmap(wall_at)(theta)
    valid = real & walls.ok
    return eqx.tree_at(lambda w: w.ok, walls, valid), valid
