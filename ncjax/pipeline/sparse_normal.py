"""Normal equations of a sparse least-squares Jacobian, for the final adjustment's trust-region steps.

Each residual of the final adjustment depends on at most four of its
parameters (a column's rows on its wall's angle and distance and the two
heights; a corner on two walls), yet a dense Gauss-Newton step materialises
the whole ``R x P`` Jacobian (``P`` forward passes) and multiplies it out
(``R P^2``). Here the Jacobian is probed instead with one forward pass per
*colour* of the parameters, Curtis, Powell and Reid's method (J. Inst. Maths
Applics 13, 1974): parameters that share no residual get one colour, and the
compressed product ``J S`` (``S`` the parameter-by-colour indicator) holds
every non-zero of ``J`` once. Residuals that depend on the same parameters
form a *group* (all the rows of one wall); their ``4 x 4`` outer products are
summed per group and scattered into ``J^T J``.

:class:`~ncjax.pipeline.normal_solver.SparseNormalCholesky` is the ``lineax`` solver
that does this for the least-squares solve of ``optimistix``'s dogleg step.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int


class JacobianStructure(eqx.Module):
    """Which flat parameters each residual may depend on (array fields traced, counts static).

    Attributes:
        row_group: (R,) the group of each residual.
        group_parameters: (G, A) the flat indices of the parameters of each
            group's residuals, ``-1`` for an empty slot; no index twice in a row.
        colours: (P,) a colour per parameter such that no group has two
            parameters of one colour.
        num_colours: static number of colours (forward passes per Jacobian).
    """

    row_group: Int[Array, " R"]
    group_parameters: Int[Array, "G A"]
    colours: Int[Array, " P"]
    num_colours: int = eqx.field(static=True)

    @property
    def num_parameters(self) -> int:
        return self.colours.shape[0]


def distinct_slots(parameters: Int[Array, "G A"]) -> Int[Array, "G A"]:
    """``parameters`` with each repeat of an index within a group set to ``-1`` (an empty slot)."""
    slots = parameters.shape[1]
    earlier = jnp.tril(jnp.ones((slots, slots), bool), -1)
    repeated = jnp.any((parameters[:, :, None] == parameters[:, None, :]) & earlier[None], axis=-1)
    return jnp.where(repeated, -1, parameters)


def _slot_indices(structure: JacobianStructure) -> Int[Array, "G A"]:
    """The parameter index of each slot, ``P`` (one past the last parameter) for empty slots."""
    return jnp.where(structure.group_parameters >= 0, structure.group_parameters, structure.num_parameters)


def _row_parameters(structure: JacobianStructure) -> Int[Array, "R A"]:
    """Each residual's parameter slots (``-1``: empty)."""
    return structure.group_parameters[structure.row_group]


def _at_slots(structure: JacobianStructure, vector: Float[Array, " P"]) -> Float[Array, "R A"]:
    """``vector[p]`` at each residual's parameter slot ``p``, 0 in empty slots."""
    parameters = _row_parameters(structure)
    return jnp.where(parameters >= 0, vector[jnp.maximum(parameters, 0)], 0.0)


def _sum_into_parameters(per_slot: Float[Array, "R A"], structure: JacobianStructure) -> Float[Array, " P"]:
    """Per parameter, the sum of ``per_slot`` over the residual slots that hold it (per group first)."""
    groups, size = structure.group_parameters.shape[0], structure.num_parameters
    per_group = jax.ops.segment_sum(per_slot, structure.row_group, groups)
    return jnp.zeros(size + 1, per_slot.dtype).at[_slot_indices(structure)].add(per_group)[:size]


def probe_jacobian(
    jvp: Callable[[Float[Array, " P"]], Float[Array, " R"]], structure: JacobianStructure, dtype
) -> Float[Array, "R A"]:
    """The non-zeros of a Jacobian, from ``structure.num_colours`` Jacobian-vector products.

    Args:
        jvp: the linear map ``t -> J t`` on flat parameter vectors (P,) to residuals (R,).
        structure: its sparsity; the colouring must be valid for ``J``.
        dtype: the parameters' dtype.

    Returns:
        ``values[r, a] = J[r, group_parameters[row_group[r], a]]`` (0 in empty slots).
    """
    seeds = jax.nn.one_hot(structure.colours, structure.num_colours, dtype=dtype).T
    compressed = jax.vmap(jvp)(seeds)  # (colours, R)
    parameters = _row_parameters(structure)
    colour = structure.colours[jnp.maximum(parameters, 0)]
    values = jnp.take_along_axis(compressed.T, colour, axis=1)
    return jnp.where(parameters >= 0, values, 0.0)


def normal_matrix(values: Float[Array, "R A"], structure: JacobianStructure) -> Float[Array, "P P"]:
    """``J^T J`` from the Jacobian's non-zeros: per-group outer products, scattered."""
    groups, size = structure.group_parameters.shape[0], structure.num_parameters
    blocks = jax.ops.segment_sum(values[:, :, None] * values[:, None, :], structure.row_group, groups)
    index = _slot_indices(structure)
    normal = jnp.zeros((size + 1, size + 1), values.dtype).at[index[:, :, None], index[:, None, :]].add(blocks)
    return normal[:size, :size]


def transpose_product(
    values: Float[Array, "R A"], structure: JacobianStructure, vector: Float[Array, " R"]
) -> Float[Array, " P"]:
    """``J^T b`` from the Jacobian's non-zeros."""
    return _sum_into_parameters(values * vector[:, None], structure)


def squared_column_norms(values: Float[Array, "R A"], structure: JacobianStructure) -> Float[Array, " P"]:
    """The diagonal of ``J^T J`` without the rest of it."""
    return _sum_into_parameters(values * values, structure)


def jacobian_product(
    values: Float[Array, "R A"], structure: JacobianStructure, vector: Float[Array, " P"]
) -> Float[Array, " R"]:
    """``J t`` from the Jacobian's non-zeros."""
    return jnp.sum(values * _at_slots(structure, vector), axis=-1)


def scale_columns(
    values: Float[Array, "R A"], structure: JacobianStructure, scale: Float[Array, " P"]
) -> Float[Array, "R A"]:
    """The non-zeros of ``J diag(scale)``."""
    return values * _at_slots(structure, scale)
