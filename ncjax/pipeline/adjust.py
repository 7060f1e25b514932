"""Final least-squares adjustment of the layout (paper Section 4.4, last step).

Minimises, over the wall directions, distances and the two heights,

* the reprojection error of the boundary pixels: per used column, the row of
  its wall's ceiling (floor) line minus the observed row, in pixels
  (:func:`ncjax.geometry.reprojection.boundary_rows_along`), times the boundary's weight
  (:func:`boundary_weights`: the paper weights both boundaries alike, which lets
  a network's noisier floor rows set the scale), and
* a soft penalty on corners leaving the vertical planes of their corner rays:
  all rays of one panorama column lie in the vertical half-plane of its
  azimuth, so the penalty is the corner's column minus the detected corner
  column, in pixels, times ``corner_weight``. This is what pins walls that
  no column sees (those inserted for occlusions).

Solved with ``optimistix.least_squares`` (``optx.Dogleg``, ``throw=False``,
at most ``AdjustmentConfig.steps`` iterations) and differentiable
through the implicit-function theorem (optimistix's default ``ImplicitAdjoint``).
Dogleg rather than ``optx.LevenbergMarquardt``: same tests and accuracy checks, about
twice as fast here (its Newton and Cauchy steps are computed once per accepted point,
Levenberg-Marquardt solves again for every damping). Its Newton step solves the normal
equations by Cholesky with :class:`ncjax.pipeline.normal_solver.SparseNormalCholesky`: every
residual depends on at most four parameters (:func:`jacobian_structure`), so the
Jacobian is probed with 8 forward passes instead of one per
parameter, and ``J^T J`` is summed per wall instead of multiplied out (the same steps;
4.5 times less time for the Atlanta adjustment, experiments/RESULTS.md). Each column's
residuals carry a JVP through their local Jacobian (:func:`_local_jacobian_jvp`).
The residuals are evaluated per column (:func:`boundary_residuals`) and per
corner (:func:`corner_residual`) from the wall angles: each wall's direction is
computed once per evaluation, each column's once per solve. Gauge: none while
``rc > 0`` (scale is observable, the heights and distances are absolute); the
Manhattan parametrisation has one yaw for all walls, the Atlanta one an angle per wall (both in one
pytree, :class:`LayoutProblem`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry.camera import NonCentralPanorama, angles_to_pixel
from ..geometry.fastmath import arctan2
from ..geometry.plucker import wall_planes_meet
from ..geometry.polygon import previous_in_loop
from ..geometry.reprojection import boundary_rows_along, column_directions
from .config import AdjustmentConfig
from .sparse_normal import JacobianStructure, distinct_slots
from .types import Walls


class BoundaryObservations(eqx.Module):
    """The data the final adjustment fits (all fields traced; ``N`` columns, ``K`` wall slots).

    Attributes:
        columns: the panorama column of each observation (N,): all ``W`` of
            them, or every ``s``-th (``AdjustmentConfig.stride``).
        ceiling_v: observed ceiling rows per column (N,).
        floor_v: observed floor rows per column (N,).
        ceiling_used: columns whose ceiling row enters the fit (RANSAC inliers).
        floor_used: columns whose floor row enters the fit.
        column_wall: the wall (slot) each column sees, -1 for none.
        corner_columns: per wall slot, the detected column of its start corner.
        corner_used: whether that corner is penalised (it is seen in the image).
        wall_mask: which slots hold walls; they are the first ``M`` slots.
        row_weights: (2,) factors of the ceiling and of the floor rows' residuals in the
            fit, the squared inverse of each boundary's noise relative to the less noisy
            one (:func:`boundary_weights`; default 1 and 1).
    """

    columns: Int[Array, " N"]
    ceiling_v: Float[Array, " N"]
    floor_v: Float[Array, " N"]
    ceiling_used: Bool[Array, " N"]
    floor_used: Bool[Array, " N"]
    column_wall: Int[Array, " N"]
    corner_columns: Float[Array, " K"]
    corner_used: Bool[Array, " K"]
    wall_mask: Bool[Array, " K"]
    row_weights: Float[Array, " 2"] = eqx.field(default_factory=lambda: jnp.ones(2))


def boundary_weights(
    ceiling_error: Float[Array, " N"],
    floor_error: Float[Array, " N"],
    ceiling_used: Bool[Array, " N"],
    floor_used: Bool[Array, " N"],
    min_noise: Float[ArrayLike, ""],
) -> Float[Array, " 2"]:
    """Weights of the ceiling and floor rows' residuals when one boundary is noisier than the other.

    Each boundary's noise ``sigma`` is the mean absolute error of its used rows
    times sqrt(pi / 2) (the standard deviation of Gaussian errors), at least
    ``min_noise`` pixels (exact rows: equal weights). The less noisy boundary gets
    weight 1 and the other ``(sigma_min / sigma)^2``; the residuals are multiplied
    by the weights, so the least-squares cost weights the squared errors by
    ``(sigma_min / sigma)^4``. A network's floor rows, which furniture hides, are
    several times noisier than its ceiling rows; weighted equally, they dominate
    the fit of the heights and with them the metric scale. The square, not white
    noise's ``sigma_min / sigma``: the floor's errors run correlated over whole
    pieces of furniture, so its rows carry less information than their count
    suggests. On our tuning renders the square gave lower corner errors than the
    plain ratio (mean CE without occlusion: Manhattan 0.165 -> 0.164 m, Atlanta
    0.209 -> 0.178 m; experiments/RESULTS.md).
    A boundary with no used row gets weight 1 (it has no residual to weight)
    and does not count as the less noisy one.
    """

    def noise(error, used):
        count = jnp.sum(used)
        mean_abs = jnp.sum(jnp.where(used, jnp.abs(error), 0.0)) / jnp.maximum(count, 1)
        return jnp.where(count > 0, jnp.maximum(math.sqrt(math.pi / 2) * mean_abs, min_noise), jnp.inf)

    sigma = jnp.stack([noise(ceiling_error, ceiling_used), noise(floor_error, floor_used)])
    least = jnp.min(sigma)
    return jnp.where(jnp.isfinite(sigma), (least / jnp.where(jnp.isfinite(sigma), sigma, 1.0)) ** 2, 1.0)


def loop_corners(
    directions: Float[Array, "K 2"], distances: Float[Array, " K"], wall_mask: Bool[Array, " K"]
) -> tuple[Float[Array, "K 2"], Bool[Array, " K"]]:
    """Corner ``k`` (start of wall ``k``) where wall ``k - 1`` meets wall ``k``, in the plane.

    Returns:
        ``(points, ok)``; ``ok`` is False for present walls parallel to their predecessor.
    """
    previous = previous_in_loop(wall_mask)
    points, ok = wall_planes_meet(directions[previous], distances[previous], directions, distances)
    return points, ok | ~wall_mask


def wrap_columns(offset: Float[Array, "*batch"], width: int) -> Float[Array, "*batch"]:
    """A column difference wrapped to ``[-W/2, W/2)``."""
    return (offset + width / 2) % width - width / 2


def _local_jacobian_jvp(fn, num_parameters: int):
    """``fn`` (scalar-in, small-out) whose JVP uses its Jacobian in the first ``num_parameters`` arguments.

    The Jacobian (``num_parameters`` forward passes) is evaluated with the
    primal, so a linearisation pushes each tangent through a few
    multiply-adds instead of the whole function: the least-squares solver
    materialises the Jacobian of ``2 W`` such residuals against every
    parameter of the layout, and most of those tangents are zero for any
    one column. The other arguments keep their ordinary JVP (the implicit
    adjoint differentiates the solution with respect to the observations).
    """

    @jax.custom_jvp
    def wrapped(*args):
        return fn(*args)

    @wrapped.defjvp
    def jvp(primals, tangents):
        parameters, rest = primals[:num_parameters], primals[num_parameters:]
        jacobian = jax.jacfwd(lambda *p: fn(*p, *rest), argnums=tuple(range(num_parameters)))(*parameters)
        _, rest_tangent = jax.jvp(lambda *r: fn(*parameters, *r), rest, tangents[num_parameters:])
        parameter_tangent = sum(
            jnp.tensordot(j, t, axes=jnp.ndim(t)) for j, t in zip(jacobian, tangents[:num_parameters], strict=True)
        )
        return fn(*primals), parameter_tangent + rest_tangent

    return wrapped


def boundary_residuals(
    direction: Float[ArrayLike, " 2"],
    distance: Float[ArrayLike, ""],
    ceiling_height: Float[ArrayLike, ""],
    floor_height: Float[ArrayLike, ""],
    cam: NonCentralPanorama,
    column: tuple[Float[ArrayLike, " 2"], Float[ArrayLike, ""], Float[ArrayLike, ""]],
) -> Float[Array, " 2"]:
    """Ceiling and floor row errors (pixels) of one ``column`` on its wall: the column's
    :func:`column_directions` and its observed ceiling and floor rows."""
    column_direction, ceiling_v, floor_v = column
    ceiling, floor, _ = boundary_rows_along(cam, direction, distance, ceiling_height, floor_height, column_direction)
    return jnp.stack([ceiling - ceiling_v, floor - floor_v])


_boundary_residuals_fast_jvp = _local_jacobian_jvp(boundary_residuals, 4)


def corner_column_offset(
    directions: Float[Array, "2 2"],
    distances: Float[Array, " 2"],
    cam: NonCentralPanorama,
    corner_column: Float[ArrayLike, ""],
) -> tuple[Float[Array, ""], Bool[Array, ""]]:
    """Column error (pixels) of the corner where wall ``(directions[0], distances[0])`` meets the next
    wall, and whether the two meet (not parallel)."""
    point, meet = wall_planes_meet(directions[0], distances[0], directions[1], distances[1])
    corner_u, _ = angles_to_pixel(cam, arctan2(point[1], point[0]), 0.0)
    return wrap_columns(corner_u - corner_column, cam.width), meet


def corner_residual(
    angles: Float[Array, " 2"],
    distances: Float[Array, " 2"],
    cam: NonCentralPanorama,
    corner_column: Float[ArrayLike, ""],
) -> Float[Array, ""]:
    """:func:`corner_column_offset` of two walls given by their angles."""
    directions = jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)
    return corner_column_offset(directions, distances, cam, corner_column)[0]


def _residual_terms(
    angles: Float[Array, " K"],
    distances: Float[Array, " K"],
    heights: tuple[Float[ArrayLike, ""], Float[ArrayLike, ""]],
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
    observed_directions: Float[Array, "N 2"],
) -> tuple[Float[Array, "N 2"], Float[Array, " K"]]:
    """Unweighted, unmasked row errors per column and column errors per corner (wall ``k`` at ``angles[k]``,
    the ceiling and floor at ``heights``).

    ``observed_directions`` are the :func:`column_directions` of the observed
    columns: the solvers evaluate the residuals many times, so they pass them in.
    """
    wall = jnp.maximum(observations.column_wall, 0)
    directions = jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)
    rows = jax.vmap(_boundary_residuals_fast_jvp, in_axes=(0, 0, None, None, None, 0))(
        directions[wall],
        distances[wall],
        *heights,
        cam,
        (observed_directions, observations.ceiling_v, observations.floor_v),
    )
    previous = previous_in_loop(observations.wall_mask)
    corners = jax.vmap(corner_residual, in_axes=(0, 0, None, 0))(
        jnp.stack([angles[previous], angles], -1),
        jnp.stack([distances[previous], distances], -1),
        cam,
        observations.corner_columns,
    )
    return rows, corners


def used_rows(observations: BoundaryObservations) -> Bool[Array, "2 N"]:
    """Which ceiling (first) and floor rows the fit uses: a column that sees no wall never is."""
    return jnp.stack([observations.ceiling_used, observations.floor_used]) & (observations.column_wall >= 0)[None, :]


def _fitted_residuals(
    rows: Float[Array, "N 2"],
    corners: Float[Array, " K"],
    observations: BoundaryObservations,
    corner_weight: Float[ArrayLike, ""],
) -> Float[Array, " residuals"]:
    """The ``2 N + K`` residuals of the fit: ceiling rows, floor rows, weighted corners; 0 where unused."""
    rows = jnp.where(used_rows(observations).T, rows, 0.0)
    corners = jnp.where(observations.corner_used & observations.wall_mask, corner_weight * corners, 0.0)
    return jnp.concatenate([rows[:, 0], rows[:, 1], corners])


def layout_residuals(
    walls: Walls, cam: NonCentralPanorama, observations: BoundaryObservations, corner_weight: Float[ArrayLike, ""]
) -> Float[Array, " residuals"]:
    """Row errors of the ceiling and floor boundaries of ``walls`` and weighted corner column errors (pixels).

    Returns:
        ``2 N + K`` residuals: the ``N`` ceiling rows, the ``N`` floor rows, the corners; 0 where unused.
    """
    angles = jnp.arctan2(walls.directions[:, 1], walls.directions[:, 0])
    heights = (walls.ceiling_height, walls.floor_height)
    rows, corners = _residual_terms(
        angles, walls.distances, heights, cam, observations, observation_directions(cam, observations)
    )
    return _fitted_residuals(rows, corners, observations, corner_weight)


def observation_directions(cam: NonCentralPanorama, observations: BoundaryObservations) -> Float[Array, "N 2"]:
    return column_directions(cam, observations.columns.astype(observations.ceiling_v.dtype))


def manhattan_directions(yaw: Float[Array, ""], labels: Int[Array, " K"]) -> Float[Array, "K 2"]:
    """Unit directions ``yaw + label * pi / 2``."""
    angle = yaw + labels * (math.pi / 2)
    return jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)


def manhattan_yaw(
    directions: Float[Array, "K 2"], labels: Int[Array, " K"], wall_mask: Bool[Array, " K"]
) -> Float[Array, ""]:
    """The yaw (modulo pi) that best fits directions labelled ``u`` (0) and ``u_perp`` (1)."""
    angle = jnp.arctan2(directions[:, 1], directions[:, 0]) - labels * (math.pi / 2)
    weight = wall_mask.astype(directions.dtype)
    return 0.5 * jnp.arctan2(jnp.sum(weight * jnp.sin(2 * angle)), jnp.sum(weight * jnp.cos(2 * angle)))


class LayoutProblem(eqx.Module):
    """The adjustment's parametrisation of a layout (internal).

    ``y = (angles, distances, (h_c, h_f))`` with ``K`` angle slots: wall ``k`` is at
    ``angles[angle_index[k]] + offsets[k]``, its own angle (Atlanta) or the one yaw of all walls plus its
    label's quarter turns (Manhattan: every wall at slot 0). The Manhattan and Atlanta problems of one
    capacity are one pytree, so the two branches' adjustments can run as one batch. ``start`` is the
    parameter point of the walls it was built from; ``angle_used`` marks the slots some wall is at (the
    others are pinned to the start). All fields traced.
    """

    start: tuple[Array, Array, Array]
    offsets: Float[Array, " K"]
    angle_index: Int[Array, " K"]
    angle_used: Bool[Array, " K"]

    def walls(self, y) -> Walls:
        """The walls and heights at the parameters ``y``."""
        angles = y[0][self.angle_index] + self.offsets
        return Walls(jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1), y[1], y[2][0], y[2][1])


# the label of a wall with its own angle (an Atlanta layout's labels)
FREE_ANGLE = -1


def is_manhattan(labels: Int[Array, " K"]) -> Bool[Array, ""]:
    """Whether ``labels`` are a Manhattan layout's (every wall labelled, one yaw) rather than all :data:`FREE_ANGLE`."""
    return jnp.all(labels != FREE_ANGLE)


