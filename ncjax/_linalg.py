"""Null spaces with well-defined derivatives (DESIGN.md section 8, "null spaces").

The geometric solvers of the paper (Section 4.1-4.3) are DLT-like: they fill a
matrix ``A`` with one row per projecting ray and take its (approximate) null
space. This module computes that null space once, in one place:

- :func:`null_space` returns the right singular vectors of the ``k`` smallest
  singular values of ``A`` (a Householder reduction to ``n x n``, then
  ``svd``; see :func:`_sorted_svd`), each with a canonical sign (its
  largest-magnitude entry positive).
- Its derivative is a ``jax.custom_jvp``. JAX's own SVD derivative divides by
  ``s_i^2 - s_j^2`` for EVERY pair of singular values, so exactly repeated
  singular values (axis-aligned walls, padded wall columns) give NaN gradients
  even when the null space itself is perfectly well conditioned. Here only the
  pairs (kept vector, other vector) enter: with ``M = A^T A``, kept vectors
  ``v_k`` (eigenvalues ``s_k^2``) and the others ``v_j``, the standard
  first-order perturbation formula gives

      dv_k = sum_j v_j (v_j^T dM v_k) / (s_k^2 - s_j^2),  dM = dA^T A + A^T dA.

  The rotation of the kept vectors among themselves is left out (set to zero):
  it is a gauge freedom, and every solver in ncjax only uses the SPAN of the
  kept vectors (a point of that span chosen by intrinsic conditions), so its
  outputs have the same derivative for any basis of the span.
- :func:`scaled_null_space` equilibrates the rows and columns of ``A`` first
  (float32 accuracy), and maps the answer back.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._plucker import safe_norm


def _pad_rows(a: Array) -> Array:
    """Zero rows so that ``A`` has at least as many rows as columns (same null space)."""
    rows, cols = a.shape
    return a if rows >= cols else jnp.concatenate([a, jnp.zeros((cols - rows, cols), a.dtype)])


def _triangular_factor(a: Array) -> Array:
    """``R`` (cols x cols) of ``A = Q R`` by Householder reflections, in plain jnp.

    One reflection per column (a static loop of vector operations), so a
    ``vmap`` over a batch stays vectorised; backward stable like LAPACK's QR.
    ``R`` has the singular values and right singular vectors of ``A``.
    """
    a = _pad_rows(a)
    rows, cols = a.shape
    index = jnp.arange(rows)
    for j in range(cols):
        x = jnp.where(index >= j, a[:, j], 0.0)
        norm = safe_norm(x)
        alpha = jnp.where(x[j] >= 0, -norm, norm)
        v = x.at[j].add(-alpha)
        vv = jnp.dot(v, v)
        a = a - jnp.outer(v, 2.0 * (v @ a) / jnp.where(vv > 0, vv, 1.0))
    return a[:cols]


def _sorted_svd(a: Array) -> tuple[Array, Array]:
    """Squared singular values ascending and the matching right singular vectors (as columns).

    The tall ``A`` is first reduced to its triangular factor (batched LAPACK
    SVDs and QRs of ``2W x n`` matrices cost milliseconds each on CPU, the
    vectorised Householder reduction microseconds), then the small ``R`` is
    decomposed by ``svd``.
    """
    _, s, vt = jnp.linalg.svd(_triangular_factor(a), full_matrices=False)
    return (s * s)[::-1], vt[::-1].T


def _canonical_sign(vectors: Array) -> Array:
    """Flip each column so that its largest-magnitude entry is positive."""
    index = jnp.argmax(jnp.abs(vectors), axis=0)
    pivot = jnp.take_along_axis(vectors, index[None], axis=0)
    return vectors * jnp.where(pivot < 0, -1.0, 1.0)


@functools.partial(jax.custom_jvp, nondiff_argnums=(1,))
def null_space(a: Float[Array, "rows cols"], k: int) -> Float[Array, "cols k"]:
    """Orthonormal basis of the (least-squares) ``k``-dimensional null space of ``A``.

    Args:
        a: the matrix, any number of rows (zero rows are harmless).
        k: how many vectors, static.

    Returns:
        ``(cols, k)``: column ``i`` is the right singular vector of the ``i``-th
        smallest singular value (column 0 minimises ``|A x|``), canonical sign.
    """
    _, vectors = _sorted_svd(a)
    return _canonical_sign(vectors[:, :k])


def _kept_tangent(eig: Array, vectors: Array, dm: Array, k: int) -> Array:
    """First-order change of the eigenvectors of the ``k`` smallest eigenvalues of ``M``.

    ``dv_k = sum_j v_j (v_j^T dM v_k) / (e_k - e_j)`` over the OTHER
    eigenvectors ``j`` only (rotation within the kept span is gauge).
    Exactly equal eigenvalues across the split would make the span
    ill-defined; they get a zero (not NaN) derivative (double where).
    """
    kept, others = vectors[:, :k], vectors[:, k:]
    gap = eig[:k][None, :] - eig[k:][:, None]  # (cols - k, k), <= 0
    tiny = jnp.finfo(dm.dtype).eps * jnp.maximum(jnp.max(jnp.abs(eig)), jnp.finfo(dm.dtype).tiny)
    separated = jnp.abs(gap) > tiny
    inverse_gap = jnp.where(separated, 1.0 / jnp.where(separated, gap, 1.0), 0.0)
    return others @ ((others.T @ dm @ kept) * inverse_gap)


@null_space.defjvp
def _null_space_jvp(k: int, primals: tuple[Array], tangents: tuple[Array]) -> tuple[Array, Array]:
    (a,), (da,) = primals, tangents
    eig, vectors = _sorted_svd(a)
    kept = _canonical_sign(vectors[:, :k])
    vectors = jnp.concatenate([kept, vectors[:, k:]], 1)
    return kept, _kept_tangent(eig, vectors, da.T @ a + a.T @ da, k)


def equilibrate(a: Float[Array, "rows cols"]) -> tuple[Float[Array, "rows cols"], Float[Array, " cols"]]:
    """Unit rows, then unit columns: returns ``(A_scaled, column_scale)``.

    ``A_scaled = diag(1/|row|) A diag(column_scale)``; zero rows and columns
    stay zero (their scale is 1).
    """
    row_norm = safe_norm(a)
    a = a / jnp.where(row_norm > 0, row_norm, 1.0)[:, None]
    column_norm = safe_norm(a.T)
    scale = 1.0 / jnp.where(column_norm > 0, column_norm, 1.0)
    return a * scale[None, :], scale


def divide_if_significant(
    values: Float[Array, "*shape"], divisor: Float[Array, ""], reference: Float[Array, ""] | float
) -> tuple[Float[Array, "*shape"], Bool[Array, ""]]:
    """``values / divisor`` when ``|divisor|`` exceeds ``1e3 eps`` times ``reference``.

    De-homogenises a null vector by one of its entries: a tiny divisor would
    give an unbounded result, so ``values`` is returned unchanged with
    ``ok = False`` instead (no NaN or inf in traced code).

    Returns:
        ``(quotient, ok)``.
    """
    ok = jnp.abs(divisor) > 1e3 * jnp.finfo(values.dtype).eps * reference
    return values / jnp.where(ok, divisor, 1.0), ok


def scaled_null_space(a: Float[Array, "rows cols"], k: int) -> Float[Array, "cols k"]:
    """:func:`null_space` of the equilibrated matrix, mapped back to the unknowns of ``A``.

    The columns span the null space of ``A`` but are not orthonormal: column
    ``i`` is ``D y_i`` with ``y_i`` orthonormal in the equilibrated space
    (``D`` the column scale), so combinations ``cos t y_0 + sin t y_1`` keep
    the metric of that well-conditioned space.
    """
    scaled, scale = equilibrate(a)
    return scale[:, None] * null_space(scaled, k)
