"""Normal equations of sparse Jacobians probed by colours (the final adjustment's linear solves)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ncjax.pipeline.normal_solver import SparseNormalCholesky
from ncjax.pipeline.sparse_normal import (
    JacobianStructure,
    distinct_slots,
    normal_matrix,
    probe_jacobian,
    squared_column_norms,
)

ROWS, GROUPS, SLOTS, PARAMETERS = 40, 8, 3, 10


def random_problem(seed: int):
    """A random sparse Jacobian, its structure (greedy colouring) and a right-hand side.

    Rows ``0..P-1`` each see one parameter (full column rank); the others belong to
    random groups of up to ``SLOTS`` parameters.
    """
    rng = np.random.default_rng(seed)
    parameters = np.full((GROUPS + PARAMETERS, SLOTS), -1)
    for g in range(GROUPS):
        chosen = rng.choice(PARAMETERS, size=rng.integers(1, SLOTS + 1), replace=False)
        parameters[g, : len(chosen)] = chosen
    parameters[GROUPS:, 0] = np.arange(PARAMETERS)
    row_group = np.concatenate([GROUPS + np.arange(PARAMETERS), rng.integers(0, GROUPS, ROWS - PARAMETERS)])
    jacobian = np.zeros((ROWS, PARAMETERS), np.float32)
    for r, g in enumerate(row_group):
        present = parameters[g][parameters[g] >= 0]
        jacobian[r, present] = rng.normal(size=len(present))
    colours = np.zeros(PARAMETERS, int)
    for p in range(PARAMETERS):  # greedy: the smallest colour of no parameter that shares a group with p
        taken = {colours[q] for row in parameters if p in row for q in row if 0 <= q < p}
        colours[p] = min(set(range(PARAMETERS)) - taken)
    structure = JacobianStructure(jnp.asarray(row_group), jnp.asarray(parameters), jnp.asarray(colours), PARAMETERS)
    return jnp.asarray(jacobian), structure, jnp.asarray(rng.normal(size=ROWS), jnp.float32)


@pytest.mark.slow
@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_sparse_normal_solve_matches_least_squares(seed):
    jacobian, structure, rhs = random_problem(seed)
    values = probe_jacobian(lambda t: jacobian @ t, structure, jnp.float32)
    np.testing.assert_allclose(normal_matrix(values, structure), jacobian.T @ jacobian, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(squared_column_norms(values, structure), jnp.sum(jacobian**2, 0), rtol=1e-5, atol=1e-5)
    operator = lx.MatrixLinearOperator(jacobian)
    solver = SparseNormalCholesky(structure)
    solution = lx.linear_solve(operator, rhs, solver).value
    expected, *_ = np.linalg.lstsq(np.asarray(jacobian, np.float64), np.asarray(rhs, np.float64), rcond=None)
    np.testing.assert_allclose(solution, expected, rtol=1e-4, atol=1e-4)
    # reverse mode through the solve uses the transposed solve J (J^T J)^-1: the pseudo-inverse's rows
    pseudo_inverse = jax.jacrev(lambda b: lx.linear_solve(operator, b, solver).value)(rhs)
    np.testing.assert_allclose(pseudo_inverse, np.linalg.pinv(np.asarray(jacobian, np.float64)), rtol=1e-4, atol=1e-4)


def test_distinct_slots_empties_repeats():
    got = distinct_slots(jnp.array([[3, 1, 3, 3], [0, -1, 0, 2], [5, 6, 7, 8]]))
    np.testing.assert_array_equal(got, [[3, 1, -1, -1], [0, -1, -1, 2], [5, 6, 7, 8]])