def layout_problem(walls: Walls, labels: Int[Array, " K"] | None, wall_mask: Bool[Array, " K"]) -> LayoutProblem:
    """The parametrisation of :func:`adjust_layout` at ``walls`` (``labels`` None or all
    :data:`FREE_ANGLE`: an angle per wall)."""
    directions, distances = walls.directions, walls.distances
    ceiling_height, floor_height = walls.ceiling_height, walls.floor_height
    capacity = distances.shape[0]
    dtype = distances.dtype
    if labels is None:
        labels = jnp.full(capacity, FREE_ANGLE)
    manhattan = is_manhattan(labels)
    quarter_turns = jnp.where(manhattan, labels, 0)
    yaw = manhattan_yaw(directions, quarter_turns, wall_mask)
    aligned = jnp.sign(jnp.sum(manhattan_directions(yaw, quarter_turns) * directions, -1))
    distances = distances * jnp.where(manhattan & (aligned != 0), aligned, 1.0)
    angles = jnp.where(manhattan, yaw, jnp.arctan2(directions[:, 1], directions[:, 0]))
    offsets = quarter_turns.astype(dtype) * (math.pi / 2)
    angle_index = jnp.where(manhattan, 0, jnp.arange(capacity))
    angle_used = jax.ops.segment_sum(wall_mask.astype(jnp.int32), angle_index, capacity) > 0
    start = (angles, distances, jnp.stack([ceiling_height, floor_height]).astype(dtype))
    return LayoutProblem(start, offsets, angle_index, angle_used)


