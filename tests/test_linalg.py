"""The small-matrix factorisations of runtime/linalg.py that the two-view closed forms use
(the SVD of any shape, its right vectors alone, a minimal system's null space) against
NumPy's LAPACK: the same singular values, orthogonal factors that reproduce the matrix, the
same subspaces; matrices of every shape and rank, at scales near over- and underflow."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kanagen.runtime.linalg import certified_solve, null_basis, right_singular, small_svd

_SHAPES = dict(m=st.integers(1, 9), n=st.integers(1, 9), rank=st.integers(0, 9),
               seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-150, 1.0, 1e150]))


def _matrix(m, n, rank, seed, scale):
    rng = np.random.default_rng(seed)
    k = min(rank, m, n)
    return scale * (rng.standard_normal((m, k)) @ rng.standard_normal((k, n))), k


@given(**_SHAPES)
@settings(max_examples=150, deadline=None)
def test_small_svd_as_lapack(m, n, rank, seed, scale):
    """``U diag(S) Vᵀ = A`` with orthogonal ``U`` (m, m) and ``Vᵀ`` (n, n), LAPACK's
    singular values in LAPACK's (decreasing) order, to 1e-13 of the largest; the right
    vectors of the zero singular values span ``A``'s null space."""
    A, k = _matrix(m, n, rank, seed, scale)
    U, S, Vt = small_svd(A)
    top = max(np.linalg.svd(A, compute_uv=False).max(initial=0.0), 1e-300 * scale)
    np.testing.assert_allclose(S, np.linalg.svd(A, compute_uv=False), rtol=0, atol=1e-13 * top)
    assert np.all(np.diff(S) <= 0)
    np.testing.assert_allclose(U @ U.T, np.eye(m), atol=1e-13)
    np.testing.assert_allclose(Vt @ Vt.T, np.eye(n), atol=1e-13)
    D = np.zeros((m, n))
    D[:S.size, :S.size] = np.diag(S)
    np.testing.assert_allclose(U @ D @ Vt, A, rtol=0, atol=1e-13 * top)
    np.testing.assert_allclose(A @ Vt[k:].T, 0.0, atol=1e-12 * top)


@given(**_SHAPES)
@settings(max_examples=150, deadline=None)
def test_right_singular_as_lapack(m, n, rank, seed, scale):
    """The singular values and the full ``Vᵀ`` of :func:`small_svd` without the left
    vectors (a tall matrix through its triangular factor): the same values, ``Vᵀ``
    orthogonal, its last rows spanning the null space."""
    A, k = _matrix(m, n, rank, seed, scale)
    S, Vt = right_singular(A)
    top = max(np.linalg.svd(A, compute_uv=False).max(initial=0.0), 1e-300 * scale)
    np.testing.assert_allclose(S, np.linalg.svd(A, compute_uv=False), rtol=0, atol=1e-13 * top)
    np.testing.assert_allclose(Vt @ Vt.T, np.eye(n), atol=1e-13)
    np.testing.assert_allclose(A @ Vt[k:].T, 0.0, atol=1e-12 * top)


@given(m=st.integers(1, 8), extra=st.integers(1, 4), deficient=st.integers(0, 2),
       seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-150, 1.0, 1e150]))
@settings(max_examples=150, deadline=None)
def test_null_basis_of_a_minimal_system(m, extra, deficient, seed, scale):
    """A wide system of full row rank: orthonormal columns spanning its null space (the
    complement of the rows, as LAPACK's), ``full`` True; of deficient rank: ``full``
    False."""
    n = m + extra
    rank = m - min(deficient, m - 1) if deficient else m
    A, k = _matrix(m, n, rank, seed, scale)
    Z, full = null_basis(A, 1e-6)
    assert full == (k == m)
    assert Z.shape == (n, n - m)
    np.testing.assert_allclose(Z.T @ Z, np.eye(n - m), atol=1e-13)
    if full:
        top = np.linalg.svd(A, compute_uv=False)[0]
        np.testing.assert_allclose(A @ Z, 0.0, atol=1e-12 * top)
        lapack = np.linalg.svd(A)[2][m:].T  # the same space: projectors equal
        np.testing.assert_allclose(Z @ Z.T, lapack @ lapack.T, atol=1e-10)


@pytest.mark.parametrize("factor", [small_svd, right_singular,
                                    lambda A: null_basis(A, 1e-6)])
