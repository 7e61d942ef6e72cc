"""The closest and reduced square roots (report §3.3) against their definitions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from kanagen.runtime.sqrt import REDUNDANT, closest_sqrt, reduced_solve, reduced_sqrt


def _psd(rng, n, rank):
    C = rng.normal(size=(n, rank))
    return C @ C.T


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 8), st.integers(0, 8), st.integers(0, 2**32 - 1), st.booleans())
@example(6, 3, 1688030, False)  # a tiny genuine pivot, then noise pivots below it
def test_closest_sqrt_is_a_definite_factor_next_to_the_input(n, rank, seed, batched):
    rng = np.random.default_rng(seed)
    S = _psd(rng, n, min(rank, n))
    L = closest_sqrt(S[None] if batched else S)
    L = L[0] if batched else L
    assert np.allclose(L, np.tril(L))
    assert np.all(np.diag(L) > 0)
    scale = max(np.max(np.diag(S)), 1.0)
    # the fixes perturb S by the rounding noise of its vanishing Schur complements, which
    # grows like ε / (smallest kept pivot)²: small, not machine-precision small
    assert np.abs(L @ L.T - S).max() <= 1e-6 * scale


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 7), st.integers(1, 6), st.integers(0, 2**32 - 1), st.booleans())
def test_reduced_sqrt_keeps_the_first_independent_rows(p, n, seed, batched):
    rng = np.random.default_rng(seed)
    C = rng.normal(size=(p, n))
    for i in range(1, p):  # make some rows combinations of earlier ones
        if rng.random() < 0.4:
            terms = rng.normal(size=i)[:, None] * C[:i]
            C[i] = terms.sum(axis=0)
            # a combination that cancels to a tiny row is numerically independent: skip it
            assume(np.linalg.norm(C[i]) > 1e-2 * np.linalg.norm(terms, axis=1).sum())
    S = C @ C.T
    L, kept = reduced_sqrt(S[None] if batched else S)
    L, kept = (L[0], kept[0]) if batched else (L, kept)
    expected = []
    for i in range(p):  # first independent rows, greedily
        if np.linalg.matrix_rank(C[expected + [i]], tol=1e-9) > len(expected):
            expected.append(i)
    # a rank decision on a Gram matrix is only as sharp as its rounding, ε·cond² of the kept
    # rows, allows: against the REDUNDANT = 1e3 ε test, cond² must stay well below 1e3
    rows = C[expected] / np.linalg.norm(C[expected], axis=1)[:, None]
    assume(np.linalg.svd(rows, compute_uv=False).min() > 0.2)
    assert np.flatnonzero(kept).tolist() == expected
    assert kept.sum() <= n
    sub = np.ix_(kept, kept)
    np.testing.assert_allclose((L @ L.T)[sub], S[sub], atol=1e-10 * max(1.0, S.max()))
    assert np.all(L[~kept] == 0) and np.all(L[:, ~kept] == 0)
    b = rng.normal(size=p)
    for transpose in (False, True):
        y = reduced_solve(L, kept, b, transpose)
        Lk = L[sub]
        np.testing.assert_allclose(y[kept], np.linalg.solve(Lk.T if transpose else Lk, b[kept]))
        assert np.all(y[~kept] == 0)


def test_extremes():
    L = closest_sqrt(np.zeros((3, 3)))
    np.testing.assert_allclose(L @ L.T, REDUNDANT * np.eye(3))  # Q = 0 -> the closest is ε I
    L, kept = reduced_sqrt(np.zeros((2, 2)))
    assert not kept.any() and np.all(L == 0)  # every equation singular: all dropped
    S = np.array([[1.0, 1.0], [1.0, 1.0 + 1e-17]])
    assert reduced_sqrt(S)[1].tolist() == [True, False]


@pytest.mark.parametrize("n", [2, 5, 20])
def test_small_and_batched_paths_agree(n):
    rng = np.random.default_rng(n)
    S = np.stack([_psd(rng, n, r) for r in (n, n - 1, 1)])
    for i in range(3):
        np.testing.assert_allclose(closest_sqrt(S[i]) @ closest_sqrt(S[i]).T,
                                   closest_sqrt(S[i : i + 1])[0] @ closest_sqrt(S[i : i + 1])[0].T,
                                   atol=1e-9 * S[i].max())
        L1, k1 = reduced_sqrt(S[i])
        L2, k2 = reduced_sqrt(S[i : i + 1])
        assert k1.tolist() == k2[0].tolist()
        np.testing.assert_allclose(L1, L2[0], atol=1e-9 * np.sqrt(S[i].max()))