def problem_residuals(
    problem: LayoutProblem,
    y,
    cam,
    observations: BoundaryObservations,
    observed_directions,
    corner_weight: Float[ArrayLike, ""],
):
    """:func:`layout_residuals` at ``y``, the rows weighted by ``observations.row_weights``, plus pins of the empty
    slots' parameters to ``problem.start``.

    The pins make the Jacobian's columns independent (the implicit adjoint
    solves with it, the covariance inverts it); they are zero at the start.
    """
    wall_angles, distances, heights = y
    rows, corners = _residual_terms(
        wall_angles[problem.angle_index] + problem.offsets,
        distances,
        (heights[0], heights[1]),
        cam,
        observations,
        observed_directions,
    )
    rows = rows * observations.row_weights
    pins = [
        jnp.where(observations.wall_mask, 0.0, distances - problem.start[1]),
        jnp.where(problem.angle_used, 0.0, wall_angles - problem.start[0]),
    ]
    return jnp.concatenate([_fitted_residuals(rows, corners, observations, corner_weight), *pins])


def jacobian_structure(problem: LayoutProblem, observations: BoundaryObservations) -> JacobianStructure:
    """Which flat parameters ``(angles, distances, h_c, h_f)`` each of :func:`problem_residuals` depends on.

    Groups: the rows of wall ``k`` (its angle and distance, both heights), corner
    ``k`` (walls ``k - 1`` and ``k``), the distance and angle pins, and one group without parameters
    for the columns of no wall. Colours: the heights one each; the distances, and
    the angles, a proper colouring of the wall cycle (two colours, a third for
    the last wall of an odd count), so that no corner sees two walls of one colour.
    """
    capacity = observations.wall_mask.shape[0]
    walls = jnp.arange(capacity)
    angle, distance = problem.angle_index, capacity + walls
    ceiling, floor = jnp.full(capacity, 2 * capacity), jnp.full(capacity, 2 * capacity + 1)
    previous = previous_in_loop(observations.wall_mask)
    empty = jnp.full(capacity, -1)
    groups = [
        jnp.stack([angle, distance, ceiling, floor], -1),
        jnp.stack([angle[previous], distance[previous], angle, distance], -1),
        jnp.stack([distance, empty, empty, empty], -1),
        jnp.stack([walls, empty, empty, empty], -1),
    ]
    no_wall = len(groups) * capacity
    group_parameters = distinct_slots(jnp.concatenate([*groups, jnp.full((1, 4), -1)]))
    column_group = jnp.where(observations.column_wall >= 0, observations.column_wall, no_wall)
    row_group = jnp.concatenate([column_group, column_group, *(walls + i * capacity for i in range(1, len(groups)))])
    count = jnp.sum(observations.wall_mask)
    cycle = jnp.where((walls == count - 1) & (count % 2 == 1), 2, walls % 2)
    # a Manhattan layout's one yaw (slot 0, colour 5) is alone in its colour in every group: the other
    # slots of colour 5 are only pinned
    colours = jnp.concatenate([5 + cycle, 2 + cycle, jnp.array([0, 1])])
    return JacobianStructure(row_group, group_parameters, colours, 8)


