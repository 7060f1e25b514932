"""The final adjustment's linear solver: least squares by Cholesky on the normal equations of a sparse Jacobian.

:class:`SparseNormalCholesky` is a ``lineax`` solver for the least-squares solve of ``optimistix``'s dogleg step
that probes the Jacobian by colours (:mod:`ncjax.pipeline.sparse_normal`): the same solution as
``lineax.Normal(lineax.Cholesky())`` at a fraction of the cost. It has a module of its own so that ``lineax``
is imported only where a layout is adjusted (traced), not by a process that runs saved programs.
"""

from __future__ import annotations

from typing import Any

import equinox.internal as eqxi
import jax
import jax.flatten_util
import jax.numpy as jnp
import jax.scipy.linalg
import lineax as lx
from jaxtyping import Array, PyTree

from .sparse_normal import JacobianStructure, jacobian_product, normal_matrix, probe_jacobian, transpose_product


def _flat_structure(parameters: PyTree[jax.ShapeDtypeStruct]):
    """A flat zero vector of ``parameters``' size and the map from flat vectors back to that pytree."""
    return jax.flatten_util.ravel_pytree(jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), parameters))


class SparseNormalCholesky(lx.AbstractLinearSolver):
    """Least-squares solves ``min |J x - b|`` by Cholesky on ``J^T J``, ``J`` probed by colours.

    For a tall ``J`` of full column rank (the solver does not check it: a
    singular ``J^T J`` gives non-finite solutions, as ``lineax.Cholesky``
    does) whose sparsity ``structure`` describes. Operators map a pytree of
    parameters to ONE flat residual vector (R,), the parameters flattened in
    ``jax.flatten_util.ravel_pytree`` order. The transposed solve (needed when
    differentiating through ``lineax.linear_solve``) is ``J (J^T J)^-1``.
    """

    structure: JacobianStructure

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]):
        del options
        parameters = operator.in_structure()
        flat, unravel = _flat_structure(parameters)
        if flat.shape[0] != self.structure.num_parameters:
            raise ValueError(
                f"the operator has {flat.shape[0]} parameters, the structure {self.structure.num_parameters}"
            )
        values = probe_jacobian(lambda t: operator.mv(unravel(t)), self.structure, flat.dtype)
        factor = jnp.linalg.cholesky(normal_matrix(values, self.structure))
        # lineax passes solver states through its primitives: non-array parts must be static
        return factor, values, eqxi.Static((parameters, False))

    def compute(self, state, vector: PyTree[Array], options: dict[str, Any]):
        del options
        factor, values, static = state
        parameters, transposed = static.value
        _, unravel = _flat_structure(parameters)
        if transposed:  # vector: parameters -> residuals J (J^T J)^-1 vector
            flat, _ = jax.flatten_util.ravel_pytree(vector)
            solution = jacobian_product(values, self.structure, jax.scipy.linalg.cho_solve((factor, True), flat))
        else:
            normal = transpose_product(values, self.structure, vector)
            solution = unravel(jax.scipy.linalg.cho_solve((factor, True), normal))
        return solution, lx.RESULTS.successful, {}

    def transpose(self, state, options: dict[str, Any]):
        factor, values, static = state
        parameters, transposed = static.value
        return (factor, values, eqxi.Static((parameters, not transposed))), options

    def conj(self, state, options: dict[str, Any]):
        return state, options  # real arithmetic only

    def assume_full_rank(self) -> bool:
        return True