def test_non_finite_matrices_raise(factor):
    for bad in (np.nan, np.inf):
        A = np.ones((2, 3))
        A[1, 2] = bad
        with pytest.raises(np.linalg.LinAlgError):
            factor(A)


@given(n=st.integers(1, 12), seed=st.integers(0, 2**32 - 1),
       scale=st.sampled_from([1e-150, 1e-3, 1.0, 1e150]))
@settings(max_examples=150, deadline=None)
def test_one_constraints_complement_is_lapacks_null_space(n, seed, scale):
    """The null space of one constraint row (the covariance's, runtime/engine/covariance.py:
    ``complement``): ``n − 1`` orthonormal columns orthogonal to the row, the same subspace
    as LAPACK's SVD gives (its projector), at scales near over- and underflow."""
    from kanagen.runtime.engine.covariance import complement

    c = scale * np.random.default_rng(seed).standard_normal(n)
    Z = complement(c)
    assert Z.shape == (n, n - 1)
    np.testing.assert_allclose(Z.T @ Z, np.eye(n - 1), atol=1e-14)
    np.testing.assert_allclose(c @ Z / np.abs(c).max(), 0.0, atol=1e-14)
    N = np.linalg.svd(c[None, :])[2][1:].T
    np.testing.assert_allclose(Z @ Z.T, N @ N.T, atol=1e-14)


@pytest.mark.parametrize("value", [1.0, -1.0, 2.5e-200, -7e250])
def test_one_pinned_components_complement_is_exact(value):
    """A constraint that pins one component (a multiple of an axis): the other axes
    exactly, so that the pinned component's variance is exactly zero; a zero row: every
    axis."""
    from kanagen.runtime.engine.covariance import complement, constrained_covariance

    c = np.zeros(5)
    c[2] = value
    Z = complement(c)
    assert np.array_equal(np.abs(Z), np.eye(5)[:, [0, 1, 3, 4]])
    info = np.diag([1.0, 2.0, 3.0, 4.0, 5.0]) + 0.1
    cov = constrained_covariance(info, c[None, :])
    assert np.all(cov[2] == 0.0) and np.all(cov[:, 2] == 0.0)
    assert np.array_equal(complement(np.zeros(4)), np.eye(4))


@given(n=st.integers(1, 12), digits=st.floats(0.0, 17.0), seed=st.integers(0, 2**32 - 1),
       scale=st.sampled_from([1e-200, 1e-3, 1.0, 1e200]), floor=st.sampled_from([1e-8, 1e-4]))
@settings(max_examples=200, deadline=None)
def test_certified_solve_certifies_only_what_an_svd_keeps_whole(n, digits, seed, scale, floor):
    """:func:`certified_solve` solves ``T x = b`` only for a matrix whose singular values
    all lie above ``floor`` times the largest — the solution LAPACK's gives, to its
    condition number's rounding — and certifies every matrix well inside that (a condition
    number ``κ`` with ``n κ`` under ``1 / (4 floor)``); matrices of every condition number
    up to singular, at scales near over- and underflow."""
    rng = np.random.default_rng(seed)
    U = np.linalg.qr(rng.standard_normal((n, n)))[0]
    V = np.linalg.qr(rng.standard_normal((n, n)))[0]
    S = np.logspace(0.0, -digits, n) if n > 1 else np.ones(1)
    T = scale * (U * S) @ V.T
    b = scale * rng.standard_normal(n)
    x = np.empty(n)
    ok = certified_solve(T, b, floor, np.empty((n, n)), np.empty((n, n + 1)), x)
    values = np.linalg.svd(T, compute_uv=False)
    kappa = values[0] / values[-1] if values[-1] > 0 else np.inf
    if ok:
        assert values[-1] > floor * values[0]
        reference = np.linalg.solve(T, b)
        np.testing.assert_allclose(x, reference, rtol=0,
                                   atol=1e-13 * n * kappa * np.abs(reference).max())
    else:
        assert not 4.0 * n * kappa * floor < 1.0


def test_certified_solve_refuses_singular_and_non_finite_matrices():
    """A singular matrix, a zero one and one with a non-finite entry are never certified."""
    x = np.empty(3)
    for T in (np.ones((3, 3)), np.zeros((3, 3)), np.diag([1.0, np.nan, 1.0]),
              np.diag([1.0, np.inf, 1.0])):
        assert not certified_solve(T, np.ones(3), 1e-8, np.empty((3, 3)), np.empty((3, 4)), x)