def layout_least_squares(
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
    walls: Walls,
    labels: Int[Array, " K"] | None,
    corner_weight: Float[ArrayLike, ""],
) -> tuple[LayoutProblem, Callable[[tuple[Array, Array, Array]], Float[Array, " residuals"]], JacobianStructure]:
    """The final adjustment's least-squares problem, which :func:`adjust_layout` solves and
    :func:`~ncjax.pipeline.uncertainty.layout_uncertainty` linearises.

    Returns:
        ``(problem, residuals, structure)``: the parametrisation at the given walls (its ``start`` the
        parameters ``y`` of those walls), the residuals as a function of ``y`` (:func:`problem_residuals`)
        and which parameters each residual depends on (:func:`jacobian_structure`).
    """
    problem = layout_problem(walls, labels, observations.wall_mask)
    observed_directions = observation_directions(cam, observations)

    def residuals(y):
        return problem_residuals(problem, y, cam, observations, observed_directions, corner_weight)

    return problem, residuals, jacobian_structure(problem, observations)


def adjust_layout(
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
    walls: Walls,
    labels: Int[Array, " K"] | None,
    config: AdjustmentConfig = AdjustmentConfig(),
) -> tuple[Walls, Bool[Array, ""]]:
    """Trust-region (dogleg) least-squares refinement of a layout (see the module docstring).

    ``optimistix.least_squares`` with ``throw=False`` and at most ``config.steps``
    iterations (under ``vmap`` a batch runs until its slowest member stops, so
    the small cap bounds the batch's while loop too).

    Args:
        cam: the camera.
        observations: boundaries, used columns and corners.
        walls: the initial walls and heights.
        labels: Manhattan labels (0: ``u``, 1: ``u_perp``) to keep the walls
            exactly Manhattan with one yaw; None or all :data:`FREE_ANGLE` for free directions (Atlanta).
        config: the corner-plane penalty's weight (traced), the static iteration cap ``steps`` and the static
            ``tolerance`` (optimistix's Cauchy test; float32 rounds the residuals at about 1e-5 px, so a much
            tighter one is never met and every solve runs ``steps`` steps).

    Returns:
        ``(walls, improved)``; the initial walls are kept (``improved`` False) when the result is not finite
        or does not lower the cost (an unconverged but better iterate is kept).
    """
    # the solvers are imported where a layout is adjusted (traced): a process that runs the saved programs of
    # ncjax.programs never needs them, and their import is a tenth of a second of its start
    import optimistix as optx

    from .normal_solver import SparseNormalCholesky

    steps, tolerance = config.steps, config.tolerance
    problem, residuals, structure = layout_least_squares(cam, observations, walls, labels, config.corner_weight)
    y0 = problem.start

    def cost(y):
        r = residuals(y)
        return jnp.sum(r * r)

    linear_solver = SparseNormalCholesky(structure)
    solution = optx.least_squares(
        lambda y, args: residuals(y),
        optx.Dogleg(rtol=tolerance, atol=tolerance, linear_solver=linear_solver),
        y0,
        max_steps=steps,
        throw=False,
    )
    final_cost = cost(solution.value)
    improved = jnp.isfinite(final_cost) & (final_cost < cost(y0))
    y = jax.tree.map(lambda new, old: jnp.where(improved, new, old), solution.value, y0)
    return problem.walls(y), improved
