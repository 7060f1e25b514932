"""Null spaces with well-defined derivatives (docs/design.md section 8, "null spaces").

The geometric solvers of the paper (Section 4.1-4.3) are DLT-like: they fill a
matrix ``A`` with one row per projecting ray and take its (approximate) null
space. This module computes that null space once, in one place:

- :func:`null_space` returns the right singular vectors of the ``k`` smallest
  singular values of ``A`` (a Gram-Schmidt reduction to ``n x n``, then
  one-sided Jacobi; see :func:`_sorted_svd`), each with a canonical sign (its
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
import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .plucker import safe_norm, safe_sqrt


def _gram_schmidt(columns: list[Array], inner, spread) -> Array:
    """Modified Gram-Schmidt on ``columns`` with a given inner product: the ``R`` of ``A = Q R``.

    ``inner(x, y)`` reduces two columns over their rows and ``spread`` maps
    such a reduction back onto the rows: plain dot products give one ``R``
    (``cols x cols``), per-segment sums one ``R`` per segment (``S x cols x cols``).
    """
    n = len(columns)
    zero = jnp.zeros_like(inner(columns[0], columns[0]))
    r = [[zero] * n for _ in range(n)]
    for j in range(n):
        norm = safe_sqrt(inner(columns[j], columns[j]))
        q = columns[j] / spread(jnp.where(norm > 0, norm, 1.0))
        r[j][j] = norm
        for k in range(j + 1, n):
            r[j][k] = inner(q, columns[k])
            columns[k] = columns[k] - spread(r[j][k]) * q
    return jnp.stack([jnp.stack(row, -1) for row in r], -2)


def _triangular_factor(a: Array) -> Array:
    """Upper-triangular ``R`` (cols x cols) of ``A = Q R`` by modified Gram-Schmidt.

    Column by column with plain vector operations, so a ``vmap`` over a batch
    stays vectorised. ``Q`` loses orthogonality in MGS but ``R`` does not: it
    is numerically the ``R`` of Householder QR of ``[0; A]`` (Björck and Paige,
    1992), backward stable, at half Householder's cost. ``R`` has the singular
    values and right singular vectors of ``A``; a column that depends on the
    previous ones gets a zero diagonal.
    """
    return _gram_schmidt(list(a.T), jnp.dot, lambda value: value)


_MAX_JACOBI_SWEEPS = 12
# A sweep is n - 1 rounds of n / 2 disjoint rotations (n even): right for the 5-7 unknowns of a wall, not for the
# 6 + K unknowns of a whole layout, which go to LAPACK.
_JACOBI_MAX_COLUMNS = 8


def _rotate_pairs(top: Array, bottom: Array) -> tuple[Array, Array, Array]:
    """The Jacobi rotations that make each pair of columns ``(top[k], bottom[k])`` of ``R V`` orthogonal.

    Returns the cosines and sines (one per pair) and the pairs' largest cosine BEFORE the rotation: a sweep
    whose rounds see none above ``eps`` changed nothing. A pair with a zero column (the padding of an odd ``n``)
    is left as it is.
    """
    alpha, beta = jnp.sum(top * top, -1), jnp.sum(bottom * bottom, -1)
    gamma = jnp.sum(top * bottom, -1)
    scale = jnp.sqrt(alpha * beta)
    worst = jnp.max(jnp.where(scale > 0, jnp.abs(gamma) / jnp.where(scale > 0, scale, 1.0), 0.0))
    rotate = gamma != 0
    zeta = (beta - alpha) / (2.0 * jnp.where(rotate, gamma, 1.0))
    tangent = jnp.where(zeta >= 0, 1.0, -1.0) / (jnp.abs(zeta) + jnp.sqrt(1.0 + zeta * zeta))
    tangent = jnp.where(rotate, tangent, 0.0)
    cosine = jax.lax.rsqrt(1.0 + tangent * tangent)
    return cosine, cosine * tangent, worst


def _jacobi_round(state: tuple) -> tuple:
    """One round of one-sided (Hestenes) Jacobi: every pair ``(top[k], bottom[k])`` rotated at once, then the
    round-robin move (``top[0]`` stays, the others turn one place), so that ``n - 1`` rounds rotate every pair of
    columns once (Brent and Luk's parallel ordering, 1985).

    ``state``: the columns of ``R V`` and of ``V`` (each as rows) and the columns' original indices, each split
    into a top and a bottom half, and the largest cosine seen this sweep.
    """
    columns, vectors, indices, worst = state
    cosine, sine, seen = _rotate_pairs(*columns)
    c, s = cosine[:, None], sine[:, None]

    def rotate(upper, lower):
        return c * upper - s * lower, s * upper + c * lower

    def turn(upper, lower):
        if len(upper) == 1:  # one pair: nothing to turn
            return upper, lower
        return jnp.concatenate([upper[:1], lower[:1], upper[1:-1]]), jnp.concatenate([lower[1:], upper[-1:]])

    return turn(*rotate(*columns)), turn(*rotate(*vectors)), turn(*indices), jnp.maximum(worst, seen)


def _jacobi_svd(r: Array) -> tuple[Array, Array]:
    """Squared singular values and right singular vectors of a small square ``R`` (one-sided Jacobi).

    Sweeps until a sweep starts with no pair of columns of ``R V`` at a cosine
    above ``sqrt(eps)`` (at most ``_MAX_JACOBI_SWEEPS``): the convergence of
    Jacobi is asymptotically quadratic, so that sweep leaves cosines of
    order ``eps``, and the sweep that would confirm it is saved (one of the
    usual seven for the walls' 7 x 7 factors). A sweep is ``n - 1`` rounds of
    disjoint rotations (:func:`_jacobi_round`), written out: a program of
    ``n - 1`` rounds of a few dozen operations (the cyclic sweep has
    ``n (n - 1) / 2`` rotations, which made most of the walls' program), and
    no inner loop, whose iterations cost a single panorama's latency a quarter
    more. Plain vector operations:
    under ``vmap`` a batch is decomposed in lock-step (LAPACK's SVD is one call
    per matrix), and one-sided Jacobi computes the small singular values, hence
    the null space, to high relative accuracy.
    """
    n = r.shape[1]
    even = n + n % 2  # an odd n gets a zero column, which no rotation touches
    half = even // 2
    threshold = math.sqrt(jnp.finfo(r.dtype).eps)
    columns = jnp.zeros((even, n), r.dtype).at[:n].set(r.T)
    vectors = jnp.zeros((even, n), r.dtype).at[:n].set(jnp.eye(n, dtype=r.dtype))
    indices = jnp.arange(even)

    def not_converged(state):
        sweep, _, worst = state
        return (sweep < _MAX_JACOBI_SWEEPS) & (worst > threshold)

    def sweep_body(state):
        sweep, halves, _ = state
        halves = (*halves, jnp.zeros((), r.dtype))
        for _ in range(even - 1):
            halves = _jacobi_round(halves)
        return sweep + 1, halves[:3], halves[3]

    def split(x):
        return x[:half], x[half:]

    start = (0, (split(columns), split(vectors), split(indices)), jnp.ones((), r.dtype))
    _, halves, _ = jax.lax.while_loop(not_converged, sweep_body, start)
    columns, vectors, indices = (jnp.concatenate(pair) for pair in halves)
    order = jnp.argsort(indices)[:n]  # the columns back in their original order, the padding last
    columns, vectors = columns[order], vectors[order]
    return jnp.sum(columns * columns, -1), vectors.T


def _sorted_svd(a: Array) -> tuple[Array, Array]:
    """Squared singular values ascending and the matching right singular vectors (as columns).

    The tall ``A`` is first reduced to its triangular factor (batched LAPACK
    SVDs and QRs of ``2W x n`` matrices cost milliseconds each on CPU, the
    vectorised Gram-Schmidt reduction microseconds), then the small ``R`` is
    decomposed by one-sided Jacobi (:func:`_jacobi_svd`; by LAPACK's ``svd``
    beyond ``_JACOBI_MAX_COLUMNS`` unknowns).
    """
    r = _triangular_factor(a)
    if r.shape[1] > _JACOBI_MAX_COLUMNS:
        _, s, vt = jnp.linalg.svd(r, full_matrices=False)
        squared, vectors = s * s, vt.T
    else:
        squared, vectors = _jacobi_svd(r)
    order = jnp.argsort(squared)
    return squared[order], vectors[:, order]


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
    a = _unit_rows(a)
    scale = _inverse_or_one(safe_norm(a.T))
    return a * scale[None, :], scale


def _unit_rows(a: Array) -> Array:
    norm = safe_norm(a)
    return a / jnp.where(norm > 0, norm, 1.0)[:, None]


def inverse_or_zero(x: Array) -> Array:
    """``1 / x`` where ``x > 0``, else 0 (no inf or NaN, and a finite gradient, in traced code)."""
    positive = x > 0
    return jnp.where(positive, 1.0 / jnp.where(positive, x, 1.0), 0.0)


def _inverse_or_one(norm: Array) -> Array:
    return 1.0 / jnp.where(norm > 0, norm, 1.0)


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


def segment_scaled_null_spaces(
    a: Float[Array, "rows cols"], segments: Int[Array, " rows"], num_segments: int, k: int
) -> Float[Array, "S cols k"]:
    """:func:`scaled_null_space` of every segment's rows, in one pass over the rows.

    Segment ``s`` is the matrix of the rows with ``segments == s`` (rows with
    an id outside ``[0, num_segments)`` belong to none): the result equals
    ``scaled_null_space(where(segments == s, A, 0), k)`` for every ``s``, but
    the equilibration and the Gram-Schmidt reduction sum each row into its own
    segment instead of reducing ``S`` masked copies of ``A`` (the baseline of
    the noise sweep fits 16 lines per panorama from 1024 rows each). Only the
    small ``R`` of each segment goes to :func:`null_space` (same right singular
    vectors as the segment's rows, and the same derivative rule).

    Args:
        a: the rows of all segments.
        segments: the segment of each row.
        num_segments: static ``S``.
        k: static number of null vectors.

    Returns:
        ``(S, cols, k)``; an empty segment gives the null space of a zero matrix.
    """
    member = (segments >= 0) & (segments < num_segments)
    segments = jnp.where(member, segments, 0)
    a = _unit_rows(jnp.where(member[:, None], a, 0.0))  # before any arithmetic: NaN rows of no segment are harmless

    def inner(x, y):
        return jax.ops.segment_sum(x * y, segments, num_segments)

    def spread(per_segment):
        return per_segment[segments]

    scale = _inverse_or_one(safe_sqrt(jax.ops.segment_sum(a * a, segments, num_segments)))  # (S, cols)
    r = _gram_schmidt(list((a * scale[segments]).T), inner, spread)
    return scale[:, :, None] * jax.vmap(null_space, (0, None))(r, k)
